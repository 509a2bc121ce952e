"""A look straight down at a spot (a pick region, a target, a drop site) goes to the camera pose the arm reaches
soonest: the same view turned about its vertical axis, not the first turn in a fixed order (Motions._look_down_at)."""

from __future__ import annotations

import numpy as np


def _start_turned(runner, turn: float) -> np.ndarray:
    """The arm moved (planned) to home with its last joint turned by `turn` rad: the camera still looks down."""
    q = np.asarray(runner.robot.config.robot.home, float).copy()
    q[5] += turn
    runner._move_joints(q, "start")
    return runner.arm.joint_positions()


def test_the_look_down_goes_to_the_turn_nearest_the_arm(make_runner):
    runner, world = make_runner(task="sink-pick", cups=1)
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    lo, hi = world.cell.sink_interior
    site = (np.asarray(lo, float) + np.asarray(hi, float)) / 2
    q0 = _start_turned(runner, 2.6)
    assert runner._look_down_at(site) == ""
    q1 = runner.arm.joint_positions()
    moved = float(np.max(np.abs(q1 - q0)))
    # the first turn in the old fixed order (0 degrees) needs the last joint turned back by about 2.6 rad; the
    # view turned with the wrist needs much less (before this change the arm went to the 0-degree pose)
    assert moved < 2.0
    if hasattr(runner, "_look_down_poses"):  # the candidates, nearest first: the arm went to the first
        scene = runner.planner.scene(runner.belief.scene_objects(), runner.belief.map_points)
        options = runner._look_down_poses(site, runner.LOOK_DOWN_HEIGHTS[0], q0, scene)
        travel = [float(np.max(np.abs(q - q0))) for q in options]
        assert len(options) >= 2 and travel == sorted(travel)
        assert np.allclose(q1, options[0], atol=1e-3)
    # still straight down at the spot, from the first height
    T_cam = runner.arm.flange_pose() @ runner.robot.T_flange_cam
    assert T_cam[2, 2] < -0.999
    assert np.allclose(T_cam[:2, 3], site[:2], atol=0.005) and abs(T_cam[2, 3] - runner.LOOK_DOWN_HEIGHTS[0]) < 0.005
