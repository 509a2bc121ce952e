"""A lift stopped by something nobody perceived (here a bowl held upside down over the sink, left out of
perception): a put-down planned from where the lift stopped starts right against it, and its first move met the
same thing again (a second protective stop). Instead the arm goes back down the lift (the way it came, free in the
world as it is), lets go where the item was taken from and keeps the lift's direction for the next try
(executive/recovery.py, back_off)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.drivers.errors import ProtectiveStopError
from kitchenbot.executive.assembly import assemble, make_sim_world
from kitchenbot.executive.failures import StepFailed, classify
from kitchenbot.executive.runner import RunOptions
from kitchenbot.executive.session import build_runner
from kitchenbot.fakes.placement import drop_onto


@pytest.fixture
def hidden_over(small_config, tmp_path):
    cfg = small_config()
    world = make_sim_world(cfg, 0)
    inv = world.inventory
    for u in list(world.objects):
        world.remove_object(u)
    cup = next(m for m in inv if m.cls == "cup")
    plate = next(m for m in inv if m.cls == "plate")
    c = world.cell.spec.sink.centre_xy
    T = np.eye(4)
    T[:3, 3] = (c[0], c[1], 0.0)
    item = world.add_object(cup, T)
    world.set_pose(item, drop_onto(world, item, T))
    hidden = []
    attach = world.attach

    def attach_then_hide(uid, slip=True):
        """Once the cup is held, a plate nobody perceived overhangs the cup's far side 3 cm over its rim, clear of
        the gripper: the lift brings the held cup's rim into it."""
        attach(uid, slip=False)
        if not hidden:
            T_cup = world.objects[uid].T_base_obj
            d = T_cup[:2, 3] - world.T_base_tcp()[:2, 3]
            d = d / max(np.linalg.norm(d), 1e-9)
            r_cup, r_plate = cup.extents[0] / 2, plate.extents[0] / 2
            Tp = np.eye(4)
            Tp[:2, 3] = T_cup[:2, 3] + d * (r_cup - 0.02 + r_plate)
            Tp[2, 3] = T_cup[2, 3] + cup.extents[2] + 0.03
            hidden.append(world.add_object(plate, Tp))

    world.attach = attach_then_hide
    robot = assemble(cfg, world=world)
    runner = build_runner(cfg, "sink-pick", 0, robot=robot, oracle_perception=True,
                          journal_path=tmp_path / "journal.sqlite",
                          options=RunOptions(poll_period=0.05, confirm_empty_scans=1))
    perceive = runner.perceiver.perceive

    def without_hidden(views):
        r = perceive(views)
        r.poses = [p for p in r.poses if p.instance_id not in hidden]
        return r

    runner.perceiver.perceive = without_hidden
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    return runner, world, item, hidden


def test_the_put_down_after_a_stopped_lift_does_not_meet_the_same_thing(hidden_over):
    runner, world, item, hidden = hidden_over
    assert [runner._do_scan(), runner._do_perceive(), runner._do_select_grasp(), runner._do_plan()] == [
        "scanned", "perceived", "selected", "planned"]
    taken_from = world.objects[item].T_base_obj[:3, 3].copy()
    with pytest.raises((StepFailed, ProtectiveStopError)) as e:
        runner._do_execute()
    runner.failure = classify(e.value, "execute")
    assert runner.failure.kind == "protective_stop" and "held hits" in str(e.value)
    assert runner.tracks.stopped is not None and runner.tracks.stopped.name == "lift"
    log = runner.arm.log
    before = log.protective_stops
    runner._do_recover()
    assert log.protective_stops == before, [ev for ev in log.events if ev.kind in ("protective_stop", "collision")]
    assert world.held_uid is None
    assert np.linalg.norm(world.objects[item].T_base_obj[:2, 3] - taken_from[:2]) < 0.01  # let go where it was
    # and the lift's direction is kept for the next try (it lifts the cup otherwise); nothing is marked where the
    # cup stands again (tests/executive/test_stopped_lift_own_marks.py)
    assert len(runner.belief.stopped_lifts(runner.item.obj)) == 1 and len(runner.belief.contact_points) == 0


def test_a_lift_stopped_within_the_release_height_needs_no_retrace(hidden_over):
    """Stopped a millimetre into its lift (less than RELEASE_ABOVE from its start), the way back "short of the start"
    is no motion at all. Before, a one-sample trajectory went to the arm, which the safety layer refused as a limit
    violation, and the run gave up."""
    from kitchenbot.planning.types import Trajectory

    runner = hidden_over[0]
    q0 = runner.arm.joint_positions().copy()
    q1, q2 = q0.copy(), q0.copy()
    q1[1] += 0.002  # the tool ~1 mm along
    q2[1] += 0.05
    fk = runner.planner.robot.fk_tcp
    assert np.linalg.norm(fk(q1)[:3, 3] - fk(q0)[:3, 3]) < runner.RELEASE_ABOVE
    runner.arm.move_joints(q1)
    lift = Trajectory(np.array([0.0, 0.1, 1.0]), np.array([q0, q1, q2]), "lift")
    assert runner._retrace(lift, "back_off", short_of=runner.RELEASE_ABOVE)
    assert np.allclose(runner.arm.joint_positions(), q1, atol=1e-6)  # nothing moved
