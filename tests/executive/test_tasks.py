"""Tasks: which objects, in what order, where they go (inside the right area, clear of each other, upright /
inverted / on edge), and when the work is done."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.executive.belief import Belief
from kitchenbot.tasks import TASKS, make_task
from kitchenbot.tasks.base import footprint
from kitchenbot.transforms import make_T
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory


@pytest.fixture(scope="module")
def inv():
    return Inventory.builtin()


def pose(inv, name, xyz=(0.5, 0.0, -0.15)):
    m = inv.by_name(name)
    return ObjectPose(m.obj_id, m.cls, make_T(np.eye(3), xyz), 1.0)


def fill(task, belief, inv, names):
    out = []
    for n in names:
        o = pose(inv, n)
        ts = task.targets(o, belief)
        out.append(ts)
        if not isinstance(ts, NoFreeSlot):
            belief.record_placed(task, o, ts[0], ts[0].T_base_obj)
    return out


def test_registry_and_unknown_name(inv):
    assert set(TASKS) == {"sink-pick", "sink-to-dishwasher", "cup-stacking"}
    with pytest.raises(ValueError, match="unknown task"):
        make_task("juggling", inv, Cell())
    for t in TASKS.values():
        assert t.description and t.success_criteria


def test_dishwasher_plates_on_edge_in_lower_rack_vessels_inverted_in_upper(inv):  # (an upright bowl: lower)
    cell = Cell()
    task = make_task("sink-to-dishwasher", inv, cell)
    belief = Belief()
    fill(task, belief, inv, ["dinner_plate", "side_plate", "cup", "glass", "bowl", "mug"])
    assert len(belief.placed) == 6
    lower, upper = cell.spec.dishwasher.lower, cell.spec.dishwasher.upper
    for p in belief.placed:
        on_rim = p.cls in ("plate", "bowl")  # an upright bowl stands on its rim in the lower rack (tests/tasks)
        rack = lower if on_rim else upper
        lo = np.array(rack.origin_xy)
        hi = lo + np.array(rack.size_xy)
        assert np.all(p.lo >= lo - 1e-6) and np.all(p.hi <= hi + 1e-6), p.cls
        z_axis = p.T_base_obj[:3, 2]
        if on_rim:
            assert abs(z_axis[0]) > 0.99  # face normal along x: standing on its rim
        else:
            assert z_axis[2] < -0.99  # upside down
        bottom = p.T_base_obj[2, 3] - (inv[p.obj_id].extents[2] / 2 if not on_rim else
                                       max(inv[p.obj_id].extents[:2]) / 2)
        assert rack.floor_z <= bottom <= rack.floor_z + 0.02
    for a in range(6):  # no two footprints overlap
        for b in range(a + 1, 6):
            pa, pb = belief.placed[a], belief.placed[b]
            assert not (np.all(pa.lo < pb.hi) and np.all(pa.hi > pb.lo)), (pa.cls, pb.cls)


def test_racks_fill_up_with_a_typed_failure(inv):
    task = make_task("sink-to-dishwasher", inv, Cell())
    belief = Belief()
    res = fill(task, belief, inv, ["dinner_plate"] * 12)
    assert isinstance(res[-1], NoFreeSlot) and "lower rack" in res[-1].message
    assert 3 <= len(belief.placed) < 12


def test_cup_stacking_builds_a_stack_per_type(inv):
    from kitchenbot.planning.placement import nesting_height

    task = make_task("cup-stacking", inv, Cell())

    belief = Belief()
    assert task.wants(pose(inv, "cup")) and not task.wants(pose(inv, "dinner_plate"))
    fill(task, belief, inv, ["cup", "cup", "cup"])
    zs = [p.T_base_obj[2, 3] for p in belief.placed]
    xy = {tuple(np.round(p.T_base_obj[:2, 3], 6)) for p in belief.placed}
    assert len(xy) == 1  # one stack
    h = nesting_height(inv.by_name("cup"))
    assert np.allclose(np.diff(zs), h + 0.01, atol=1e-6)
    assert [p.target.kind for p in belief.placed] == ["stack_base", "stack", "stack"]
    area = Cell().spec.stacking_area
    assert task.at_target("cup", belief.placed[0].T_base_obj) and not task.at_target("cup", make_T(t=(0.5, 0, -0.1)))
    assert area.origin_xy[0] <= belief.placed[0].T_base_obj[0, 3] <= area.origin_xy[0] + area.size_xy[0]


def test_sink_pick_keeps_room_for_a_plate_still_in_the_sink(inv):
    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    plate, cup = pose(inv, "dinner_plate"), pose(inv, "cup", (0.55, 0.02, -0.1))
    belief.pending = task.pending_models([plate, cup])  # the plate is still to come
    t = task.targets(cup, belief)
    belief.record_placed(task, cup, t[0], t[0].T_base_obj)
    assert not isinstance(task.targets(plate, belief), NoFreeSlot)


def test_pick_order_takes_what_is_on_top_first_and_ignores_objects_outside_the_sink(inv):
    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    plate = pose(inv, "dinner_plate", (0.5, 0.0, -0.18))
    cup_on_plate = pose(inv, "cup", (0.55, 0.02, -0.12))
    # clear of the cup (at (0.6, -0.1) the cup's base overhung its rim: lifted, it ran 10.5 cm into the cup, which by
    # the meshes lies on it too: planning.resting)
    loose_plate = pose(inv, "side_plate", (0.64, -0.12, -0.18))
    on_counter = pose(inv, "glass", (0.1, 0.6, 0.06))
    order = task.remaining([plate, cup_on_plate, loose_plate, on_counter])
    assert order[0] is loose_plate and order.index(cup_on_plate) < order.index(plate)
    assert on_counter not in order
    assert not task.complete([plate]) and task.complete([on_counter])


def test_footprint_of_a_plate_on_edge_is_thin_in_x(inv):
    from kitchenbot.tasks.base import on_edge

    m = inv.by_name("dinner_plate")
    lo, hi, top = footprint(m, on_edge(m, (0.2, -0.5), -0.3))
    assert hi[0] - lo[0] < 0.04 and hi[1] - lo[1] > 0.25 and top > -0.3 + 0.25


def test_fallback_target_is_one_place_target_or_a_typed_failure(inv):
    from kitchenbot.planning.types import PlaceTarget

    for name in TASKS:
        task = make_task(name, inv, Cell())
        belief = Belief()
        t = task.fallback_target(pose(inv, "cup"), belief)
        assert isinstance(t, PlaceTarget) and t.kind == "drop"
    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    fill(task, belief, inv, ["dinner_plate"] * 3 + ["bowl"] * 8)  # the zone and its pile fill up
    assert isinstance(task.fallback_target(pose(inv, "mug"), belief), (PlaceTarget, NoFreeSlot))
