"""A placement its retreat view settles is verified without a re-scan (executive/verification.py); a pick that
may have moved a neighbour, or a view that does not see it there, re-scans. Oracle perception: the executive is
under test."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.runner import RunOptions
from kitchenbot.fakes.placement import drop_onto
from kitchenbot.perception.types import ObjectPose


REGION_VIEW = RunOptions(poll_period=0.05, confirm_empty_scans=1, verify_region_view=True)


def _notes(runner, name: str) -> int:
    return sum(1 for e in runner.journal.events(runner.run_id) if e["kind"] == "note" and e["name"] == name)


def _cups_apart(world, dx: float = 0.14) -> None:
    """The upper of two nested cups moved `dx` along x (within the sink) and settled: two cups apart."""
    cups = sorted([u for u, o in world.objects.items() if o.model.cls == "cup"],
                  key=lambda u: world.objects[u].T_base_obj[2, 3])
    lo, hi = world.cell.sink_interior
    T = world.objects[cups[1]].T_base_obj.copy()
    x = T[0, 3] + dx
    T[0, 3] = x if lo[0] + 0.06 < x < hi[0] - 0.06 else T[0, 3] - 2 * dx
    world.set_pose(cups[1], drop_onto(world, cups[1], T))


def test_separate_items_are_verified_without_a_rescan(make_runner, safe_end):
    runner, world = make_runner(task="sink-pick", cups=2)
    _cups_apart(world)
    report = runner.run()
    safe_end(runner, world)
    assert report.status == "succeeded" and report.objects_done == 2
    assert report.truth["end"]["delivered"] == 2 and report.collisions == 0
    # the first placement: seen at its target, the other cup far away -> no re-scan; the second leaves nothing to
    # do as perceived -> the re-scan confirms the sink empty
    assert _notes(runner, "verified from the placement view, no re-scan") == 1
    assert runner.counts.scan_count == 2
    # each cycle's compute is split by stage, and the stages add up to it
    for c in report.cycles:
        assert abs(sum(c["stages_s"].values()) - c["compute_s"]) < 0.05
        assert c["stages_s"].get("plan", 0) > 0 and "capture" in c["stages_s"]
    assert report.items_per_minute is not None and report.items_per_minute > 0


def test_always_rescan_when_told(make_runner, safe_end):
    runner, world = make_runner(task="sink-pick", cups=2,
                                options=RunOptions(poll_period=0.05, confirm_empty_scans=1, verify_without_rescan=False))
    _cups_apart(world)
    report = runner.run()
    safe_end(runner, world)
    assert report.objects_done == 2 and runner.counts.scan_count == 3
    assert _notes(runner, "verified from the placement view, no re-scan") == 0


def test_a_pick_off_a_stack_is_verified_with_one_view_of_its_region(make_runner, safe_end):
    """Two nested cups: the top one picked leaves a copy of its class where it was. One view straight down at the
    pick spot re-perceives that region (the cup below found again there) instead of a re-scan."""
    runner, world = make_runner(task="sink-pick", cups=2, options=REGION_VIEW)
    report = runner.run()
    safe_end(runner, world)
    assert report.objects_done == 2 and report.collisions == 0
    assert _notes(runner, "verified from the placement view, no re-scan") == 0
    assert _notes(runner, "verified with one view of the pick region, no re-scan") == 1
    assert runner.counts.scan_count == 2  # the first scan; after the last placement, the one confirming it empty
    region = [e for e in runner.journal.events(runner.run_id) if e["name"] == "perceive region"]
    assert len(region) == 1 and region[0]["payload"]["replaced"] == 1


def test_a_pick_off_a_stack_rescans_without_the_region_view(make_runner, safe_end):
    runner, world = make_runner(task="sink-pick", cups=2,
                                options=RunOptions(poll_period=0.05, confirm_empty_scans=1, verify_region_view=False))
    report = runner.run()
    safe_end(runner, world)
    assert report.objects_done == 2
    assert _notes(runner, "verified with one view of the pick region, no re-scan") == 0
    assert runner.counts.scan_count == 3  # the first scan, one after each placement (the second confirms empty)


def test_a_region_view_that_misses_a_known_item_rescans(make_runner, safe_end):
    """The region's one view does not show the cup left under the picked one (here: a perceiver blind in views
    straight down, as the region's view is; the scan's are oblique): it is not taken as gone; a re-scan decides,
    and finds it."""
    runner, world = make_runner(task="sink-pick", cups=2, options=REGION_VIEW)
    inner = runner.perceiver

    class BlindInOneView:
        def perceive(self, views):
            res = inner.perceive(views)
            if len(views) == 1 and views[0].T_base_cam[2, 2] < -0.99:
                res.poses = []
            return res

    runner.perceiver = BlindInOneView()
    report = runner.run()
    safe_end(runner, world)
    assert report.objects_done == 2
    assert _notes(runner, "re-scan: one view of the pick region does not settle it") == 1
    assert runner.counts.scan_count == 3


def test_the_region_view_is_on_by_default():
    assert RunOptions().verify_region_view


@pytest.mark.parametrize("shift", [0.0, 0.03])
def test_a_region_view_that_finds_an_item_moved_rescans(make_runner, safe_end, shift):
    """The region's one view finds the cup left under the picked one, but 3 cm from where the scan put it (here: a
    perceiver that shifts what it sees in views straight down): one view's fit is not taken for a moved item; a
    re-scan decides. Found where it was (no shift), the scan's pose stays (the same object) and no re-scan."""
    runner, world = make_runner(task="sink-pick", cups=2, options=REGION_VIEW)
    inner = runner.perceiver

    class ShiftedInOneView:
        def perceive(self, views):
            res = inner.perceive(views)
            if len(views) == 1 and views[0].T_base_cam[2, 2] < -0.99:
                for p in res.poses:
                    p.T_base_obj = p.T_base_obj.copy()
                    p.T_base_obj[0, 3] += shift
            return res

    runner.perceiver = ShiftedInOneView()
    report = runner.run()
    safe_end(runner, world)
    assert report.objects_done == 2 and report.collisions == 0
    moved = 1 if shift else 0
    assert _notes(runner, "re-scan: one view of the pick region does not settle it") == moved
    assert _notes(runner, "verified with one view of the pick region, no re-scan") == 1 - moved
    assert runner.counts.scan_count == 2 + moved


