"""After a protective stop: the space the pads were about to enter is marked as an obstacle (map points no object
explains), kept outside the sink, dropped inside it once an item has been placed (the sink changed)."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.types import Trajectory


def _inside(P, T_base_box, size, pad=0.0):
    L = (P - T_base_box[:3, 3]) @ T_base_box[:3, :3]
    return np.all(np.abs(L) <= np.asarray(size) / 2 + pad, axis=1)


def test_a_stop_marks_the_space_the_pads_were_about_to_enter(make_runner):
    runner, world = make_runner()
    runner.arm.connect()
    runner.gripper.connect()
    robot, g = runner.planner.robot, runner.planner.world.gripper
    q0 = np.asarray(runner.robot.config.robot.home, float)
    q1 = q0 + np.array([0.6, 0.0, 0.0, 0.0, 0.0, 0.0])  # swing the base: the tool sweeps sideways
    n = 200
    traj = Trajectory(np.linspace(0.0, 4.0, n), np.linspace(q0, q1, n), "move")
    k = 80
    world.set_joints(traj.q[k])  # "stopped" here
    b = runner.belief
    b.set_map_base(None)
    runner._mark_contact(traj)
    P = b.contact_points
    assert len(P) > 10 and b.map_points is not None and len(b.map_points) == len(P)
    opening = runner.gripper.opening()
    F = robot.fk_tcp(traj.q[k]) @ np.linalg.inv(robot.T_flange_tcp)
    for tb in g.pads(robot.T_flange_tcp, opening):  # not where the pads are now...
        assert not _inside(P, F @ tb.T_flange_box, tb.size).any()
    tcp_now = robot.fk_tcp(traj.q[k])[:3, 3]
    assert np.max(np.linalg.norm(P - tcp_now, axis=1)) < 0.15  # ...but right ahead of them
    moved = robot.fk_tcp(traj.q[k + 5])[:3, 3] - tcp_now
    assert (P.mean(axis=0) - tcp_now) @ moved > 0  # on the side the tool was moving to

    lo, hi = runner.robot.cell.sink_interior
    in_sink = np.array([[(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, -0.1]])
    runner._add_contact_marks(in_sink)
    fresh = np.zeros((5, 3))
    b.perceived([], fresh, [], (lo, hi))
    assert len(b.map_points) == 5 + len(P) + 1  # nothing placed since: every mark is kept
    b.scene_changed()  # an item was placed: the sink changed, its marks go with the next perception; the others stay
    b.perceived([], fresh, [], (lo, hi))
    sink_pts = np.all(P[:, :2] >= lo[:2], axis=1) & np.all(P[:, :2] <= hi[:2], axis=1)
    assert len(b.map_points) == 5 + int((~sink_pts).sum())


def test_a_move_whose_search_timed_out_is_planned_again_with_a_longer_budget(make_runner):
    """RRT-Connect stops at its wall-clock budget (a narrow way, a loaded computer): the next try of that move
    gets TIMEOUT_GROWTH times the budget, not the same one again (that left the arm unable to reach any scan
    waypoint, and the run gave up)."""
    from kitchenbot.planning.types import PlannerTimeout

    runner, world = make_runner()
    runner.arm.connect()
    runner.gripper.connect()
    real = runner.planner
    asked = []

    class ShortBudget:  # a search that needs twice the configured budget
        def __getattr__(self, name):
            return getattr(real, name)

        def plan_move(self, q0, q1, *, timeout_scale=1.0, **kw):
            asked.append(timeout_scale)
            if timeout_scale < 2.0:
                return PlannerTimeout("test: the search needs twice the budget")
            return real.plan_move(q0, q1, timeout_scale=timeout_scale, **kw)

    runner.planner = ShortBudget()
    q = np.asarray(runner.robot.config.scan_waypoints[0], float)
    runner._move_joints(q, "scan waypoint 0")
    assert asked == [1.0, runner.TIMEOUT_GROWTH]
    assert np.max(np.abs(runner.arm.joint_positions() - q)) < 1e-3


def test_a_scan_waypoint_with_no_path_from_here_is_reached_by_way_of_home(make_runner):
    """A place can leave the arm on another IK branch, from where a bounded search finds no way to a scan waypoint
    while one to home exists: the scan goes there by way of home instead of giving up."""
    from kitchenbot.planning.types import PlannerTimeout

    runner, world = make_runner()
    runner.arm.connect()
    runner.gripper.connect()
    real = runner.planner
    home = np.asarray(runner.robot.config.robot.home, float)
    wp = np.asarray(runner.robot.config.scan_waypoints[0], float)
    far = wp + np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])  # somewhere else, not home
    plan = real.plan_move(world.q.copy(), far)
    assert plan.ok, plan
    runner._run_trajectory(plan.trajectory)
    legs = []

    class NoWayFromHere:  # from anywhere but home, no path to the waypoint is found
        def __getattr__(self, name):
            return getattr(real, name)

        def plan_move(self, q0, q1, **kw):
            legs.append((np.allclose(q0, home, atol=1e-3), np.allclose(q1, wp, atol=1e-3)))
            if np.allclose(q1, wp, atol=1e-3) and not np.allclose(q0, home, atol=1e-3):
                return PlannerTimeout("test: no path found within the budget")
            return real.plan_move(q0, q1, **kw)

    runner.planner = NoWayFromHere()
    runner._move_joints_via(wp, "scan waypoint 0", home)
    assert np.max(np.abs(runner.arm.joint_positions() - wp)) < 1e-3
    assert legs[-2:] == [(False, False), (True, True)]  # to home, then from home to the waypoint
    assert runner.arm.log.collisions == 0


def test_a_start_within_the_margin_is_planned_again_with_the_pads_where_they_are_and_the_pairs_reported(make_runner):
    """A start within the margin (the pads, planned fully open, beside items the gripper let go among): the move
    is planned again with the gripper's real opening (planning.leave checks the way out with it); when the arm
    still cannot move, the failure names the pairs that block it (the run's report shows them)."""
    import pytest

    from kitchenbot.executive.failures import StepFailed
    from kitchenbot.planning.types import CartesianPathFailed, StartInCollision

    runner, world = make_runner()
    runner.arm.connect()
    runner.gripper.connect()
    real = runner.planner
    runner.gripper.open(0.03)
    home = np.asarray(runner.robot.config.robot.home, float)
    openings = []

    class Stuck:
        def __getattr__(self, name):
            return getattr(real, name)

        def plan_move(self, q0, q1, **kw):
            openings.append(kw.get("opening"))
            return StartInCollision("test: within the margin", {"pairs": [("pad_b", "obj:7"), ("pad_a", "obj:8")]})

        def plan_escape(self, q0, objects=(), **kw):
            return CartesianPathFailed("test: no straight way out")

    runner.planner = Stuck()
    with pytest.raises(StepFailed) as e:
        runner._move_joints(home + np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), "home")
    assert e.value.kind == "no_path"
    assert e.value.details["blocking_pairs"] == [["pad_b", "obj:7"], ["pad_a", "obj:8"]]
    assert openings[0] is None and openings[1] == pytest.approx(runner.gripper.opening())
    assert runner.arm.log.collisions == 0
