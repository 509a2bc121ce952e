"""A scan waypoint (and the move back over the sink) stands for a camera pose: the arm goes to its joint values
turned by whole turns nearest where it stands, not unwinding a wrist by a full turn (executive/motion.py,
`_turned_near`)."""

from __future__ import annotations

import numpy as np


def _wound_at(runner, world, q_wp, turn=0.3):
    """The arm where `q_wp` puts the tool turned by `turn` (rad) about the last joint, that joint's value a whole
    turn away from the waypoint's (a release can leave it there: its IK branch is chosen near the arm's q)."""
    q = np.asarray(q_wp, float).copy()
    q[5] += turn - 2 * np.pi
    assert runner.planner.robot.within_limits(q)
    assert runner.planner.robot.within_limits(q_wp - np.array([0, 0, 0, 0, 0, 2 * np.pi]))  # the waypoint's pose there
    world.set_joints(q)
    return q


def _travel(traj) -> np.ndarray:
    return np.abs(np.diff(traj.q, axis=0)).sum(axis=0)


def test_the_scan_turns_the_wrist_the_short_way_to_the_same_camera_pose(make_runner):
    runner, world = make_runner(waypoints=1)
    runner.arm.connect()
    runner.gripper.connect()
    runner.camera.connect()
    wp = np.asarray(runner.robot.config.scan_waypoints[0], float)
    q0 = _wound_at(runner, world, wp)
    views = runner._scan()
    assert len(views) == 1
    traj = runner.tracks.last
    assert traj is not None and np.allclose(traj.q[0], q0)
    assert _travel(traj)[5] < 1.0  # before: 2*pi - 0.3 = 6.0 rad of wrist travel, back to the waypoint's value
    robot = runner.planner.robot
    q_end = runner.arm.joint_positions()
    assert np.allclose(robot.fk_tcp(q_end), robot.fk_tcp(wp), atol=1e-6)  # the waypoint's pose, so its view
    assert np.allclose(views[0].T_base_cam[:3, 3], (robot.fk_tcp(wp) @ np.linalg.inv(robot.T_flange_tcp)
                                                    @ runner.robot.T_flange_cam)[:3, 3], atol=1e-4)


def test_back_over_the_sink_turns_the_wrist_the_short_way(make_runner):
    runner, world = make_runner(waypoints=1)
    runner.arm.connect()
    runner.gripper.connect()
    wp = np.asarray(runner.robot.config.scan_waypoints[-1], float)
    _wound_at(runner, world, wp, turn=-0.4)
    runner._back_over_the_sink()
    traj = runner.tracks.last
    assert traj is not None
    assert _travel(traj)[5] < 1.0  # before: 2*pi + 0.4 = 6.7 rad (the waypoint's value)
    robot = runner.planner.robot
    assert np.allclose(robot.fk_tcp(runner.arm.joint_positions()), robot.fk_tcp(wp), atol=1e-6)


def test_a_waypoint_already_nearest_is_asked_as_it_is(make_runner):
    runner, world = make_runner(waypoints=1)
    runner.arm.connect()
    wp = np.asarray(runner.robot.config.scan_waypoints[0], float)
    world.set_joints(wp + np.array([0.3, 0.0, 0.0, 0.0, 0.0, -0.4]))
    assert np.array_equal(runner._turned_near(wp), wp)  # bitwise: no turn, the configured values
