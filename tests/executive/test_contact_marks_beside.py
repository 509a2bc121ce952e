"""Contact marks that block a move's start: only those the arm's own bodies stand in go. A stopped lift of a cup
from a stack marks what the held cup was about to sweep (the unperceived cup above it); the cup let go there lies
in those marks too. The tool stands among them, within the margin of the marks at its pads: the move to the
next scan waypoint was planned without every mark within 12 cm of the arm, and went straight up through the cup
they marked (a protective stop during the scan). Now the marks beside the tool stay and the move keeps clear."""

from __future__ import annotations

import numpy as np

from kitchenbot.drivers.errors import ProtectiveStopError
from kitchenbot.transforms import make_T
from kitchenbot.world.gripper import MAX_OPENING, PAD_ENVELOPE


def _tilted_tool(runner, world, p):
    """The tool at `p` pointing down 45 degrees towards the robot's side of the sink, closing axis horizontal,
    pads open: as after a tilted side grasp low in a stack."""
    t = np.radians(45.0)
    z, y = np.array([-np.cos(t), 0.0, -np.sin(t)]), np.array([0.0, -1.0, 0.0])
    R = np.column_stack([np.cross(y, z), y, z])
    q = runner.planner.robot.ik_q(make_T(R, p), runner.arm.joint_positions())
    assert q is not None
    world.set_joints(q)
    return q


def test_marks_beside_the_tool_stay_when_those_at_it_go(make_runner):
    runner, world = make_runner(cups=1)
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    b = runner.belief
    _tilted_tool(runner, world, np.array([0.45, 0.0, -0.08]))
    T = runner.arm.tcp_pose()
    uid = max(world.objects)
    # the cup upright just over the pads' upper side (on the stack below it, which plays no part here), 2 cm
    # clear of them: outside the arm's margin, inside the 12 cm the marks used to go within
    world.set_pose(uid, make_T(np.eye(3), T[:3, 3] - 0.07 * T[:3, 0]))
    cup = world.objects[uid]
    T_cup = cup.T_base_obj
    on_cup = cup.model.points @ T_cup[:3, :3].T + T_cup[:3, 3]
    gap = np.array([[x, y, z] for x in (-0.01, 0.0, 0.01) for y in (-MAX_OPENING / 4, 0.0, MAX_OPENING / 4)
                    for z in (-0.04, -0.02, 0.0)])  # the held cup's sliver left between the open pads
    b.mark_contact(np.vstack([gap @ T[:3, :3].T + T[:3, 3], on_cup]))
    waypoint = np.asarray(runner.robot.config.scan_waypoints[0], float)
    plan = runner.planner.plan_move(runner.arm.joint_positions(), waypoint, objects=b.scene_objects(),
                                    map_points=b.map_points)
    assert plan.kind == "start_in_collision"  # the situation: the marks block the start

    try:
        runner._move_joints(waypoint, "scan waypoint 0")
    except ProtectiveStopError as e:
        raise AssertionError(f"the move ran into what the marks showed: {e}")

    assert np.allclose(runner.arm.joint_positions(), waypoint, atol=1e-3)
    left = b.contact_points
    assert len(left) >= 0.8 * len(on_cup)  # the cup's marks stayed
    assert not runner.planner.points_at_robot(runner.arm.joint_positions(), left).any()


def test_points_at_robot_are_those_within_the_margin_of_its_bodies(make_runner):
    runner, world = make_runner(cups=1)
    runner.arm.connect()
    q = runner.arm.joint_positions()
    T = runner.arm.tcp_pose()
    margin = runner.planner.world.margin
    vs = runner.planner.world.voxel_size
    at_pad = T[:3, :3] @ np.array([0.0, MAX_OPENING / 2 + PAD_ENVELOPE.thickness / 2, -0.03]) + T[:3, 3]
    ahead = T[:3, :3] @ np.array([0.0, 0.0, PAD_ENVELOPE.tip + margin + 2 * vs]) + T[:3, 3]  # past the pad tips
    away = np.array([-0.3, 0.6, 0.1])
    assert runner.planner.points_at_robot(q, np.array([at_pad, ahead, away])).tolist() == [True, False, False]
