"""sink-pick's counter spots keep room for what is still to come (hand-made drop zones, targets only, no motion):
a spot is chosen among several, each in its own part of the zone, by how many of the items still in the sink that
need counter room of their own still fit once it is taken (`SinkPick._leaving_room`); and a plate pile is not
closed by a taller item standing on the counter beside it (`SinkPick._carries`)."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.belief import Belief
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget
from kitchenbot.tasks import make_task
from kitchenbot.tasks.base import upright
from kitchenbot.transforms import make_T
from kitchenbot.world.cell import Cell
from kitchenbot.world.gripper import DROP_HEIGHT


def item(inv, name, xyz, k):
    m = inv.by_name(name)
    return ObjectPose(m.obj_id, m.cls, make_T(np.eye(3), xyz), 1.0, instance_id=k)


def put(task, belief, inv, name, xy, k, on=None):
    """A hand-made placement: `name` standing upright at xy on the counter (or nested on the placed item `on`)."""
    m = inv.by_name(name)
    z = task.cell.spec.drop_zone.z
    T = upright(m, xy, z)
    T[2, 3] -= DROP_HEIGHT
    if on is not None:
        T[2, 3] = on.top_z + m.extents[2] / 2
    o = item(inv, name, T[:3, 3], k)
    released = T.copy()
    released[2, 3] += DROP_HEIGHT
    belief.placed.append(task.placed_record(o, PlaceTarget(released, "drop"), T))
    return belief.placed[-1]


def test_a_glass_leaves_room_for_the_bowl_still_to_come(inv, place_in_order):
    """The zone's right part holds a plate pile (room kept for a dinner plate around it), its back row glasses, the
    left middle two cups: an L-shaped room is left at the front left, 28 x 19 cm, room for a bowl and two glasses
    side by side. The nearest free spot for the first glass is the front middle, which left no room for the bowl;
    after, all three are placed."""
    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    put(task, belief, inv, "side_plate", (0.1185, 0.5415), 0)
    for k, x in enumerate((-0.259, -0.176, -0.093, -0.010, 0.073, 0.156)):
        put(task, belief, inv, "glass", (x, 0.739), 1 + k)
    put(task, belief, inv, "glass", (-0.259, 0.656), 7)
    put(task, belief, inv, "cup", (-0.167, 0.637), 8)
    put(task, belief, inv, "cup", (-0.072, 0.637), 9)
    left = place_in_order(task, belief, ["glass", "glass", "bowl", "dinner_plate"], first_id=100)
    assert left == [], left


def test_a_mug_beside_a_plate_pile_does_not_close_it(inv):
    """A dinner plate on the counter and a mug standing beside it, the mug's box grazing the plate's (its centre
    higher than the plate's): the next dinner plate goes onto the plate (before: the pile counted as carrying
    the mug, and the plate had no spot)."""
    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    plate = put(task, belief, inv, "dinner_plate", (0.1185, 0.5415), 0)
    mug = put(task, belief, inv, "mug", (-0.057, 0.59), 1)
    assert np.all(mug.lo < plate.hi) and np.all(mug.hi > plate.lo)  # the boxes overlap
    for k, (x, y) in enumerate([(-0.26, 0.44), (-0.26, 0.55), (-0.26, 0.66), (-0.15, 0.44), (-0.15, 0.70),
                                (-0.06, 0.70), (0.04, 0.74), (0.13, 0.74), (0.22, 0.74)]):
        put(task, belief, inv, "mug", (x, y), 2 + k)
    belief.pending = [inv.by_name("dinner_plate")]
    ts = task.targets(item(inv, "dinner_plate", (0.45, 0.0, -0.15), 20), belief)
    assert not isinstance(ts, NoFreeSlot), ts
    assert np.allclose(ts[0].T_base_obj[:2, 3], plate.T_base_obj[:2, 3]) and ts[0].support == "a plate pile"
