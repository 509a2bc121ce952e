"""A grasp's joints are turned by whole turns for the way out from the arm's configuration and back to where it
returns between items (RobotModel.wrap_round_trip; Planner.q_rest, the last scan waypoint in a run), not only the
way out: nearest the arm alone, a wrist within ~pi of it either way was turned the way that left it a whole turn
from the scan waypoints, and the way back unwound it (3.4-8.1 s moves in sink-to-dishwasher runs)."""

from __future__ import annotations

import numpy as np


def test_round_trip_turns_a_joint_the_way_that_comes_back_short(planner, home):
    robot = planner.robot
    q = np.array([3.16, -1.84, 2.54, -2.35, -1.67, 4.41])  # the wrist nearest ref=1.43: 4.41 (2.98 away, -1.87 3.30)
    ref = q.copy()
    ref[5] = 1.43
    rest = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])
    assert np.array_equal(robot.wrap_near(q, ref), q)
    w = robot.wrap_round_trip(q, ref, rest)
    assert np.isclose(w[5], 4.41 - 2 * np.pi) and np.array_equal(w[:5], q[:5])
    assert np.allclose(robot.fk_tcp(w), robot.fk_tcp(q), atol=1e-9)
    assert np.array_equal(robot.wrap_round_trip(q, ref, ref), q)  # rest where the arm is: nearest, bitwise q


def test_round_trip_stays_inside_the_limits(planner):
    robot = planner.robot
    q = np.array([0.0, -1.5, 1.5, -1.5, -1.5, 1.0])
    ref, rest = q.copy(), q.copy()
    ref[5], rest[5] = 3.5, 6.2
    assert np.array_equal(robot.wrap_round_trip(q, ref, rest), q)  # 1 + 2 pi would come back shorter: outside
    q2 = np.array([0.0, -1.5, 3.0, -1.5, -1.5, 0.0])  # the elbow's +-pi range has no other turn
    assert np.array_equal(robot.wrap_round_trip(q2, q2, np.array([0.0, -1.5, -3.0, -1.5, -1.5, 0.0])), q2)


def test_round_trip_between_the_arm_and_rest_is_the_nearest(planner):
    """Every value between where the arm is and where it comes back to makes the same round trip: nearest wins."""
    robot = planner.robot
    q = np.array([0.0, -1.5, 1.5, -1.5, -1.5, 5.0])
    rest = q.copy()
    rest[5] = -6.0
    assert np.array_equal(robot.wrap_round_trip(q, q, rest), q)


def test_a_grasp_from_a_turned_wrist_is_taken_the_way_that_comes_back_short(planner, resting, home, monkeypatch):
    cup = resting("cup", (0.50, 0.0), 1)
    first = planner.select_grasps(home, [cup])
    assert isinstance(first, list) and first
    g0 = first[0]
    x = g0.q[5]
    assert abs(x) < np.pi
    s = 1.0 if x > 0 else -1.0
    a = x - s * 2 * np.pi  # its wrist turned by a whole turn: pi < |a| < 2 pi, inside the limits
    q_cur = home.copy()
    q_cur[5] = a + s * (np.pi - 0.6)  # the wrist's nearest turn of the grasp is `a`, a whole turn from home's 0
    by_name = {g.spec.name: g for g in planner.select_grasps(q_cur, [cup])}
    assert g0.spec.name in by_name and np.isclose(by_name[g0.spec.name].q[5], a)  # before: the way out only
    monkeypatch.setattr(planner, "q_rest", home)
    after = {g.spec.name: g for g in planner.select_grasps(q_cur, [cup])}
    g = after[g0.spec.name]
    assert np.isclose(g.q[5], x)  # turned towards home (0): |x| < |a|
    robot = planner.robot
    assert np.allclose(robot.fk_tcp(g.q), g0.T_base_tcp, atol=1e-6)
    assert np.max(np.abs(g.q_pregrasp - g.q)) < 1.0  # the pre-grasp follows the grasp's turn
