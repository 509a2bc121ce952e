"""A mug may go into the rack with its handle either way along x (sink_to_dishwasher.either_way: its rack targets
have ``flip_ok``). A mug lying on its side in the sink, its handle level, is carried by grasps across its body;
at the back of the upper rack (where mouth-down items go first) none of them reaches a spot with the handle the
one way the targets used to allow, while many reach it the other way round. With the rack's near part taken by
upright items (which only a level grasp turns over, and that reaches only the near part), the mug stayed in the
sink: ``no_feasible_placement``. Hand-made: the lying mug alone in the sink, the task's back spots."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from kitchenbot.executive.belief import Belief
from kitchenbot.executive.config import CellConfig
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.grasp_synthesis import ensure_grasps
from kitchenbot.planning.pick_place import Planner
from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.tasks import make_task
from kitchenbot.tasks.base import footprint
from kitchenbot.transforms import make_T, rot_x, rot_z
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory


@pytest.fixture(scope="module")
def setup():
    cfg = CellConfig()
    inventory = ensure_grasps(Inventory.builtin())
    planner = Planner.from_config(cfg, inventory)
    return cfg, inventory, planner, make_task("sink-to-dishwasher", inventory, Cell())


def _lying_mug(planner, inventory) -> ObjectPose:
    """The mug on its side on the sink floor, in the sink's middle, its handle level (pointing along -y)."""
    m = inventory.by_name("mug")
    R = rot_x(np.pi / 2)[:3, :3] @ rot_z(np.pi / 2)[:3, :3]
    lo, hi = planner.cell.sink_interior
    c = (np.asarray(lo) + np.asarray(hi)) / 2
    bottom = float(np.min(m.points @ R[2, :]))
    return ObjectPose(m.obj_id, m.cls, make_T(R, (c[0], c[1], lo[2] - bottom + 0.001)), 1.0, instance_id=1)


def test_a_lying_mug_reaches_the_back_of_the_rack_with_its_handle_either_way(setup):
    cfg, inventory, planner, task = setup
    home = np.asarray(cfg.robot.home, float)
    mug = _lying_mug(planner, inventory)
    targets = task.targets(mug, Belief())
    assert not isinstance(targets, NoFreeSlot)
    assert all(t.flip_ok for t in targets), "a mug's rack targets allow its handle either way"
    back = [t for t in targets if t.T_base_obj[0, 3] > 0.6]  # the column the task loads first
    assert back and targets[0] is back[0]

    # the back spots with the handle one way only (as before): no grasp of the lying mug reaches any
    fixed = [replace(t, flip_ok=False) for t in back]
    before = planner.plan_pick(home, [mug], target=mug, place_target=fixed)
    assert not before.ok and before.kind == "no_feasible_placement", before

    pick = planner.plan_pick(home, [mug], target=mug, place_target=back)
    assert pick.ok, pick
    place = planner.plan_place(pick.lift.q[-1], pick.grasp, back, objects=[mug])
    assert place.ok, place
    t = place.target
    assert place.T_base_obj[2, 2] < -0.99  # mouth-down
    # turned half a turn about the vertical: the handle points the other way along x ...
    assert float(place.T_base_obj[:3, 0] @ t.T_base_obj[:3, 0]) < -0.99
    # ... and it covers the box the task kept free for it
    m = inventory.by_name("mug")
    for a, b in zip(footprint(m, place.T_base_obj)[:2], footprint(m, t.T_base_obj)[:2]):
        np.testing.assert_allclose(a, b, atol=1e-6)
