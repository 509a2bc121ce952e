"""sink-to-dishwasher loads the upper rack from the back: items carried from above (mouth-down or lying in the
sink) reach the whole rack and take the spots at its far side first; upright items, which only a near-level side
grasp turns over and which a level tool sets down only in the rack's near part, get the spots with the smallest x."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.belief import Belief
from kitchenbot.tasks import make_task
from kitchenbot.transforms import rot_x, rot_y
from kitchenbot.world.cell import Cell

MOUTH_DOWN = rot_x(np.pi)[:3, :3]
LYING = rot_y(np.pi / 2)[:3, :3]


def test_items_carried_from_above_fill_the_back_and_upright_ones_the_front(inv, sink_item):
    cell = Cell()
    upper = cell.spec.dishwasher.upper
    x_mid = upper.origin_xy[0] + upper.size_xy[0] / 2
    task = make_task("sink-to-dishwasher", inv, cell)
    belief = Belief()
    for name, R in [("glass", MOUTH_DOWN), ("cup", LYING), ("mug", MOUTH_DOWN)]:
        ts = task.targets(sink_item(name, R), belief)
        assert ts[0].T_base_obj[0, 3] > x_mid, (name, ts[0].T_base_obj[:3, 3])
        # the nearest spots follow, should none at the back be reachable with the item's grasps
        assert min(t.T_base_obj[0, 3] for t in ts) < x_mid
        belief.record_placed(task, sink_item(name, R), ts[0], ts[0].T_base_obj)
    ts = task.targets(sink_item("cup"), belief)  # upright: the smallest x first, all in the near half
    racks = [t.support.split()[0] for t in ts]
    # then the lower rack mouth-down, should a level grasp reach none of them
    assert racks == sorted(racks, key=lambda r: r != "rack_upper") and "rack_lower" in racks
    ts = [t for t in ts if t.support == "rack_upper"]
    assert all(t.T_base_obj[0, 3] < x_mid for t in ts)
    xs = [round(float(t.T_base_obj[0, 3]), 4) for t in ts]
    assert xs == sorted(xs) and len(ts) > 3
    # what was placed at the back left the near half free
    assert all(p.T_base_obj[0, 3] > x_mid for p in belief.placed)
