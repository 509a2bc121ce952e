"""Planner entry points end to end: pick and place plans whose every segment the independent FCL checker
confirms, unreachable targets as typed failures."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.fcl_check import FclChecker, verify_pick, verify_place
from kitchenbot.planning.placement import SlotBook
from kitchenbot.planning.types import InvalidInput, NoIK, PickPlan, PlacePlan
from kitchenbot.transforms import make_T


@pytest.fixture(scope="module")
def checker(planner):
    return FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)


def test_pick_and_place_a_cup_into_the_upper_rack(planner, home, cup_for_the_upper_rack, checker):
    # upside down in the sink: a grasp from above keeps coming from above when it goes upside down into the rack
    cup, objs, targets = cup_for_the_upper_rack
    pick = planner.plan_pick(home, objs, target=cup, place_target=targets)
    assert isinstance(pick, PickPlan), pick
    assert pick.grasp.obj is cup
    for t in pick.trajectories:
        planner.limits.check_trajectory(planner.robot.ur, t.times, t.q)
    np.testing.assert_allclose(pick.approach.end, pick.grasp_in.start)
    np.testing.assert_allclose(pick.grasp_in.end, pick.lift.start)
    assert planner.robot.fk_tcp(pick.lift.end)[2, 3] - pick.grasp.T_base_tcp[2, 3] == pytest.approx(
        planner.settings.lift_height, abs=1e-3)
    for name, r in verify_pick(checker, planner, pick, objs, step=0.004):
        assert r.ok, (name, str(r))
    place = planner.plan_place(pick.end, pick.grasp, targets, objects=objs)
    assert isinstance(place, PlacePlan), place
    for t in place.trajectories:
        planner.limits.check_trajectory(planner.robot.ur, t.times, t.q)
    # the object ends in the slot (upside down), the TCP where the grasp puts it
    assert place.T_base_obj[2, 2] < -0.99
    np.testing.assert_allclose(place.T_base_obj @ pick.grasp.T_obj_tcp, place.T_base_tcp, atol=1e-9)
    np.testing.assert_allclose(planner.robot.fk_tcp(place.lower.end), place.T_base_tcp, atol=1e-4)
    for name, r in verify_place(checker, planner, place, pick.grasp, objs, step=0.004):
        assert r.ok, (name, str(r))


def test_upright_cup_on_the_sink_floor_cannot_go_straight_to_the_rack(planner, home, resting):
    """Tilted grasps reach it, but none of them can invert it into the rack from above: a typed failure that
    tells the task to regrasp (via the drop zone); without the placement constraint it is pickable."""
    cup = resting("cup", (0.50, -0.05), 1)
    targets = SlotBook(planner.cell).targets_for(planner.inventory[cup.obj_id])[:3]
    res = planner.plan_pick(home, [cup], place_target=targets)
    assert res.kind == "no_feasible_placement", res
    assert planner.plan_pick(home, [cup]).ok
    upright = SlotBook(planner.cell).targets_for(planner.inventory[cup.obj_id], inverted=False)[:3]
    assert planner.plan_pick(home, [cup], place_target=upright).ok  # the documented fallback


def test_unreachable_object_gives_no_ik(planner, home):
    m = planner.inventory.by_name("cup")
    far = ObjectPose(m.obj_id, m.cls, make_T(t=(1.6, 0.0, 0.05)), 1.0, instance_id=9)
    res = planner.plan_pick(home, [far])
    assert isinstance(res, NoIK), res
    assert not res.ok and res.kind == "no_ik"


def test_bad_input_is_a_typed_failure(planner, home, resting):
    assert isinstance(planner.plan_pick(np.zeros(5), [resting("cup", (0.5, 0.0), 1)]), InvalidInput)
    assert isinstance(planner.plan_move(home, np.full(6, np.nan)), InvalidInput)
    cup = resting("cup", (0.5, 0.0), 1)
    targets = SlotBook(planner.cell).targets_for(planner.inventory[cup.obj_id])[:2]
    assert isinstance(planner.plan_pick(home, [cup], place_target=[targets]), InvalidInput)  # a list of lists


def test_plan_move_to_scan_waypoints(planner, cfg, home, checker):
    for q in cfg.scan_waypoints:
        res = planner.plan_move(home, np.asarray(q))
        assert res.ok, res
        planner.limits.check_trajectory(planner.robot.ur, res.trajectory.times, res.trajectory.q)
        assert checker.check_path(res.trajectory.q[:: max(1, len(res.trajectory.q) // 50)], step=0.004).ok


def test_cup_staged_upright_on_the_counter_goes_inverted_into_the_rack(planner, home, resting, checker):
    """The regrasp route for an upright cup: on the counter a nearly level side grasp (5 degrees from above)
    keeps the wrist clear of the counter and still approaches from above once the cup is upside down
    (released a few centimetres over the rack rails)."""
    cup = resting("cup", (0.12, 0.62), 1, z_floor=0.0)
    targets = SlotBook(planner.cell).targets_for(planner.inventory[cup.obj_id])[:3]
    pick = planner.plan_pick(home, [cup], place_target=targets)
    assert pick.ok, pick
    place = planner.plan_place(pick.end, pick.grasp, targets)
    assert place.ok, place
    assert place.T_base_obj[2, 2] < -0.99
    assert 0.0 <= place.release_drop <= planner.settings.max_release_drop + 1e-9
    for name, r in verify_place(checker, planner, place, pick.grasp, [cup], step=0.004):
        assert r.ok, (name, str(r))


def test_grasps_whose_place_failed_are_not_offered_again(planner, home, resting):
    cup = resting("cup", (0.5, 0.0), 1)
    first = planner.plan_pick(home, [cup], target=cup)
    assert first.ok, first
    other = planner.plan_pick(home, [cup], target=cup, avoid_grasps=(first.grasp.spec.name,))
    assert other.ok, other
    assert other.grasp.spec.name.split("_tilt")[0] != first.grasp.spec.name.split("_tilt")[0]  # nor its tilted variants
