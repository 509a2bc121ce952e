"""A plate leaning against a basin wall (its upper lip on the wall): the standard rim pinches put the outer pad
into the wall, so plates also get a narrow rim pinch (8 mm bite, 8 mm of slack per pad), level and rolled 45
degrees about its closing axis (planning.grasp_synthesis.generate_grasps, sink-pick seeds 22, 30, 46)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning import grasps as grasps_mod
from kitchenbot.planning.fcl_check import FclChecker, verify_pick
from kitchenbot.planning.grasp_synthesis import NARROW_ROLLS
from kitchenbot.transforms import make_T, rot_x


def _leaning(planner, name: str, x: float, tilt_deg: float, instance_id: int = 1) -> ObjectPose:
    """`name` tilted `tilt_deg` about the base x axis, its face away from the right basin wall (y = lower bound),
    pushed against that wall and down onto the sink floor (1 mm off each)."""
    m = planner.inventory.by_name(name)
    lo, _ = planner.cell.sink_interior
    R = rot_x(-np.radians(tilt_deg))
    V = np.asarray(m.mesh.vertices) @ R[:3, :3].T
    y = lo[1] + 0.001 - V[:, 1].min()
    z = lo[2] + 0.001 - V[:, 2].min()
    return ObjectPose(m.obj_id, m.cls, make_T(t=(x, y, z)) @ R, 1.0, instance_id=instance_id)


def test_plates_get_narrow_rim_pinches(inventory):
    for name in ("dinner_plate", "side_plate"):
        m = inventory.by_name(name)
        narrow = [g for g in m.grasps if g.name.startswith("rimnarrow")]
        assert len(narrow) == 12 * len(NARROW_ROLLS)
        for g in narrow:
            assert 0.0 < g.width < 0.02
            assert g.opening - g.width < 0.0165  # 8 mm of slack per pad
            # closing radially across the lip, the approach turned about the closing axis only
            radial = g.T_obj_tcp[:3, 3] * np.array([1.0, 1.0, 0.0])
            assert abs(g.T_obj_tcp[:3, 1] @ radial / np.linalg.norm(radial)) > 0.999
        rolls = {round(float(np.degrees(np.arccos(-g.T_obj_tcp[2, 2])))) for g in narrow}
        assert rolls == {abs(r) for r in NARROW_ROLLS}
    assert not any(g.name.startswith("rimnarrow") for g in inventory.by_name("cup").grasps)


@pytest.mark.parametrize("name", ["dinner_plate", "side_plate"])
def test_simulated_gripper_holds_the_plate_with_a_narrow_pinch(name, grasps_hold):
    grasps_hold(name, "rimnarrow", 5)


def test_a_plate_leaning_on_a_basin_wall_is_picked_with_a_narrow_pinch(planner, home, monkeypatch):
    plate = _leaning(planner, "side_plate", 0.43, 67.0)
    pick = planner.plan_pick(home, [plate], target=plate)
    assert pick.ok, str(pick)
    assert pick.grasp.spec.name.startswith("rimnarrow"), pick.grasp.spec.name
    checker = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
    assert all(r.ok for _, r in verify_pick(checker, planner, pick, [plate], step=0.003))
    # without the narrow pinches every grasp as given collides with the wall (the cause; without the last pass,
    # which turns a round item's grasps between their copies where none fits)
    monkeypatch.setattr(grasps_mod, "SPIN_STEPS", ())
    m = planner.inventory.by_name("side_plate")
    saved = m.grasps
    try:
        m.grasps = [g for g in saved if not g.name.startswith("rimnarrow")]
        grasps_mod._expanded.clear()
        res = planner.plan_pick(home, [plate], target=plate)
        assert not res.ok and res.kind == "no_collision_free_grasp", res
    finally:
        m.grasps = saved
        grasps_mod._expanded.clear()


def test_narrow_pinches_rank_after_the_standard_ones(planner, home, resting):
    """A plate lying free in the sink: standard pinches fit, so the narrow ones (less tolerant of pose error)
    come after them."""
    plate = resting("side_plate", (0.5, 0.0), 1)
    ranked = planner.select_grasps(home, [plate], target=plate)
    assert not isinstance(ranked, Exception) and len(ranked) > 1
    names = [g.spec.name for g in ranked]
    assert not names[0].startswith("rimnarrow"), names
    first_narrow = next((i for i, n in enumerate(names) if n.startswith("rimnarrow")), len(names))
    assert all(n.startswith("rimnarrow") for n in names[first_narrow:]), names
