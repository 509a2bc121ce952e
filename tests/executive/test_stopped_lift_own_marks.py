"""A bowl's straight-up lift is cut short by a protective stop; recovery backs down the lift and lets the bowl go
where it was taken. Before, what the lift was about to sweep was marked: the bowl's rim and floor 15 mm up and the
pads' boxes there, i.e. the space the bowl's own next grasp and lift need (what the lift met may lie anywhere along
the bowl: a foot under a plate's flange, 5 cm below those marks). Every grasp of the bowl collided with the marks,
and the failure named a neighbour, not them. Now the bowl keeps the stopped lift's direction instead
(Belief.record_stopped_lift): a grasp plans, and its lift goes another way (planning.lift.lift_fallbacks); and a
grasp selection blocked by map points no item explains says so (planning.grasps._crowded_by counts the voxels)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.drivers.errors import ProtectiveStopError
from kitchenbot.executive.assembly import assemble, make_sim_world
from kitchenbot.executive.failures import StepFailed, classify
from kitchenbot.executive.runner import RunOptions
from kitchenbot.executive.session import build_runner
from kitchenbot.fakes.placement import drop_onto
from kitchenbot.planning.lift import STOPPED_LIFT_ANGLE
from kitchenbot.planning.types import MapPoints


@pytest.fixture
def bowl_runner(small_config, tmp_path):
    """A runner (oracle perception, sink-pick) over one bowl resting on the sink floor, in the middle."""
    cfg = small_config()
    world = make_sim_world(cfg, 0)
    for u in list(world.objects):
        world.remove_object(u)
    bowl = next(m for m in world.inventory if m.cls == "bowl")
    c = world.cell.spec.sink.centre_xy
    T = np.eye(4)
    T[:3, 3] = (c[0], c[1], 0.0)
    uid = world.add_object(bowl, T)
    world.set_pose(uid, drop_onto(world, uid, T))
    runner = build_runner(cfg, "sink-pick", 0, robot=assemble(cfg, world=world), oracle_perception=True,
                          journal_path=tmp_path / "journal.sqlite",
                          options=RunOptions(poll_period=0.05, confirm_empty_scans=1))
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    return runner, world, uid


def _direction(planner, lift) -> np.ndarray:
    """The unit direction of a lift's first 15 mm of tool travel (base frame)."""
    fk = planner.robot.fk_tcp
    p0 = fk(lift.q[0])[:3, 3]
    for q in lift.q[1:]:
        d = fk(q)[:3, 3] - p0
        if np.linalg.norm(d) >= 0.015:
            break
    return d / np.linalg.norm(d)


def test_a_stopped_lift_released_in_place_leaves_its_item_graspable_and_lifts_it_otherwise(bowl_runner):
    runner, world, uid = bowl_runner
    assert [runner._do_scan(), runner._do_perceive(), runner._do_select_grasp(), runner._do_plan()] == [
        "scanned", "perceived", "selected", "planned"]
    bowl = runner.item.obj
    up = _direction(runner.planner, runner.item.pick.lift)
    assert up[2] > np.cos(STOPPED_LIFT_ANGLE / 2), up  # the situation: a lift straight up
    taken_from = world.objects[uid].T_base_obj[:3, 3].copy()

    grasp = runner.gripper.grasp

    def grasp_then_stop(limit, timeout=3.0):
        res = grasp(limit, timeout)
        world.faults.protective_stop = 1  # the lift, the next motion, stops halfway holding the bowl
        return res

    runner.gripper.grasp = grasp_then_stop
    with pytest.raises((StepFailed, ProtectiveStopError)) as e:
        runner._do_execute()
    runner.gripper.grasp = grasp
    runner.failure = classify(e.value, "execute")
    assert runner.failure.kind == "protective_stop" and runner.tracks.stopped.name == "lift"
    old_marks = runner._contact_sliver(runner.tracks.stopped)  # what was marked before
    runner._do_recover()
    assert world.held_uid is None
    assert np.linalg.norm(world.objects[uid].T_base_obj[:3, 3] - taken_from) < 0.01  # let go where it was

    # before: with the sliver marked, every grasp of the bowl collides with the marks, and the failure says so
    objs = runner.belief.scene_objects()
    q = runner.arm.joint_positions()
    before = runner.planner.plan_pick(q, objs, target=bowl, map_points=MapPoints.of(old_marks, len(old_marks)))
    assert not before.ok and before.kind == "no_collision_free_grasp", str(before)
    assert before.details["blocked_by_voxels"] > 0 and "no perceived item explains" in before.message

    # now: nothing marked; the bowl keeps the stopped lift's direction, and the next plan lifts it another way
    assert len(runner.belief.contact_points) == 0
    stopped = runner.belief.stopped_lifts(bowl)
    assert len(stopped) == 1 and float(stopped[0] @ up) > np.cos(STOPPED_LIFT_ANGLE / 2)
    runner.failure = None
    assert [runner._do_scan(), runner._do_perceive(), runner._do_select_grasp(), runner._do_plan()] == [
        "scanned", "perceived", "selected", "planned"]
    again = _direction(runner.planner, runner.item.pick.lift)
    assert float(again @ up) < np.cos(STOPPED_LIFT_ANGLE), again
    stops = runner.arm.log.protective_stops
    runner._do_execute()  # and it is lifted that way, and placed, without meeting anything
    assert runner.arm.log.protective_stops == stops and runner.arm.log.collisions == 0
    assert world.held_uid is None and np.linalg.norm(world.objects[uid].T_base_obj[:2, 3] - taken_from[:2]) > 0.2
