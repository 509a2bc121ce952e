"""A staging for a regrasp is made where the next pick reaches the targets the item will have *there*
(planning/regrasp.py, StageForRegrasp): the task gives an item its targets by how it lies, and a staged item is
planned for those of its staged pose. Hand-made from a sink-to-dishwasher reproduction: a bowl lying mouth-down,
tilted about 50 degrees towards the robot (it lay on two plates against the sink's far wall). Its targets where it
lies are mouth-down spots (lower rack, upper rack); its one way out is a staging upright on the counter, from
where a rim pinch stands it on its rim in the lower rack (its targets standing). Checked against the targets of
where it lay (mouth-down: no grasp of an upright bowl turns it over), no staging spot led on, and it stayed in
the sink with the two plates under it."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.belief import Belief
from kitchenbot.executive.config import CellConfig
from kitchenbot.executive.strategies import ItemPlan, PlanRequest, StageForRegrasp
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.grasp_synthesis import ensure_grasps
from kitchenbot.planning.pick_place import Planner
from kitchenbot.planning.regrasp import _resting, reaches_from
from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.tasks import make_task
from kitchenbot.world.attitude import faces_down, faces_up
from kitchenbot.world.inventory import Inventory


@pytest.fixture(scope="module")
def planner():
    return Planner.from_config(CellConfig(), ensure_grasps(Inventory.builtin()))


def _tilted_bowl(planner) -> ObjectPose:
    R = np.array([[0.0, 0.66, -0.75], [0.94, 0.26, 0.24], [0.35, -0.70, -0.62]])
    U, _, Vt = np.linalg.svd(R)  # the nearest rotation
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = U @ Vt, (0.647, -0.022, -0.113)
    m = planner.inventory.by_name("bowl")
    return ObjectPose(m.obj_id, m.cls, T, 1.0, instance_id=2)


def test_a_tilted_mouth_down_bowl_is_staged_where_its_targets_standing_are_reached(planner):
    task = make_task("sink-to-dishwasher", planner.inventory, planner.cell)
    bowl = _tilted_bowl(planner)
    assert faces_down(bowl.T_base_obj)
    b = Belief()
    targets = task.targets(bowl, b)
    assert not isinstance(targets, NoFreeSlot) and all(faces_down(t.T_base_obj) for t in targets)
    home = np.asarray(CellConfig().robot.home, float)
    notes = []
    req = PlanRequest(bowl, list(targets), None, task, b, planner, joints=lambda: home, escape=lambda: False,
                      note=lambda kind, name, **kw: notes.append(name), check_deadline=lambda: None,
                      scene_objs=[bowl])

    plan = StageForRegrasp().plan(req)

    assert "no staging spot from which a grasp reaches a target" not in notes
    assert isinstance(plan, ItemPlan) and plan.staging, plan
    staged = plan.place.target
    assert staged.kind == "stage" and faces_up(staged.T_base_obj)
    # from there a grasp reaches one of the targets the task gives it standing there (on its rim, lower rack)
    there = ObjectPose(bowl.obj_id, bowl.cls, _resting(plan.place.T_base_obj), 1.0)
    onward = task.targets(there, b)
    assert not isinstance(onward, NoFreeSlot)
    assert reaches_from(planner, bowl, there.T_base_obj, onward, [], None, home)
    # and none reaches the targets it had lying mouth-down: that check is what left it in the sink
    assert not reaches_from(planner, bowl, there.T_base_obj, targets, [], None, home)
