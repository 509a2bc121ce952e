"""sink-pick keeps counter room for a plate hidden in the sink (hand-made sinks, targets only, no motion): the items
seen first are set down where they leave room for the largest plate of the inventory while no plate pile is in the
zone, so a plate that shows up once the items over it are out still finds a spot (`SinkPick._floor_needs`)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.belief import Belief
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.tasks import make_task
from kitchenbot.transforms import make_T
from kitchenbot.world.cell import Cell


def clear(task, inv, seen, hidden):
    """Place `seen` at their first targets while only they are pending (what lies under them is not seen yet),
    then `hidden`; returns the names that found no target."""
    belief = Belief()
    names = list(seen) + list(hidden)
    poses = [ObjectPose(inv.by_name(n).obj_id, inv.by_name(n).cls, make_T(np.eye(3), (0.45 + 0.01 * k, 0.0, -0.15)),
                        1.0, instance_id=k) for k, n in enumerate(names)]
    failed = []
    for k, o in enumerate(poses):
        belief.pending = task.pending_models(poses[k:len(seen)] if k < len(seen) else poses[k:])
        ts = task.targets(o, belief)
        if isinstance(ts, NoFreeSlot):
            failed.append(inv[o.obj_id].name)
            continue
        belief.record_placed(task, o, ts[0], ts[0].T_base_obj)
    return failed


@pytest.mark.parametrize("seen", [
    ["glass", "glass", "mug", "mug", "cup", "cup"],
    ["bowl", "mug", "glass", "mug", "cup"],
    ["mug", "glass", "mug", "glass", "bowl", "bowl"],
])
def test_a_plate_found_under_the_others_still_finds_room(inv, seen):
    task = make_task("sink-pick", inv, Cell())
    assert clear(task, inv, seen, ["dinner_plate", "dinner_plate"]) == []
