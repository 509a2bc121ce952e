"""A mug lying on its side with its handle part-way up (about 25 degrees above level) has no grasp across its body
clear of the handle: near vertical a pad lands on the handle, turned far enough to clear it the lower pad meets the
sink floor. Cups, mugs and glasses with a handle (found by shape: `find_handle`) also get grasps that straddle it
(planning/grasp_synthesis.py `_handle_grasps`, fallbacks): approaching across the handle's plane, which is then
25 degrees off vertical, the pads close along the body's axis on the handle's two roots."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.grasp_synthesis import find_handle
from kitchenbot.planning.grasps import FALLBACK_GRASPS
from kitchenbot.transforms import make_T, rot_y, rot_z


def _axis_and_radius(model):
    V = np.asarray(model.mesh.vertices)
    rim = V[V[:, 2] > V[:, 2].max() - 0.004][:, :2]
    c = (rim.max(axis=0) + rim.min(axis=0)) / 2
    return V, np.array([c[0], c[1], 0.0]), float(np.max(np.linalg.norm(rim - c, axis=1)))


def test_the_handle_is_found_by_shape(inventory):
    V, axis, r = _axis_and_radius(inventory.by_name("mug"))
    h, P = find_handle(V, axis, r)
    assert h @ [1.0, 0.0, 0.0] > 0.99  # the builtin mug's handle points along its +x
    assert np.linalg.norm(P[:, :2] - axis[:2], axis=1).max() > r + 0.02
    for name in ("cup", "glass", "bowl", "dinner_plate"):
        assert find_handle(*_axis_and_radius(inventory.by_name(name))) is None, name
    # a lump all around the body (a flange) is no handle
    a = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    ring = np.column_stack([0.05 * np.cos(a), 0.05 * np.sin(a), np.zeros_like(a)])
    assert find_handle(ring, np.zeros(3), 0.04) is None


def test_mug_handle_grasps_straddle_it_and_hold(inventory, grasps_hold):
    assert "handle" in FALLBACK_GRASPS  # they hold the mug by its handle: after every grasp of the body
    hg = [g for g in inventory.by_name("mug").grasps if g.name.startswith("handle")]
    assert len(hg) == 4
    for g in hg:
        assert abs(abs(g.T_obj_tcp[2, 1]) - 1.0) < 1e-6  # closing along the body's axis
        assert abs(g.T_obj_tcp[1, 2]) > 0.99  # approaching across the handle's plane
        assert 0.05 < g.width < 0.07  # the handle's extent along the axis at its roots
    grasps_hold("mug", "handle", 1)


def _lying_mug(planner, yaw: float, elevation: float) -> ObjectPose:
    """The mug on its side in the basin's middle, its handle `elevation` above level, its axis turned `yaw`."""
    m = planner.inventory.by_name("mug")
    lo, hi = planner.cell.sink_interior
    R = (rot_z(yaw) @ rot_y(np.pi / 2) @ rot_z(np.pi / 2 + elevation))[:3, :3]
    zmin = (np.asarray(m.mesh.vertices) @ R.T)[:, 2].min()
    c = (lo + hi) / 2
    return ObjectPose(m.obj_id, m.cls, make_T(R, (c[0], c[1], lo[2] - zmin + 0.001)), 1.0, instance_id=1)


@pytest.mark.parametrize("yaw", [0.0, np.pi / 2])
def test_a_lying_mug_with_its_handle_part_way_up_is_taken_by_the_handle(planner, cfg, home, inventory, yaw,
                                                                       run_pick_on_fake_arm):
    from kitchenbot.fakes.world import SimWorld
    from kitchenbot.world.cell import Cell

    mug = _lying_mug(planner, yaw, np.radians(25))
    assert mug.T_base_obj[:3, 0] @ [0, 0, 1] == pytest.approx(np.sin(np.radians(25)))  # the handle 25 deg up
    pick = planner.plan_pick(home, [mug], target=mug)
    assert pick.ok, pick
    assert pick.grasp.spec.name.startswith("handle")
    assert pick.grasp.T_base_tcp[2, 2] < -0.8  # from above, about 25 degrees off vertical
    world = SimWorld(Cell(), inventory, T_flange_tcp=cfg.safety_limits().T_flange_tcp, q=home.copy())
    world.add_object(inventory.by_name("mug"), np.asarray(mug.T_base_obj, float))
    run_pick_on_fake_arm(cfg, world, pick)
