"""sink-to-dishwasher: a bowl that is not mouth-down (no level side grasp turns a 16 cm bowl over) stands on its
rim in the lower rack like a plate, away from the plates' end; a mouth-down bowl goes mouth-down into the lower
rack, the upper rack (16 cm a bowl: the room of two or three cups) only when the lower one is full."""

from __future__ import annotations

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.executive.belief import Belief
from kitchenbot.tasks import make_task
from kitchenbot.transforms import make_T
from kitchenbot.world.cell import Cell

MOUTH_DOWN = np.diag([1.0, -1.0, -1.0])


def in_sink(inv, name, R=np.eye(3), k=0):
    m = inv.by_name(name)
    return ObjectPose(m.obj_id, m.cls, make_T(R, (0.5, 0.01 * k, -0.15)), 1.0, instance_id=k)


def test_upright_bowls_stand_on_their_rim_in_the_lower_rack(inv):
    cell = Cell()
    task = make_task("sink-to-dishwasher", inv, cell)
    belief = Belief()
    sink = [in_sink(inv, "bowl", k=0), in_sink(inv, "bowl", k=1), in_sink(inv, "dinner_plate", k=2),
            in_sink(inv, "dinner_plate", k=3)]
    belief.pending = task.pending_models(sink)
    low = cell.spec.dishwasher.lower
    lo, hi = np.array(low.origin_xy), np.array(low.origin_xy) + np.array(low.size_xy)
    r = max(inv.by_name("bowl").extents[:2]) / 2
    for b in sink[:2]:
        ts = task.targets(b, belief)
        assert not isinstance(ts, NoFreeSlot)
        t = ts[0]
        T = t.T_base_obj
        assert abs(T[0, 2]) > 0.99  # axis along x: on its rim between the tines
        assert low.floor_z <= T[2, 3] - r <= low.floor_z + 0.02
        p = belief.record_placed(task, b, t, T)
        assert np.all(p.lo >= lo - 1e-6) and np.all(p.hi <= hi + 1e-6)
        assert task.at_target("bowl", T)
    # the plates still to come keep their end of the rack
    for pl in sink[2:]:
        ts = task.targets(pl, belief)
        assert not isinstance(ts, NoFreeSlot), ts
        belief.record_placed(task, pl, ts[0], ts[0].T_base_obj)
    assert len(belief.placed) == 4


def test_a_mouth_down_bowl_goes_mouth_down_into_the_lower_rack_then_the_upper(inv):
    cell = Cell()
    task = make_task("sink-to-dishwasher", inv, cell)
    belief = Belief()
    bowl = in_sink(inv, "bowl", MOUTH_DOWN)
    low, up = cell.spec.dishwasher.lower, cell.spec.dishwasher.upper

    def in_rack(rack, T):
        return all(rack.origin_xy[i] <= T[i, 3] <= rack.origin_xy[i] + rack.size_xy[i] for i in (0, 1))

    ts = task.targets(bowl, belief)
    assert ts and all(t.T_base_obj[2, 2] < -0.99 for t in ts)  # mouth-down everywhere
    racks = ["lower" if in_rack(low, t.T_base_obj) else "upper" if in_rack(up, t.T_base_obj) else "?" for t in ts]
    assert "?" not in racks and racks[0] == "lower" and "upper" in racks
    assert racks == sorted(racks)  # every lower-rack spot before the upper rack's
    lower = [t for t, r in zip(ts, racks) if r == "lower"]
    xs = [t.T_base_obj[0, 3] for t in lower]
    assert xs == sorted(xs, reverse=True)  # from the rack's far end (plates fill it from the robot's end)
    assert min(t.T_base_obj[2, 3] for t in lower) - inv.by_name("bowl").extents[2] / 2 <= low.floor_z + 0.02
    # with the lower rack kept for plates still in the sink, the bowl goes to the upper rack
    belief.pending = task.pending_models([bowl] + [in_sink(inv, "dinner_plate", k=k) for k in range(1, 12)])
    ts = task.targets(bowl, belief)
    assert ts and all(in_rack(up, t.T_base_obj) for t in ts)


def test_mouth_down_bowls_go_two_across_the_lower_rack(inv):
    """Seed 15: three mouth-down bowls, glasses and mugs. On the lower rack's centre line each 16 cm bowl took a
    whole column (two bowls in all) and the third found the upper rack full. Against its sides, staggered in x by
    what the round rims need, the 34 cm rack takes two bowls across: four in all, CLEARANCE between their rims
    and inside the side wires."""
    from kitchenbot.tasks.base import CLEARANCE

    cell = Cell()
    task = make_task("sink-to-dishwasher", inv, cell)
    belief = Belief()
    low = cell.spec.dishwasher.lower
    lo, hi = np.array(low.origin_xy), np.array(low.origin_xy) + np.array(low.size_xy)
    r = max(inv.by_name("bowl").extents[:2]) / 2
    bowls = [in_sink(inv, "bowl", MOUTH_DOWN, k=k) for k in range(5)]
    belief.pending = task.pending_models(bowls)
    centres = []
    for b in bowls[:4]:
        ts = task.targets(b, belief)
        assert not isinstance(ts, NoFreeSlot), ts
        T = ts[0].T_base_obj
        assert ts[0].support.startswith("rack_lower") and T[2, 2] < -0.99
        c = T[:2, 3]
        assert np.all(c - r >= lo + 0.006) and np.all(c + r <= hi - 0.006)  # inside the 6 mm side wires
        assert all(np.hypot(*(c - o)) >= 2 * r + CLEARANCE - 1e-9 for o in centres)
        centres.append(c)
        belief.record_placed(task, b, ts[0], T)
    assert len({round(float(c[1]), 3) for c in centres}) == 2  # both sides of the rack
    ts = task.targets(bowls[4], belief)  # the lower rack is full: the upper one
    assert not isinstance(ts, NoFreeSlot) and all(t.support == "rack_upper" for t in ts)


