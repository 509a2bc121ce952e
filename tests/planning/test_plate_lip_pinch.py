"""Plates get narrow, shallow lip pinches leaning in from outside whose fingers keep clear of a plate nested below
(stacks in a sink), where the standard vertical rim pinch reaches the lower plate through the target's well."""

from __future__ import annotations

import coal
import pytest
import numpy as np

from kitchenbot.planning.collision import coal_transform
from kitchenbot.transforms import make_T


def _nested_below(planner, model, T_top, shift):
    """The highest pose, `shift` (base frame) off the target, at which a copy of `model` clears it."""
    bvh = planner.world.bvh(model)
    req = coal.CollisionRequest()
    for dz in np.arange(0.0, 0.03, 0.0005):
        T = make_T(t=T_top[:3, 3] + shift - (0, 0, dz))
        if not coal.collide(bvh, coal_transform(T_top), bvh, coal_transform(T), req, coal.CollisionResult()):
            return T
    raise AssertionError("no nested pose")


def _finger_distance(planner, spec, T_tcp, model, T_obj):
    """Smallest distance (m) of the two finger boxes at `T_tcp` to `model` posed at `T_obj`."""
    out = []
    for pb in planner.world.gripper.pads(np.eye(4), spec.opening):
        r = coal.DistanceResult()
        out.append(coal.distance(coal.Box(*pb.size), coal_transform(T_tcp @ pb.T_flange_box), planner.world.bvh(model),
                                 coal_transform(T_obj), coal.DistanceRequest(), r))
    return min(out)


def test_plates_get_narrow_lip_pinches(inventory):
    for name in ("dinner_plate", "side_plate"):
        m = inventory.by_name(name)
        narrow = [g for g in m.grasps if g.name.startswith("rimlean")]
        assert len(narrow) == 24
        for g in narrow:
            assert 0.0 < g.width < 0.02
            assert g.opening - g.width < 0.0165  # 8 mm of slack per pad
            assert g.T_obj_tcp[2, 2] < -0.7  # from above, leaning in
            # the TCP sits on the lip's outer side, the approach points in towards the plate's axis
            assert g.T_obj_tcp[:3, 2] @ g.T_obj_tcp[:3, 3] < 0


@pytest.mark.parametrize("name", ["dinner_plate", "side_plate"])
@pytest.mark.parametrize("overhang", [0.0, 0.01, 0.02])
def test_lip_pinch_clears_a_plate_nested_below(planner, inventory, name, overhang):
    m = inventory.by_name(name)
    T_top = make_T(t=(0.5, 0.0, -0.1))
    narrow = next(g for g in m.grasps if g.name.startswith("rimlean40_"))
    deep = next(g for g in m.grasps if g.name == narrow.name.replace("rimlean40_", "rim_"))
    radial = narrow.T_obj_tcp[:3, 3] * np.array([1.0, 1.0, 0.0])
    radial /= np.linalg.norm(radial)
    T_below = _nested_below(planner, m, T_top, -overhang * radial)  # the target overhangs it on this side
    grasp_margin = planner.settings.grasp_margin
    assert _finger_distance(planner, narrow, T_top @ narrow.T_obj_tcp, m, T_below) > grasp_margin
    # the standard (deeper, wider) rim pinch's inner finger reaches the plate below through the target
    assert _finger_distance(planner, deep, T_top @ deep.T_obj_tcp, m, T_below) < grasp_margin
    if overhang >= 0.02:  # grasp selection's multi-object test (the closing volume) lets it through
        from kitchenbot.planning.grasps import closing_volume

        gr = planner.world.gripper
        vol, T_v = closing_volume(narrow.opening, gr.pad_width, gr.pad_root, gr.pad_tip)
        assert not coal.collide(vol, coal_transform(T_top @ narrow.T_obj_tcp @ T_v), planner.world.bvh(m),
                                coal_transform(T_below), coal.CollisionRequest(), coal.CollisionResult())



@pytest.mark.parametrize("name", ["dinner_plate", "side_plate"])
@pytest.mark.parametrize("lean", ["rimlean25_", "rimlean40_"])
def test_simulated_gripper_holds_the_plate_by_its_lip(name, lean, grasps_hold):
    """The simulator's Fin-Ray model (its own contact test) holds the plate at about the expected width."""
    grasps_hold(name, lean, 4)
