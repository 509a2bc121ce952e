"""An item the racks have no room for that blocks one they have room for (sink-to-dishwasher, a crowded sink): it is
set aside on the counter (strategies.SetAsideBlocker, strategies.aside_targets), and a staged item with no room
waits on the counter while the sink has work. Hand-made: the racks filled with cup records but for a band too
narrow for a cup that takes a plate on edge; a plate and a cup in the sink, the cup named as in the plate's lift."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive import machine as M
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.tasks.base import inverted
from kitchenbot.transforms import make_T


def _full_racks(runner) -> None:
    """Cup records mouth-down over the upper rack and the lower one, but for the lower rack's first 5 cm in x."""
    cell, task, b = runner.robot.cell, runner.task, runner.belief
    cup = runner.robot.inventory.by_name("cup")
    r = max(cup.extents[:2]) / 2
    for rack, x_from in (("upper", cell.spec.dishwasher.upper.origin_xy[0]),
                         ("lower", cell.spec.dishwasher.lower.origin_xy[0] + 0.05 + r)):
        spec = getattr(cell.spec.dishwasher, rack)
        lo = np.array(spec.origin_xy)
        hi = lo + np.array(spec.size_xy)
        for x in np.arange(hi[0] - r - 0.007, x_from, -(2 * r + 0.011)):
            for y in np.arange(lo[1] + r + 0.008, hi[1] - r, 2 * r + 0.011):
                T = inverted(cup, (x, y), spec.floor_z)
                o = ObjectPose(cup.obj_id, "cup", T, 1.0, instance_id=100 + len(b.placed))
                b.placed.append(task.placed_record(o, None, T, o.instance_id))


def _plate_and_cup(runner):
    inv, b = runner.robot.inventory, runner.belief
    plate_m, cup_m = inv.by_name("dinner_plate"), inv.by_name("cup")
    plate = ObjectPose(plate_m.obj_id, "plate", make_T(np.eye(3), (0.48, 0.09, -0.19)), 1.0, instance_id=1)
    cup = ObjectPose(cup_m.obj_id, "cup", make_T(np.eye(3), (0.40, 0.0, -0.15)), 1.0, instance_id=2)
    b.poses = [plate, cup]
    b.pending = [plate_m, cup_m]
    return plate, cup


def test_a_blocker_the_racks_have_no_room_for_is_set_aside_for_the_item_it_blocks(make_runner):
    runner, _ = make_runner(task="sink-to-dishwasher")
    _full_racks(runner)
    plate, cup = _plate_and_cup(runner)
    b, task = runner.belief, runner.task
    assert isinstance(task.targets(cup, b), NoFreeSlot) and not isinstance(task.targets(plate, b), NoFreeSlot)
    b.give_up_on(cup, str(task.targets(cup, b)))  # as the runner records an item with no target
    b.record_blocked(plate, cup.instance_id)  # the plate's pick: its lift runs into the cup (blocker_first)
    assert runner._do_select_grasp() == "selected"
    it = runner.item
    assert it.obj is cup and it.staged is None
    assert it.targets and all(t.kind == "stage" for t in it.targets)  # counter spots, not rack slots
    # nothing named it this time: the plate is next, the cup stays given up
    assert runner._do_select_grasp() == "selected" and runner.item.obj is plate


def test_setting_aside_is_bounded_per_item(make_runner):
    runner, _ = make_runner(task="sink-to-dishwasher")
    _full_racks(runner)
    plate, cup = _plate_and_cup(runner)
    b = runner.belief
    b.give_up_on(cup, "no_free_slot")
    for _ in range(M.MAX_SET_ASIDE_PLANS):
        b.record_blocked(plate, cup.instance_id)
        assert runner._do_select_grasp() == "selected" and runner.item.obj is cup
    b.record_blocked(plate, cup.instance_id)
    assert runner._do_select_grasp() == "selected" and runner.item.obj is plate


def test_a_blocker_with_a_target_is_not_set_aside(make_runner):
    """With room in the racks the named blocker is picked for its own target, as before."""
    runner, _ = make_runner(task="sink-to-dishwasher")
    plate, cup = _plate_and_cup(runner)
    runner.belief.record_blocked(plate, cup.instance_id)
    assert runner._do_select_grasp() == "selected"
    assert runner.item.obj is cup and all(t.kind == "slot" for t in runner.item.targets)


def test_a_staged_item_with_no_room_waits_while_the_sink_has_work(make_runner, record_staged):
    runner, _ = make_runner(task="sink-to-dishwasher")
    _full_racks(runner)
    plate, cup = _plate_and_cup(runner)
    b, task = runner.belief, runner.task
    spot = task.staging_targets(cup, b)[0]
    T_put = spot.T_base_obj.copy()
    T_put[2, 3] -= 0.01
    b.seen_staged.add(-1)  # no look at it (tests/executive/test_staged_look.py covers the look)
    rec = record_staged(runner, runner.robot.inventory.by_name("cup"), T_put)
    b.seen_staged.add(rec.instance_id)
    b.poses = [plate]
    assert runner._do_select_grasp() == "selected" and runner.item.obj is plate
    assert b.staged_waiting(), "the staged cup was given up while the plate was still to do"
    b.poses = []  # nothing left in the sink: it is given up, with its reason
    assert runner._do_select_grasp() == "nothing_left"
    assert not b.staged_waiting()
    t = b.attempts_for(ObjectPose(rec.obj_id, rec.cls, rec.T_base_obj, 1.0))
    assert any("no_free_slot" in r for r in t.reasons)
