"""A staged item (set down on the counter for its regrasp) picked up again and placed is verified without a re-scan
of the sink: nothing in the sink was touched since its last perception, and a scan's views (perception keeps the
basin only) show nothing of the counter, so the re-scan decided nothing about it (executive/verification.py,
``_verified_from_the_counter``). Where nothing is left to do as perceived, the re-scan still confirms the sink
empty. Oracle perception: the executive's mechanism is under test."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.belief import Belief
from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import make_T, rot_x

NOTE = "a staged item verified without a re-scan: the sink was not touched"


def _notes(runner, name: str) -> int:
    return sum(1 for e in runner.journal.events(runner.run_id) if e["kind"] == "note" and e["name"] == name)


def _stage_a_cup(record_staged, runner, world, uid):
    """Move cup `uid` from the sink to the middle of the drop zone, on its side (as sink-to-dishwasher stages
    cups), and record it staged there, already looked at: the run starts with it waiting for its regrasp."""
    from kitchenbot.fakes.placement import drop_onto

    cup = world.objects[uid].model
    zone = runner.robot.cell.spec.drop_zone
    xy = np.array(zone.origin_xy) + np.array(zone.size_xy) / 2
    T = make_T(rot_x(np.pi / 2)[:3, :3], (xy[0], xy[1], zone.z + max(cup.extents[:2]) / 2))
    world.set_pose(uid, T)
    T = drop_onto(world, uid, T)
    world.set_pose(uid, T)
    rec = record_staged(runner, cup, T)
    runner.belief.seen_staged.add(rec.instance_id)
    return rec


def _cups(world):
    return sorted([u for u, o in world.objects.items() if o.model.cls == "cup"],
                  key=lambda u: world.objects[u].T_base_obj[2, 3])


def _run_with_a_staged_cup(make_runner, record_staged, safe_end, cups: int, staged: int):
    """A sink-to-dishwasher run on a cell of `cups` cups, the `staged`-th lowest moved to the counter and recorded
    staged there; returns (runner, world, report) after the run and its safe end."""
    runner, world = make_runner(task="sink-to-dishwasher", cups=cups)
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    _stage_a_cup(record_staged, runner, world, _cups(world)[staged])
    report = runner.run()
    safe_end(runner, world)
    return runner, world, report


def test_a_staged_items_placement_is_verified_without_a_rescan(make_runner, record_staged, safe_end):
    """A cup staged on the counter, another in the sink. The staged cup is placed first (in a rack); before, its
    verification re-scanned the sink (3 scans: the first, that one, the one confirming the sink empty); now the
    sink's perception stays, the arm goes back over the sink, and the cup in the sink is picked next (2 scans)."""
    runner, world, report = _run_with_a_staged_cup(make_runner, record_staged, safe_end, cups=2, staged=1)
    assert report.status == "succeeded" and report.objects_done == 2
    assert report.truth["end"]["delivered"] == 2 and report.collisions == 0
    assert _notes(runner, NOTE) == 1
    assert runner.counts.scan_count == 2
    assert not runner.belief.staged
    # instead of the re-scan's moves, one move back to where it would have left the arm (the last scan waypoint)
    ev = runner.journal.events(runner.run_id)
    k = next(i for i, e in enumerate(ev) if e["name"] == NOTE)
    move = next(e for e in ev[k:] if e["name"] == "arm.execute_trajectory")
    assert np.allclose(move["payload"]["q_end"], runner.robot.config.scan_waypoints[-1], atol=1e-6)


def test_a_staged_item_with_nothing_left_in_the_sink_still_rescans(make_runner, record_staged, safe_end):
    """The only cup staged on the counter, the sink empty: after it is placed, the scan confirming the sink empty
    is made (not skipped with the re-scan)."""
    runner, world, report = _run_with_a_staged_cup(make_runner, record_staged, safe_end, cups=1, staged=0)
    assert report.status == "succeeded" and report.truth["end"]["delivered"] == 1 and report.collisions == 0
    assert _notes(runner, NOTE) == 0
    assert runner.counts.scan_count == 2  # the first; the one after the placement confirms the sink empty


def test_the_staged_item_leaves_the_perception_it_was_seen_in():
    """A perception that sees the counter too holds the staged item where it was staged: once it is picked up from
    there and placed, that pose goes (it was the item), the others stay."""
    b = Belief()
    at = {"cup": (0.6, 0.3, 0.05), "mug": (0.6, 0.3, 0.05), "far": (0.1, -0.2, -0.15)}
    cup = ObjectPose(1, "cup", make_T(np.eye(3), at["cup"]), 1.0, instance_id=1)
    mug = ObjectPose(2, "mug", make_T(np.eye(3), at["mug"]), 1.0, instance_id=2)
    far = ObjectPose(1, "cup", make_T(np.eye(3), at["far"]), 1.0, instance_id=3)
    b.poses = [cup, mug, far]
    staged = type("Staged", (), {"cls": "cup", "T_base_obj": make_T(np.eye(3), (0.61, 0.3, 0.05))})()
    b.unplannable = [far]
    b.counter_item_moved(staged, lambda poses: [])
    assert b.poses == [mug, far] and b.unplannable == []