def test_what_may_have_moved_with_a_pick(make_runner):
    """Beside it on the same support and fully seen: stays. On it, leaning, seen in part, or touching: moved."""
    runner, world = make_runner(task="sink-pick", cups=1)
    cup = next(o.model for o in world.objects.values() if o.model.cls == "cup")
    width = float(cup.extents[0])

    def at(x: float, z: float = 0.0, tilt: float = 0.0, seen: float = 1.0) -> ObjectPose:
        c, s = np.cos(tilt), np.sin(tilt)
        T = np.eye(4)
        T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
        T[:3, 3] = (x, 0.5, z)
        return ObjectPose(cup.obj_id, "cup", T, 1.0, instance_id=int(x * 1000 + z * 100), visible_fraction=seen)

    picked = at(0.0)
    far, beside = at(width + 0.05), at(width + 0.01)
    assert runner._moved_with(picked, [far, beside]) == []  # touching, but beside it on the same support
    assert runner._moved_with(picked, [at(width + 0.01, z=0.03)])[0][1] == "rested on it"
    assert runner._moved_with(picked, [at(width + 0.01, tilt=0.6)])[0][1] == "leaning"
    assert runner._moved_with(picked, [at(width + 0.01, seen=0.1)])[0][1] == "seen in part"
    assert runner._moved_with(picked, [at(width + 0.05, seen=0.1)]) == []  # seen in part, but not touching
    assert runner._moved_with(picked, [at(width + 0.01, tilt=np.pi)]) == []  # upside down: not leaning


def test_an_item_under_another_from_above_is_left_to_a_rescan(make_runner):
    """Plates nested in a stack: from straight above the top one hides the one under it (the scan's oblique views
    see its rim), so the region's one view is not taken; a mug on a plate does not hide it, nor does a plate
    beside it or a narrower item off its axis."""
    runner, world = make_runner(task="sink-pick", cups=1)
    inv = runner.robot.inventory
    plate = next(m for m in inv.models.values() if m.cls == "plate")
    mug = next(m for m in inv.models.values() if m.cls == "mug")

    def at(model, x: float, z: float) -> ObjectPose:
        T = np.eye(4)
        T[:3, 3] = (x, 0.5, z)
        return ObjectPose(model.obj_id, model.cls, T, 1.0, instance_id=int(1000 * x + 100 * z))

    lower, upper = at(plate, 0.4, -0.19), at(plate, 0.402, -0.18)
    assert runner._covered_from_above([lower], [lower, upper]) is lower
    assert runner._covered_from_above([upper], [lower, upper]) is None
    assert runner._covered_from_above([lower], [lower, at(mug, 0.4, -0.15)]) is None  # narrower
    assert runner._covered_from_above([lower], [lower, at(plate, 0.4 + plate.diameter, -0.18)]) is None  # beside


