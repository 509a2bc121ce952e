"""Where an item that slipped out fell is judged by the item as it was held, not by the tool point
(executive/drop_footprint.py, RecoveryActions._search_drop_site).

A dinner plate held by its rim slipped out during a lift with the tool 5 mm outside the basin's interior; the plate
lay over the basin and fell into it. Judged by the tool point, the drop was "outside the sink": it was looked for on
the counter only, never awaited in the sink, and although the scans found the plate in the sink and it was placed,
the run ended `failed` with the plate "not seen again". Now the plate's footprint as held decides: over the basin,
a scan that holds it back in the sink finds the drop."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from kitchenbot.executive.drop_footprint import drop_footprint
from kitchenbot.executive.execution import Item
from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import make_T

SINK = (np.array([0.25, -0.2, -0.2]), np.array([0.75, 0.2, 0.0]))  # the shipped cell's basin interior


def _disc(centre, radius, n=24):
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.c_[centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), np.full(n, centre[2])]


def test_the_footprint_decides_where_an_item_fell():
    tool = np.array([0.45, 0.205, 0.15])  # 5 mm outside the basin's interior in y
    # by the tool point alone (no grasp known): outside, looked for on the counter only
    alone = drop_footprint(tool, None, SINK)
    assert (alone.over_basin, alone.beyond_basin) == (False, True)
    # a plate held by its rim, its centre 13 cm inside: over the basin, reaching 1.5 cm beyond it (it tips in)
    rim = drop_footprint(tool, _disc((0.45, 0.075, 0.13), 0.14), SINK)
    assert (rim.over_basin, rim.beyond_basin) == (True, False)
    assert np.allclose(rim.centre, (0.45, 0.075, 0.15), atol=1e-3)
    # the same plate held half over the counter: awaited in the sink and looked for on the counter
    edge = drop_footprint(tool, _disc((0.45, 0.19, 0.13), 0.14), SINK)
    assert (edge.over_basin, edge.beyond_basin) == (True, True)
    # held wholly over the counter
    out = drop_footprint(np.array([0.45, 0.5, 0.15]), _disc((0.45, 0.40, 0.13), 0.1), SINK)
    assert (out.over_basin, out.beyond_basin) == (False, True)


def _connected_and_empty(make_runner, task):
    """A runner for TASK with its devices connected and nothing in its world."""
    runner, world = make_runner(task=task)
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    for u in list(world.objects):
        world.remove_object(u)
    return runner, world


def test_a_plate_held_by_its_rim_over_the_basin_is_awaited_in_the_sink(make_runner):
    runner, world = _connected_and_empty(make_runner, "sink-pick")
    plate = runner.robot.inventory.by_name("dinner_plate")
    lo, hi = runner.robot.cell.sink_interior
    # the tool pointing down, 5 mm outside the basin in y; the plate held by its rim, its centre 13 cm inside
    T_tool = make_T(np.diag([1.0, -1.0, -1.0]), (0.45, float(hi[1]) + 0.005, 0.15))
    q = runner.planner.robot.ik_q(T_tool, runner.arm.joint_positions())
    assert q is not None
    world.set_joints(q)
    T_held = make_T(np.eye(3), (0.45, float(hi[1]) + 0.005 - 0.13, 0.13))
    T_tcp_obj = np.linalg.inv(runner.arm.tcp_pose()) @ T_held
    T_picked = make_T(np.eye(3), (0.45, 0.0, -0.185))
    runner.item = Item(ObjectPose(plate.obj_id, "plate", T_picked, 1.0))
    runner.item.plan = SimpleNamespace(pick=SimpleNamespace(grasp=SimpleNamespace(T_tcp_obj=T_tcp_obj)),
                                       place=None, slide=None, staging=False)
    T_fallen = make_T(np.eye(3), (0.45, float(hi[1]) + 0.005 - 0.13, float(lo[2]) + 0.016))
    world.add_object(plate, T_fallen)  # where it came to rest: in the basin
    b = runner.belief

    runner._slipped("lift")
    runner._search_drop_site()

    assert len(b.sink_drops) == 1, "the plate held over the basin is not awaited in the sink"
    assert np.allclose(b.sink_drops[0].where[:2], T_held[:2, 3], atol=0.01)  # looked for where the plate was
    assert runner.report.recovered_drops == 0
    # a scan of the sink that holds it (as many plates as before it was picked): the drop is seen again
    b.perceived([ObjectPose(plate.obj_id, "plate", T_fallen, 0.9)], None, [], (lo, hi))
    assert b.lost_drops() == []


class _Sees:
    """A perception that finds the given poses, whatever the view shows."""

    def __init__(self, poses):
        self.poses = poses

    def perceive(self, views):
        return SimpleNamespace(poses=self.poses, map_points=None)


def test_a_found_drop_that_a_later_look_shows_absent_is_looked_for_again(make_runner):
    """A side plate slipped out over the counter and lies at Q; the look at its drop site perceived a plate at P,
    25 cm from it (a misfit), and recorded it there to be picked up again. What that view showed at Q, which
    nothing believed explained, is kept clear of (before: nothing; the camera later ran into the plate there). The
    look before its regrasp shows P's spot empty: the record goes, the drop site is looked at again, and the plate
    is found at Q (before: the record stayed, and three grasps closed on nothing at P)."""
    runner, world = _connected_and_empty(make_runner, "sink-to-dishwasher")
    plate = runner.robot.inventory.by_name("side_plate")
    z = plate.extents[2] / 2
    T_q = make_T(np.eye(3), (0.04, 0.62, z))  # where it lies
    T_p = make_T(np.eye(3), (-0.20, 0.55, z))  # where the drop-site look put it: the counter there is empty
    world.add_object(plate, T_q)
    runner.item = Item(ObjectPose(plate.obj_id, "plate", make_T(np.eye(3), (0.5, 0.0, -0.19)), 1.0))
    b = runner.belief
    b.record_dropped(np.array([0.0, 0.6, 0.25]), cls="plate")  # about above where it fell
    real = runner._drop_perceiver()
    runner._drop_perceiver = lambda: _Sees([ObjectPose(plate.obj_id, "plate", T_p, 0.9)])

    runner._search_drop_site()

    assert [np.round(s.T_base_obj[:2, 3], 2).tolist() for s in b.staged] == [[-0.2, 0.55]]
    assert b.lost_drops() == []
    marks = b.contact_points
    assert len(marks) and np.all(np.linalg.norm(marks[:, :2] - T_q[:2, 3], axis=1) < 0.13), \
        "the plate the view showed at Q is in no map"

    runner._drop_perceiver = lambda: real
    runner.item = Item()  # as the selection of the next item has it
    st = b.staged[0]
    assert runner._look_at_staged(st) is None, "the record the look disproved was kept"

    assert [np.round(s.T_base_obj[:2, 3], 2).tolist() for s in b.staged] == [[0.04, 0.62]]
    assert not any(np.linalg.norm(p.T_base_obj[:2, 3] - T_p[:2, 3]) < 0.05 for p in b.placed)
    assert b.lost_drops() == []
    assert len(b.contact_points) == 0  # the marks that stood for it go: it is recognised there now


def test_a_found_drop_the_look_does_not_recognise_but_sees_there_is_kept(make_runner):
    """The plate lies where the drop-site look put it, and the look before its regrasp recognises nothing: the view
    still shows something there that nothing else explains, so the record stays (it is not looked for again)."""
    runner, world = _connected_and_empty(make_runner, "sink-to-dishwasher")
    plate = runner.robot.inventory.by_name("side_plate")
    T_p = make_T(np.eye(3), (-0.20, 0.55, plate.extents[2] / 2))
    world.add_object(plate, T_p)
    runner.item = Item(ObjectPose(plate.obj_id, "plate", make_T(np.eye(3), (0.5, 0.0, -0.19)), 1.0))
    b = runner.belief
    b.record_dropped(np.array([-0.15, 0.6, 0.25]), cls="plate")
    runner._search_drop_site()
    assert len(b.staged) == 1 and b.lost_drops() == []
    st = b.staged[0]
    runner._drop_perceiver = lambda: _Sees([])
    runner.item = Item()

    assert runner._look_at_staged(st) is st
    assert b.staged == [st] and b.lost_drops() == []