def test_cups_go_mouth_down_into_the_lower_rack_when_the_upper_one_is_full(inv):
    """Seed 4 (six cups, two glasses, a mug and a plate): the upper rack took seven and two cups found no slot.
    As people load a full dishwasher, what the upper rack has no room for goes mouth-down into the lower one,
    with room kept for the plate still in the sink, and counts as delivered there."""
    cell = Cell()
    task = make_task("sink-to-dishwasher", inv, cell)
    belief = Belief()
    up, low = cell.spec.dishwasher.upper, cell.spec.dishwasher.lower
    cups = [in_sink(inv, "cup", k=k) for k in range(14)]
    plate = in_sink(inv, "dinner_plate", k=20)
    belief.pending = task.pending_models(cups + [plate])
    racks = []
    for c in cups:
        ts = task.targets(c, belief)
        assert not isinstance(ts, NoFreeSlot), (len(racks), ts)
        racks.append(ts[0].support.split()[0])
        if racks[-1] == "rack_lower":
            T = ts[0].T_base_obj
            assert T[2, 2] < -0.99 and all(t.support.startswith("rack_lower") for t in ts)
            assert all(low.origin_xy[i] <= T[i, 3] <= low.origin_xy[i] + low.size_xy[i] for i in (0, 1))
            assert task.at_target("cup", T)
        belief.record_placed(task, c, ts[0], ts[0].T_base_obj)
    n_up = racks.index("rack_lower")
    assert n_up >= 7 and set(racks[:n_up]) == {"rack_upper"} and set(racks[n_up:]) == {"rack_lower"}
    ts = task.targets(plate, belief)  # the plate still has its place in the lower rack
    assert not isinstance(ts, NoFreeSlot) and abs(ts[0].T_base_obj[0, 2]) > 0.99


def test_an_upright_bowl_may_stand_in_the_room_kept_for_plates_when_they_all_still_fit(inv):
    """Two bowls already stand on their rim at the lower rack's far end, four dinner plates are still in the sink
    and one more upright bowl. The room kept for the plates (their first spots, nearest the robot) reached into the
    only spot left beside the bowls, so the bowl had no lower-rack target, only mouth-down ones in the upper rack
    that no grasp of an upright bowl reaches (turning it over needs a regrasp), and it stayed in the sink with the
    plates under it. A spot inside that room is offered, after the others, when every plate still fits beside it."""
    cell = Cell()
    task = make_task("sink-to-dishwasher", inv, cell)
    belief = Belief()
    sink = [in_sink(inv, "bowl", k=k) for k in range(3)] + [in_sink(inv, "dinner_plate", k=k) for k in range(3, 7)]
    low = cell.spec.dishwasher.lower
    lo, hi = np.array(low.origin_xy), np.array(low.origin_xy) + np.array(low.size_xy)

    def in_lower(T):
        return all(lo[i] <= T[i, 3] <= hi[i] for i in (0, 1))

    for b in sink[:2]:  # the first two bowls, placed with nothing kept for plates (as if no plate were seen yet)
        belief.pending = []
        ts = task.targets(b, belief)
        belief.record_placed(task, b, ts[0], ts[0].T_base_obj)
    belief.pending = task.pending_models(sink[2:])
    ts = task.targets(sink[2], belief)
    assert not isinstance(ts, NoFreeSlot)
    lower = [t for t in ts if in_lower(t.T_base_obj)]
    assert lower, [t.slot for t in ts]  # before: only the upper rack's mouth-down spots
    assert all(abs(t.T_base_obj[0, 2]) > 0.99 for t in lower)  # on its rim
    belief.record_placed(task, sink[2], lower[0], lower[0].T_base_obj)
    belief.pending = task.pending_models(sink[3:])
    for pl in sink[3:]:  # every plate still has a spot beside the three bowls
        ts = task.targets(pl, belief)
        assert not isinstance(ts, NoFreeSlot), ts
        belief.record_placed(task, pl, ts[0], ts[0].T_base_obj)
        belief.pending = belief.pending[1:]
    assert len(belief.placed) == 7
    boxes = [(p.lo, p.hi) for p in belief.placed]
    for i in range(len(boxes)):
        for j in range(i):
            assert not (np.all(boxes[i][0] < boxes[j][1]) and np.all(boxes[i][1] > boxes[j][0]))