def test_an_item_held_up_by_nothing_perceived_is_left_to_a_rescan(make_runner):
    """A plate picked from where it lay on a plate no pose described (it hid it): the map of before the pick lacks
    what it uncovered, so the placement is verified by a re-scan (the next lift would meet the plate under it). On
    the sink floor, or on a perceived plate under it, the retreat view may settle it."""
    runner, world = make_runner(task="sink-pick", cups=1)
    inv = runner.robot.inventory
    plate = next(m for m in inv.models.values() if m.cls == "plate")
    lo, hi = runner.robot.cell.sink_interior
    c = (np.asarray(lo) + np.asarray(hi)) / 2

    def at(z_above: float, dx: float = 0.0, iid: int = 1) -> ObjectPose:
        T = np.eye(4)
        T[:3, 3] = (c[0] + dx, c[1], lo[2] - plate.points[:, 2].min() + z_above)
        return ObjectPose(plate.obj_id, "plate", T, 1.0, instance_id=iid)

    on_floor, on_hidden, below = at(0.001), at(0.012, dx=0.01), at(0.001, iid=2)
    assert runner._held_up_by_unseen(on_floor, []) is None
    assert runner._held_up_by_unseen(on_hidden, []) == pytest.approx(0.012, abs=1e-3)
    assert runner._held_up_by_unseen(on_hidden, [below]) is None  # the plate under it is perceived
    far = at(0.001, dx=plate.diameter + 0.05, iid=3)
    assert runner._held_up_by_unseen(on_hidden, [far]) == pytest.approx(0.012, abs=1e-3)  # not under it
    counter = ObjectPose(plate.obj_id, "plate", np.eye(4), 1.0, instance_id=4)
    counter.T_base_obj[:3, 3] = (hi[0] + 0.3, hi[1] + 0.3, 0.05)
    assert runner._held_up_by_unseen(counter, []) is None  # not in the sink


def test_a_pick_off_another_item_is_verified_with_one_view_of_its_region(make_runner, safe_end):
    """A cup resting on a plate (both perceived): what the cup hid on the plate (a bowl nested under a bowl lay hidden
    so, and the next lift met it) is in no map of before the pick, so its placement is verified with one view of the
    pick region, not from the placement view alone. A cup on the sink floor keeps the placement view (above)."""
    runner, world = make_runner(task="sink-pick", cups=1, options=REGION_VIEW)
    plate = next(m for m in runner.robot.inventory.models.values() if m.cls == "plate")
    cup = next(u for u, o in world.objects.items() if o.model.cls == "cup")
    T_cup = world.objects[cup].T_base_obj.copy()
    lo, _ = world.cell.sink_interior
    away = T_cup.copy()
    away[2, 3] += 5.0
    world.set_pose(cup, away)
    T_plate = np.eye(4)
    T_plate[:3, 3] = (T_cup[0, 3], T_cup[1, 3], lo[2] - plate.points[:, 2].min() + 0.05)
    p = world.add_object(plate, T_plate)
    world.set_pose(p, drop_onto(world, p, T_plate))
    T_on = T_cup.copy()
    T_on[0, 3] += 0.3 * plate.diameter  # on the plate's sloping rim, well above the sink floor
    T_on[2, 3] += 0.06
    world.set_pose(cup, drop_onto(world, cup, T_on))
    assert world.objects[cup].T_base_obj[2, 3] > T_cup[2, 3] + runner.SAME_SUPPORT  # it rests on the plate

    report = runner.run()
    safe_end(runner, world)
    assert report.objects_done == 2 and report.collisions == 0
    assert _notes(runner, "verified from the placement view, no re-scan") == 0
    assert _notes(runner, "verified with one view of the pick region, no re-scan") == 1
