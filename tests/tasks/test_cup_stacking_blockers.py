"""cup-stacking moves what rests on or over a cup out of the way first (into the counter drop zone), and only
then picks the cup; items beside or below a cup stay in the sink."""

from __future__ import annotations

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.executive.belief import Belief
from kitchenbot.tasks import make_task
from kitchenbot.transforms import make_T, rot_y
from kitchenbot.world.cell import Cell


def put(inv, name, xyz, R=np.eye(3), k=0):
    m = inv.by_name(name)
    return ObjectPose(m.obj_id, m.cls, make_T(R, xyz), 1.0, instance_id=k)


def test_a_mug_leaning_into_a_cup_is_moved_to_the_drop_zone_first(inv):
    cell = Cell()
    task = make_task("cup-stacking", inv, cell)
    belief = Belief()
    cup = put(inv, "cup", (0.38, -0.04, -0.12), k=1)
    r_cup = max(inv.by_name("cup").extents[:2]) / 2
    r_mug = inv.by_name("mug").extents[1] / 2  # its half width in y, lying along x
    # a mug lying on its side next to the cup, higher up, its body ~13 mm into the cup's footprint
    mug = put(inv, "mug", (0.38, -0.04 - r_cup - r_mug + 0.013, -0.085), rot_y(np.pi / 2)[:3, :3], k=2)
    beside = put(inv, "glass", (0.60, 0.10, -0.12), k=3)  # clear of the cup: it stays
    below = put(inv, "dinner_plate", (0.40, -0.03, -0.19), k=4)  # under the cup: it stays
    todo = task.remaining([cup, mug, beside, below])
    assert [p.instance_id for p in todo] == [2, 1]
    assert not task.wants(mug)  # the audit still counts cups only
    ts = task.targets(mug, belief)
    assert not isinstance(ts, NoFreeSlot) and ts
    z = cell.spec.drop_zone
    lo, hi = np.array(z.origin_xy), np.array(z.origin_xy) + np.array(z.size_xy)
    for t in ts:
        assert t.kind == "drop" and np.all(t.T_base_obj[:2, 3] >= lo) and np.all(t.T_base_obj[:2, 3] <= hi)
    belief.record_placed(task, mug, ts[0], ts[0].T_base_obj)
    # the mug is gone from the sink: only the cup is left, and it goes to the stacking area
    assert [p.instance_id for p in task.remaining([cup, beside, below])] == [1]
    assert task.targets(cup, belief)[0].kind == "stack_base"


def test_nothing_over_a_cup_means_no_extra_moves(inv):
    task = make_task("cup-stacking", inv, Cell())
    belief = Belief()
    cups = [put(inv, "cup", (0.40 + 0.12 * k, 0.0, -0.15), k=k) for k in range(2)]
    mug = put(inv, "mug", (0.45, 0.15, -0.15), k=5)
    assert sorted(p.instance_id for p in task.remaining(cups + [mug])) == [0, 1]
    assert task.blockers(cups + [mug]) == []
