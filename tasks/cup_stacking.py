"""cup-stacking: stack each cup from the sink onto a cup of the same type in the counter stacking area.

The first cup of a type becomes the base of its stack (upright, on a free spot of the stacking area); each
further cup of that type nests on top of the stack, lifted by planning.placement's nesting height. Other objects stay in the sink. Success: no cup left in the sink, every cup verified on its stack.
"""

from __future__ import annotations

import numpy as np

from kitchenbot.perception.inventory import ObjectModel
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.placement import nesting_height
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget
from kitchenbot.tasks.base import Task, area_spots, on_top_of_same, upright

MAX_STACK = 6


def nest_offset_of(model: ObjectModel) -> float:
    """How much higher a copy of `model` rests when nested into another (planning.placement, ray cast)."""
    return nesting_height(model)


class CupStacking(Task):
    name = "cup-stacking"
    description = "stack cups onto a cup of the same type on the counter stacking area"
    success_criteria = "no cup left in the sink; every cup verified on a stack of its own type"

    def wants(self, obj: ObjectPose) -> bool:
        return obj.cls == "cup"

    def target_areas(self, cls: str) -> list[tuple[np.ndarray, np.ndarray]]:
        a = self.cell.spec.stacking_area
        return [(np.array(a.origin_xy), np.array(a.origin_xy) + np.array(a.size_xy))]

    def targets(self, obj: ObjectPose) -> list[PlaceTarget] | NoFreeSlot:
        model = self.inventory[obj.obj_id]
        stacked = [p for p in self.placed if p.obj_id == obj.obj_id and p.target.kind in ("stack", "stack_base")]
        if stacked and len(stacked) < MAX_STACK:
            T = on_top_of_same(model, stacked, nest_offset_of(model))
            if T is not None:
                return [PlaceTarget(T, "stack", free_yaw=True, support=f"stack of {model.name}")]
        area = self.cell.spec.stacking_area
        lo = np.array(area.origin_xy)
        spots = area_spots(model, lo, lo + np.array(area.size_xy), area.z, self.placed, upright, 3)
        if not spots:
            return NoFreeSlot(f"stacking area has no free spot for a new {model.name} stack")
        return [PlaceTarget(T, "stack_base", free_yaw=True, support="stacking_area") for T in spots]
