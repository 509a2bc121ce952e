"""Recovery strategies as data (executive/recovery_strategies.py): per failure kind, the strategies in order, each
with a precondition and a bounded number of tries per cycle; the one used is journaled and counted.

- A start within the margin right after a retreat (the tool let go of an item there): before, the escape's fallback
  retraced the retreat, back into where the item was let go (and out again, 47 times in one run). A retreat starts
  at a release: it is never retraced; the move fails with the reason of each strategy.
- A motion that started clear of contact is still retraced (as before).
- A slip during the lift: before, the arm stayed where the slip was seen, the tool among the items; now it goes on
  up along the rest of the lift (checked first), and the strategy is in the journal and the report.
"""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.failures import StepFailed, classify
from kitchenbot.planning.types import CartesianPathFailed, MovePlan, StartInCollision, Trajectory


def _stuck(real, escape=None):
    """A planner whose every move refuses the start (within the margin); plan_escape: `escape` or no way out."""

    class Stuck:
        def __getattr__(self, name):
            return getattr(real, name)

        def plan_move(self, q0, q1, **kw):
            return StartInCollision("test: within the margin", {"pairs": [("pad_b", "obj:7")]})

        def plan_escape(self, q0, objects=(), **kw):
            return escape(q0) if escape is not None else CartesianPathFailed("test: the tool is inside obj:7")

    return Stuck()


def _ran_then_stands_at_end(runner, name):
    """Run a motion named `name` from home to a pose 0.3 rad of the base away; the arm stands at its end."""
    home = np.asarray(runner.robot.config.robot.home, float)
    runner.arm.move_joints(home)
    q1 = home + np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])
    n = 60
    traj = Trajectory(np.linspace(0.0, 2.0, n), np.linspace(home, q1, n), name)
    runner._run_trajectory(traj)
    assert np.allclose(runner.arm.joint_positions(), q1, atol=1e-3)
    return home, q1


def _notes(runner, name):
    return [e for e in runner.journal.events(runner.run_id, kind="note") if e["name"] == name]


def test_a_refused_start_after_a_retreat_is_not_retraced_into_the_release(make_runner):
    runner, world = make_runner()
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    home, q_end = _ran_then_stands_at_end(runner, "retreat")  # it let go at `home`, retreated to q_end
    runner.planner = _stuck(runner.planner)
    with pytest.raises(StepFailed) as e:
        runner._move_joints(home + np.array([0.0, -0.2, 0.0, 0.0, 0.0, 0.0]), "scan waypoint 0")
    assert e.value.kind == "no_path"
    # it did not go back along the retreat to where the item was let go
    assert np.allclose(runner.arm.joint_positions(), q_end, atol=1e-3)
    why = e.value.details["escape"]
    assert "straight_out" in why and "retrace_last" in why and "retreat" in why
    assert "no way out of the margin" in str(e.value)
    assert runner.report.escapes == 0
    assert runner.report.recovery_strategies == {"start_in_collision/none": 1}


def test_a_refused_start_on_a_motion_from_a_free_pose_is_retraced_and_named(make_runner):
    runner, world = make_runner()
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    home, q_end = _ran_then_stands_at_end(runner, "approach")
    runner.planner = _stuck(runner.planner)
    assert runner._escape()
    assert np.allclose(runner.arm.joint_positions(), home, atol=1e-3)  # back to where the approach began
    assert runner.report.recovery_strategies == {"start_in_collision/retrace_last": 1}
    used = _notes(runner, "recovery strategy")
    assert [(u["payload"]["strategy"], u["payload"]["ok"]) for u in used] == [("straight_out", False), ("retrace_last", True)]


def test_escapes_are_bounded_per_cycle(make_runner):
    """The straight way out works every time here (the start is refused again after it): at most `tries` per
    cycle, then a clear reason; a new pick gives the tries back."""
    from kitchenbot.executive.recovery_strategies import STRATEGIES

    runner, world = make_runner()
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    home = np.asarray(runner.robot.config.robot.home, float)
    runner.arm.move_joints(home)
    step = np.array([0.02, 0.0, 0.0, 0.0, 0.0, 0.0])

    def out(q0):
        return MovePlan(Trajectory(np.linspace(0.0, 0.5, 10), np.linspace(q0, q0 + step, 10), "escape"))

    runner.planner = _stuck(runner.planner, escape=out)
    n = STRATEGIES["start_in_collision"][0].tries
    assert all(runner._escape() for _ in range(n))
    assert not runner._escape()  # the escape is the last motion: never retraced either
    assert runner.report.escapes == n
    runner.tracks.new_cycle()
    assert runner._escape()


def test_after_a_slip_in_the_lift_the_arm_goes_on_up_the_lift(make_runner):
    runner, world = make_runner(task="sink-pick")
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    attach = world.attach

    def attach_slipping(u, slip=True):  # its first hold slips in the next motion: the lift
        attach(u, slip)
        world.slip_in_motions = 0

    world.attach = attach_slipping
    assert [runner._do_scan(), runner._do_perceive(), runner._do_select_grasp(), runner._do_plan()] == [
        "scanned", "perceived", "selected", "planned"]
    lift = runner.item.pick.lift
    with pytest.raises(StepFailed) as e:
        runner._do_execute()
    assert e.value.kind == "slip" and "lift" in str(e.value)
    k = runner._index_on(lift)
    assert k is not None and 0 < k < len(lift) - 1  # stopped on the lift, among the items
    runner.failure = classify(e.value, "execute")
    runner._do_recover()
    moves = [c["payload"] for c in runner.journal.events(runner.run_id, kind="command")
             if c["name"] == "arm.execute_trajectory" and c["payload"]["name"] == "leave_lift"]
    assert len(moves) == 1  # from where it stopped on up to the lift's end (then back_out's rise, as before)
    assert np.allclose(moves[0]["q_start"], lift.q[k], atol=0.01) and np.allclose(moves[0]["q_end"], lift.q[-1])
    fk = runner.planner.robot.fk_tcp
    assert fk(runner.arm.joint_positions())[2, 3] >= fk(lift.q[-1])[2, 3] - 1e-3
    assert runner.arm.log.collisions == 0
    assert runner.report.recovery_strategies == {"slip/leave_along_lift": 1}
    assert runner.report.recovery_actions.get("leave_after_slip") == 1
