"""Lifting an item out of a neighbour its estimated pose overlaps, and naming the item that blocks a pick."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.fcl_check import FclChecker, verify_pick
from kitchenbot.planning.pick_place import LIFT_CLEAR_TRAVEL, LIFT_CONTACT_TRAVEL
from kitchenbot.transforms import make_T


def _on(planner, name: str, below: ObjectPose, instance_id: int, sink: float = 0.0, dx: float = 0.0) -> ObjectPose:
    """`name` standing upright on top of `below` (its bounding box), sunk `sink` metres into it, `dx` off its
    axis."""
    m = planner.inventory.by_name(name)
    mb = planner.inventory[below.obj_id]
    p = np.asarray(below.T_base_obj, float)[:3, 3]
    z = p[2] + mb.extents[2] / 2 + m.extents[2] / 2 - sink
    return ObjectPose(m.obj_id, m.cls, make_T(t=(p[0] + dx, p[1], z)), 1.0, instance_id=instance_id)


def test_an_item_overlapping_its_support_by_4_cm_is_lifted_out(planner, home, resting):
    """A glass perceived 4 cm deep in the cup, through its wall (pose error): the contact lasts past the first 3 cm
    of the lift but clears for good before LIFT_CLEAR_TRAVEL; the FCL re-check gets the longer window."""
    cup = resting("cup", (0.50, -0.02), 1)
    glass = _on(planner, "glass", cup, 2, sink=0.04, dx=0.035)
    pick = planner.plan_pick(home, [cup, glass], target=glass)
    assert pick.ok, str(pick)
    assert LIFT_CONTACT_TRAVEL < pick.lift_contact_travel <= LIFT_CLEAR_TRAVEL
    checker = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
    assert all(r.ok for _, r in verify_pick(checker, planner, pick, [cup, glass], step=0.003))
    # a contact that lasts longer than LIFT_CLEAR_TRAVEL is not lifted through
    deep = _on(planner, "glass", cup, 2, sink=LIFT_CLEAR_TRAVEL + 0.01, dx=0.035)
    res = planner.plan_pick(home, [cup, deep], target=deep)
    assert not res.ok and res.kind == "cartesian_path_failed", res


def test_a_pick_blocked_by_an_item_lying_on_it_names_that_item(planner, home, resting):
    plate = resting("side_plate", (0.45, 0.0), 7)
    cup = _on(planner, "cup", plate, 9, sink=0.015)  # stands in the plate's well
    res = planner.plan_pick(home, [plate, cup], target=plate)
    assert not res.ok
    assert res.details.get("blocking") == 9, (res, res.details)
    assert res.details["blocking_all"][0] == (9, "cup")
    # the cup itself is not blocked by the plate it stands on
    assert planner.plan_pick(home, [plate, cup], target=cup).ok
    assert planner._lies_on(cup, plate) and not planner._lies_on(plate, cup)


def test_a_held_item_that_cannot_leave_is_tried_with_one_grasp_only(planner, home, resting):
    """Every lift direction depends on the item, not on the grasp: when the item itself runs into something in
    every direction, the other grasp candidates are not tried (they would fail the same way)."""
    plate = resting("side_plate", (0.45, 0.0), 7)
    cup = _on(planner, "cup", plate, 9, sink=0.015)
    res = planner.plan_pick(home, [plate, cup], target=plate)
    if res.kind == "cartesian_path_failed":  # (no_collision_free_grasp when no grasp of the plate fits at all)
        assert res.details["candidates_tried"] == 1
        assert all("held" in p for p in res.details["pairs"])


def test_lift_directions_away_from_what_the_lift_ran_into(planner, resting):
    cup = resting("cup", (0.50, 0.0), 1)
    glass = resting("glass", (0.55, 0.03), 2)
    centre = cup.T_base_obj[:3, 3]
    up = [np.array([0.0, 0.0, 1.0])]
    ds = planner._lift_directions_away(centre, [cup, glass], {"2"}, up)
    away = (centre - glass.T_base_obj[:3, 3])[:2]
    assert len(ds) == 6
    for d in ds:
        assert abs(np.linalg.norm(d) - 1) < 1e-9
        assert d[:2] @ away > 0  # away from the glass
        assert np.degrees(np.arccos(d[2])) in (pytest.approx(30.0), pytest.approx(45.0))
    assert planner._lift_directions_away(centre, [cup, glass], {"nothing"}, up) == []


def test_items_on_lists_what_lies_on_the_target(planner, resting):
    plate = resting("side_plate", (0.45, 0.0), 7)
    cup = _on(planner, "cup", plate, 9, sink=0.015)
    glass = resting("glass", (0.62, 0.10), 11)  # beside, not on it
    assert [o.instance_id for o in planner.items_on(plate, [plate, cup, glass])] == [9]
    assert planner.items_on(cup, [plate, cup, glass]) == []


def test_an_item_lifted_along_a_basin_wall_is_moved_clear_of_it(planner, home, resting):
    """An upside-down bowl 4 mm from a basin wall, glasses around it (no tilted lift fits): lifted straight up it
    stays 4 mm from the wall, inside the 1 cm transport margin, so the lift goes on 2-4 cm towards the sink's
    middle (sink-pick seed 16); without that move there is no pick. The FCL re-check passes the whole lift."""
    bowl_m, glass_m = planner.inventory.by_name("bowl"), planner.inventory.by_name("glass")
    _, hi = planner.cell.sink_interior
    r, rg = bowl_m.extents[0] / 2, glass_m.extents[0] / 2
    y = hi[1] - r - 0.004
    bowl = resting("bowl", (0.6, y), 1, upside_down=True)
    glasses = [resting("glass", (0.6 + dx, y - r - rg - 0.01), 10 + i) for i, dx in enumerate((-0.08, 0.0, 0.08))]
    glasses += [resting("glass", (0.6 + s * (r + rg + 0.01), y), 20 + i) for i, s in enumerate((-1, 1))]
    objects = [bowl, *glasses]
    pick = planner.plan_pick(home, objects, target=bowl)
    assert pick.ok, str(pick)
    p0, p1 = (planner.robot.fk_tcp(q)[:3, 3] for q in (pick.lift.q[0], pick.lift.q[-1]))
    assert p1[1] < p0[1] - 0.015  # moved away from the wall (y = hi[1])
    checker = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
    assert all(r.ok for _, r in verify_pick(checker, planner, pick, objects, step=0.003))
    saved = planner.LIFT_CLEAR_MOVES
    try:
        planner.LIFT_CLEAR_MOVES = ()
        res = planner.plan_pick(home, objects, target=bowl)
        assert not res.ok and res.kind == "cartesian_path_failed", res
    finally:
        del planner.LIFT_CLEAR_MOVES
    assert planner.LIFT_CLEAR_MOVES == saved
