"""sink-to-dishwasher leaves room in the upper rack for the open pads of a near-level side grasp: an item that is
not already mouth-down is turned over with one, so it goes PAD_ROOM from its neighbours along y (the pads' closing
axis: the hand comes in along ~x), 1 cm along x; an item already
mouth-down is set in from above and may stand 1 cm from them."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.executive.belief import Belief
from kitchenbot.tasks import make_task
from kitchenbot.tasks.base import CLEARANCE, PAD_ROOM, footprint
from kitchenbot.world.cell import Cell

MOUTH_DOWN = np.diag([1.0, -1.0, -1.0])


def gap(belief, inv, obj, T, room=(1.0, 1.0)):
    """Smallest box-to-box gap (m) between `obj` at pose T and anything placed, each axis's gap scaled by
    1/room (room: the clearance wanted along x and y, relative)."""
    lo, hi, _ = footprint(inv[obj.obj_id], T)
    out = np.inf
    for p in belief.placed:
        d = np.maximum(np.maximum(p.lo - hi, lo - p.hi), 0.0) / np.asarray(room)
        out = min(out, float(np.max(d)))
    return out


def test_an_upright_cup_gets_room_for_the_open_pads(inv, sink_item):
    task = make_task("sink-to-dishwasher", inv, Cell())
    belief = Belief()
    for name, R in [("mug", MOUTH_DOWN), ("glass", MOUTH_DOWN), ("cup", np.eye(3)), ("cup", np.eye(3))]:
        o = sink_item(name, R)
        ts = task.targets(o, belief)
        assert not isinstance(ts, NoFreeSlot), ts
        for t in ts:
            if R[2, 2] > 0:  # turned over by a side grasp coming in along ~x: the pads need their room along y
                g = gap(belief, inv, o, t.T_base_obj, (CLEARANCE, PAD_ROOM))
                assert g >= 1.0 - 1e-6, (name, g)
            else:
                g = gap(belief, inv, o, t.T_base_obj)
                assert g >= CLEARANCE - 1e-6, (name, g)
        belief.record_placed(task, o, ts[0], ts[0].T_base_obj)
    # and mouth-down items still pack tight: the second glass may stand closer than PAD_ROOM
    o = sink_item("glass", MOUTH_DOWN)
    assert min(gap(belief, inv, o, t.T_base_obj) for t in task.targets(o, belief)) < PAD_ROOM


def test_a_turned_round_item_records_its_disc_not_its_turned_box(inv, sink_item):
    from kitchenbot.transforms import rot_z

    task = make_task("sink-to-dishwasher", inv, Cell())

    belief = Belief()
    o = sink_item("cup")
    t = task.targets(o, belief)[0]
    T = t.T_base_obj @ rot_z(np.pi / 4)  # the planner turned it 45 degrees about its axis
    p = belief.record_placed(task, o, t, T)
    r = max(inv.by_name("cup").extents[:2]) / 2
    assert np.allclose(p.hi - p.lo, 2 * r)
