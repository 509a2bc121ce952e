"""sink-to-dishwasher, a crowded sink: the lower rack's room is kept for the plates still in the sink (the task's
pending models), so a bowl finds no slot while they are to come. When every plan for those plates has failed in
this scene (their grasps all collide), they keep no room (Belief.pending), and the bowl that was waiting
(Belief.no_room, not given up) gets a slot. Hand-made: the upper rack filled with cup records, twelve plates and
an upright bowl in the sink."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive import machine as M
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.tasks.base import inverted
from kitchenbot.transforms import make_T


def _full_upper_rack(runner) -> None:
    cell, task, b = runner.robot.cell, runner.task, runner.belief
    cup = runner.robot.inventory.by_name("cup")
    r = max(cup.extents[:2]) / 2
    spec = cell.spec.dishwasher.upper
    lo = np.array(spec.origin_xy)
    hi = lo + np.array(spec.size_xy)
    for x in np.arange(hi[0] - r - 0.007, lo[0] + r, -(2 * r + 0.011)):
        for y in np.arange(lo[1] + r + 0.008, hi[1] - r, 2 * r + 0.011):
            T = inverted(cup, (x, y), spec.floor_z)
            o = ObjectPose(cup.obj_id, "cup", T, 1.0, instance_id=100 + len(b.placed))
            b.placed.append(task.placed_record(o, None, T, o.instance_id))


def _crowded_sink(runner, plates: int = 12):
    inv, b, task = runner.robot.inventory, runner.belief, runner.task
    plate_m, bowl_m = inv.by_name("dinner_plate"), inv.by_name("bowl")
    ps = [ObjectPose(plate_m.obj_id, "plate", make_T(np.eye(3), (0.30 + 0.1 * (k % 5), -0.15 + 0.1 * (k // 5),
                                                                  -0.19)), 1.0, instance_id=k)
          for k in range(plates)]
    bowl = ObjectPose(bowl_m.obj_id, "bowl", make_T(np.eye(3), (0.70, 0.15, -0.15)), 1.0, instance_id=50)
    b.poses = ps + [bowl]
    b.pending_items = task.pending_items(b.poses)
    return ps, bowl


def _fail_to_plan(b, obj) -> None:
    for _ in range(M.MAX_PLAN_FAILURES_PER_SCENE):
        b.record_plan_failure(obj, "no_collision_free_grasp")


def test_a_bowl_waits_for_the_room_kept_for_plates_and_gets_it_when_they_prove_stuck(make_runner):
    runner, _ = make_runner(task="sink-to-dishwasher")
    _full_upper_rack(runner)
    plates, bowl = _crowded_sink(runner)
    b, task = runner.belief, runner.task
    assert isinstance(task.targets(bowl, b), NoFreeSlot)  # the lower rack kept for the twelve plates
    for p in plates:  # every plate fails to plan once: the others first until the next perception
        b.record_plan_failure(p, "no_collision_free_grasp")
        b.record_unplannable(p)
    assert runner._do_select_grasp() == "nothing_left"  # the bowl has no slot: it waits
    assert b.exhausted(bowl) and not b.stuck(bowl)
    t = b.attempts_for(bowl)
    assert t.count < M.MAX_ATTEMPTS_PER_OBJECT and any("no free slot" in r for r in t.reasons)
    b.unplannable = []  # the next perception: the plates fail to plan a second time in this scene
    for p in plates:
        b.record_plan_failure(p, "no_collision_free_grasp")
    assert all(b.stuck(p) for p in plates) and all(m.cls != "plate" for m in b.pending)
    assert not b.exhausted(bowl)  # the room changed: it is tried again
    assert runner._do_select_grasp() == "selected"
    it = runner.item
    assert it.obj is bowl and it.targets and all(t.kind == "slot" for t in it.targets)
    assert all(t.support.startswith("rack_lower") for t in it.targets)


def test_the_room_comes_back_when_the_scene_changes(make_runner):
    """A plate that proved stuck in one scene keeps room again once the scene changes (it is tried again)."""
    runner, _ = make_runner(task="sink-to-dishwasher")
    _full_upper_rack(runner)
    plates, bowl = _crowded_sink(runner)
    b, task = runner.belief, runner.task
    for p in plates:
        _fail_to_plan(b, p)
    assert not isinstance(task.targets(bowl, b), NoFreeSlot)
    b.scene_changed()
    assert sum(m.cls == "plate" for m in b.pending) == len(plates)
    assert isinstance(task.targets(bowl, b), NoFreeSlot)


def test_a_plate_still_to_try_keeps_its_room(make_runner):
    """Only the plates that proved stuck give up their room: with one plate not yet stuck, the room kept for it
    stays kept."""
    runner, _ = make_runner(task="sink-to-dishwasher")
    _full_upper_rack(runner)
    plates, bowl = _crowded_sink(runner)
    b = runner.belief
    for p in plates[1:]:
        _fail_to_plan(b, p)
    assert [m.cls for m in b.pending].count("plate") == 1


def test_giving_up_with_items_in_the_sink_names_those_on_the_counter_too(make_runner, record_staged):
    """The run's message names every item left: those in the sink and the staged ones on the counter (set aside
    with no room), each with its reason. It used to name the counter's only when the sink was empty."""
    runner, _ = make_runner(task="sink-to-dishwasher")
    _full_upper_rack(runner)
    plates, bowl = _crowded_sink(runner, plates=1)
    b, task = runner.belief, runner.task
    cup = runner.robot.inventory.by_name("cup")
    spot = task.staging_targets(as_pose_of(cup), b)[0]
    rec = record_staged(runner, cup, spot.T_base_obj)
    b.no_room(as_pose_of(cup, rec.T_base_obj), "no_free_slot: no free slot for a cup in the upper or lower rack")
    _fail_to_plan(b, plates[0])
    msg = runner._why_left([plates[0]])
    assert msg.startswith("1 object(s) left in the sink: plate (no_collision_free_grasp)")
    assert "1 object(s) left on the counter" in msg and "cup (no_free_slot" in msg


def as_pose_of(model, T=None):
    return ObjectPose(model.obj_id, model.cls, make_T(np.eye(3), (0.5, 0.0, -0.15)) if T is None else T, 1.0)
