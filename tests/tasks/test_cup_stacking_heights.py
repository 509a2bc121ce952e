"""cup-stacking: cups that nest stack up to MAX_STACK; cups that do not nest (straight sides: each rests on the rim
of the one below) stop at MAX_STACK_HEIGHT and start a stack of their own beside it."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.belief import Belief
from kitchenbot.perception.types import ObjectPose
from kitchenbot.tasks import make_task
from kitchenbot.tasks.cup_stacking import MAX_STACK, MAX_STACK_HEIGHT
from kitchenbot.transforms import make_T
from kitchenbot.world.cell import Cell
from kitchenbot.world.dishware import DishSpec, _vessel, build_mesh
from kitchenbot.world.inventory import Inventory, ObjectModel, _diameter


def _cup(obj_id: int, name: str, r_bottom: float, r_top: float, height: float) -> ObjectModel:
    mesh = build_mesh(DishSpec(name, "cup", (0.5, 0.5, 0.5), _vessel(r_bottom, r_top, height), 0.0035))
    return ObjectModel(obj_id, name, "cup", mesh, _diameter(np.asarray(mesh.vertices)),
                       symmetries_continuous=[{"axis": [0, 0, 1], "offset": [0, 0, 0]}])


def _stack(task, model: ObjectModel, n: int) -> list[str]:
    """Put `n` copies of `model` from the sink at their first target each; the kinds of target they got."""
    belief = Belief()
    kinds = []
    for k in range(n):
        obj = ObjectPose(model.obj_id, "cup", make_T(np.eye(3), (0.45 + 0.01 * k, 0.0, -0.15)), 1.0, instance_id=k)
        t = task.targets(obj, belief)[0]
        kinds.append(t.kind)
        belief.record_placed(task, obj, t, t.T_base_obj)
    return kinds


def test_straight_cups_do_not_tower_but_tapered_ones_nest_to_the_limit():
    straight = _cup(1, "straight_cup", 0.040, 0.040, 0.090)  # rests on the rim below: 9 cm higher each
    tapered = _cup(2, "tapered_cup", 0.026, 0.040, 0.078)  # nests: 2 cm higher each
    inv = Inventory([straight, tapered])
    task = make_task("cup-stacking", inv, Cell())
    kinds = _stack(task, straight, 4)
    assert kinds == ["stack_base", "stack", "stack_base", "stack"]  # two stacks of two, none of three (27 cm)
    kinds = _stack(task, tapered, MAX_STACK)
    assert kinds == ["stack_base"] + ["stack"] * (MAX_STACK - 1)  # 6 nested: 18 cm, under MAX_STACK_HEIGHT
    assert 0.08 + (MAX_STACK - 1) * 0.02 < MAX_STACK_HEIGHT
