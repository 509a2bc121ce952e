"""An item that slipped out over the cell and that the look at its drop site does not recognise (fallen into a
rack, lying against something) still lies there, where the sink scans never look: what the drop-site view shows
there that neither the cell nor a believed item explains becomes marks the plans keep clear of. Before, the
belief kept nothing there and the next transfer (or a place at the same spot) ran into it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from kitchenbot.executive.execution import Item
from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import make_T
from kitchenbot.world.gripper import MAX_OPENING, PAD_ENVELOPE


class _RecognisesNothing:
    def perceive(self, views):
        return SimpleNamespace(poses=[], map_points=None)


def _connected(runner):
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    return runner


def _fallen_cup(world, xy):
    uid = max(world.objects)
    o = world.objects[uid]
    world.set_pose(uid, make_T(np.eye(3), (xy[0], xy[1], o.model.extents[2] / 2)))  # upright on the counter top
    return uid


@pytest.mark.parametrize("tool_over_it", [False, True], ids=["tool_away", "tool_just_over_its_rim"])
def test_an_unrecognised_item_at_the_drop_site_is_kept_clear_of(make_runner, tool_over_it):
    """`tool_just_over_its_rim`: it slipped out at the end of a transfer, right above where it came to stand, so
    the keep-out cylinder that clears the tool ends below its rim; the marks are looked for in the whole one."""
    runner, world = make_runner(cups=2)
    _connected(runner)
    xy = np.array([-0.10, 0.55])  # the counter beside the robot, outside the sink
    uid = _fallen_cup(world, xy)
    cup = world.objects[uid]
    if tool_over_it:  # pointing down, the pad tips 2 mm over its rim (it just left them)
        rim = cup.T_base_obj[2, 3] + cup.model.extents[2] / 2
        T = make_T(np.diag([1.0, -1.0, -1.0]), (xy[0], xy[1], rim + PAD_ENVELOPE.tip + 0.002))
        q = runner.planner.robot.ik_q(T, runner.arm.joint_positions())
        assert q is not None
        world.set_joints(q)
    runner.item = Item(ObjectPose(cup.model.obj_id, "cup", np.array(cup.T_base_obj), 1.0))
    b = runner.belief
    b.record_dropped(runner.arm.tcp_pose()[:3, 3] if tool_over_it else np.array([xy[0] + 0.02, xy[1] - 0.01, 0.25]))  # it left the tool about above where it lies
    runner._drop_perceiver = lambda: _RecognisesNothing()
    assert len(b.contact_points) == 0

    runner._search_drop_site()

    marks = b.contact_points
    assert len(marks) > 0, "the unrecognised item left no trace in the belief"
    top = float(cup.T_base_obj[2, 3] + cup.model.extents[2] / 2)
    assert abs(marks[:, 2].max() - top) < 0.02  # its rim, as the camera saw it from above (2 cm voxels)
    assert np.linalg.norm(marks[:, :2].mean(axis=0) - xy) < 0.02  # around it
    # only the item: nothing of the counter around it, nothing far from it
    r = max(cup.model.extents[:2]) / 2
    assert np.all(np.linalg.norm(marks[:, :2] - xy, axis=1) < r + 0.03)
    assert np.all(marks[:, 2] > 0.005)
    # and a plan sees it: a scene from the belief has the tool over the cup's rim in collision
    scene = runner.planner.scene(b.scene_objects(), b.map_points)
    assert len(scene.voxels) > 0


def test_a_drop_site_seen_empty_leaves_no_marks(make_runner):
    """The item fell elsewhere (back into the sink): the counter seen there is explained by the cell, no marks."""
    runner, world = make_runner(cups=1)
    _connected(runner)
    cup = world.objects[max(world.objects)]
    runner.item = Item(ObjectPose(cup.model.obj_id, "cup", np.array(cup.T_base_obj), 1.0))
    b = runner.belief
    b.record_dropped(np.array([-0.08, 0.54, 0.25]))
    runner._drop_perceiver = lambda: _RecognisesNothing()
    runner._search_drop_site()
    assert len(b.contact_points) == 0


def test_marks_that_block_a_move_go_and_a_fallen_items_stay(make_runner):
    """The arm stands within the margin of contact marks (a stop in the sink): the move out is planned without
    the marks around the arm; the marks on an item fallen outside the sink stay (before, every mark went, and a
    later transfer ran into that item)."""
    runner, world = make_runner(cups=1)
    _connected(runner)
    b = runner.belief
    q0 = runner.arm.joint_positions()
    T = runner.arm.tcp_pose()
    pad = np.array([[0.0, y, z] for y in (MAX_OPENING / 2, -MAX_OPENING / 2) for z in (-0.04, -0.02, 0.0)])
    b.mark_contact(pad @ T[:3, :3].T + T[:3, 3])  # at the open pads' inner faces
    fallen = np.array([[-0.20, 0.70, 0.06], [-0.20, 0.70, 0.08]])  # on the counter, away from the arm
    b.mark_contact(fallen)
    plan = runner.planner.plan_move(q0, np.asarray(runner.robot.config.scan_waypoints[0], float),
                                    objects=b.scene_objects(), map_points=b.map_points)
    assert plan.kind == "start_in_collision"  # the situation: the marks block the start

    runner._move_joints(np.asarray(runner.robot.config.scan_waypoints[0], float), "scan waypoint 0")

    assert np.allclose(runner.arm.joint_positions(), runner.robot.config.scan_waypoints[0], atol=1e-3)
    assert len(b.contact_points) == 2 and np.allclose(b.contact_points, fallen)


def _marked_fallen_cup(make_runner):
    """A cup fell upright on the counter where the drop-site view did not recognise it: its marks are kept."""
    runner, world = make_runner(cups=2)
    _connected(runner)
    xy = np.array([-0.10, 0.55])
    uid = _fallen_cup(world, xy)
    cup = world.objects[uid]
    runner.item = Item(ObjectPose(cup.model.obj_id, "cup", np.array(cup.T_base_obj), 1.0))
    b = runner.belief
    b.record_dropped(np.array([xy[0] + 0.02, xy[1] - 0.01, 0.25]))
    runner._drop_perceiver = lambda: _RecognisesNothing()
    runner._search_drop_site()
    assert len(b.contact_points) > 0
    return runner, world, cup


def test_an_unseen_items_marks_go_when_a_perception_recognises_it_there(make_runner):
    """The marks stand for the fallen item while no view recognises it. A later perception that does recognise it
    there (a re-scan that takes in that part of the counter) gives its model: the marks would cage it (no object
    explains marks) and every lift of it meets them. Before, they stayed for the rest of the run: a mug that
    slipped onto the counter beside the sink, marked so, was then perceived there and never picked again
    (`no_feasible_placement` from its staging pick's lift into its own marks, every round)."""
    runner, world, cup = _marked_fallen_cup(make_runner)
    b = runner.belief
    seen = ObjectPose(cup.model.obj_id, "cup", np.array(cup.T_base_obj), 1.0, instance_id=7)
    q = runner.arm.joint_positions()
    caged = runner.planner.plan_pick(q, [seen], target=seen, map_points=b.map_points)
    assert not caged.ok  # the situation: with its marks, it cannot be picked

    # a perception that does not recognise it there (another class, or none) keeps the marks
    n = len(b.contact_points)
    other = ObjectPose(cup.model.obj_id, "glass", np.array(cup.T_base_obj), 1.0, instance_id=8)
    b.perceived([other], None, [], runner.robot.cell.sink_interior)
    assert len(b.contact_points) == n
    b.perceived([], None, [], runner.robot.cell.sink_interior)
    assert len(b.contact_points) == n

    b.perceived([seen], None, [], runner.robot.cell.sink_interior)
    assert len(b.contact_points) == 0
    assert runner.planner.plan_pick(q, [seen], target=seen, map_points=b.map_points).ok


def test_other_marks_stay_when_an_unseen_item_is_recognised(make_runner):
    """Only the marks that stood for the recognised item go: a contact sliver elsewhere stays."""
    runner, world, cup = _marked_fallen_cup(make_runner)
    b = runner.belief
    sliver = np.array([[0.50, 0.00, -0.10], [0.50, 0.01, -0.10]])
    b.mark_contact(sliver)
    seen = ObjectPose(cup.model.obj_id, "cup", np.array(cup.T_base_obj), 1.0, instance_id=7)
    b.region_perceived([seen], None, [])
    assert len(b.contact_points) == 2 and np.allclose(b.contact_points, sliver)
