"""cup-stacking: stack each cup from the sink onto a cup of the same type in the counter stacking area.

The first cup of a type becomes the base of its stack (upright, on a free spot of the stacking area); each
further cup of that type nests on top of the stack, lifted by planning.placement's nesting height. Other objects
stay in the sink, except those resting on or over a cup (a mug leaning into it, a glass lying across it): as a
person would, they are moved out of the way first, into the counter drop zone (upright, or set down the way they
lay), since a cup cannot be lifted out from under them. Success: no cup left in the sink, every cup verified on
its stack.
"""

from __future__ import annotations

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.placement import nesting_height
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget
from kitchenbot.tasks.base import (
    Holdings,
    Task,
    _drop_zone_targets,
    area_spots,
    as_is,
    footprint,
    on_top_of_same,
    upright,
)
from kitchenbot.world.attitude import is_upright
from kitchenbot.world.gripper import DROP_HEIGHT
from kitchenbot.world.inventory import ObjectModel

MAX_STACK = 6
# m: a stack stands no taller than this above the stacking area (about six nested builtin cups, 0.23 m). A cup that
# does not nest (straight sides: it rests on the rim of the one below, a whole cup height higher) reaches it at two
# or three: the next one starts a stack of its own, as a person stands non-nesting cups side by side rather than in a
# tower that tips and that the gripper, holding a cup by its side, can no longer reach over.
MAX_STACK_HEIGHT = 0.25
STACK_RADIUS = 0.03  # m: cups whose centres are this close stand on one stack


def nest_offset_of(model: ObjectModel) -> float:
    """How much higher a copy of `model` rests when nested into another (planning.placement, ray cast)."""
    return nesting_height(model)


class CupStacking(Task):
    name = "cup-stacking"
    description = "stack cups onto a cup of the same type on the counter stacking area"
    success_criteria = "no cup left in the sink; every cup verified on a stack of its own type"

    def wants(self, obj: ObjectPose) -> bool:
        return obj.cls == "cup"

    def _rests_over(self, o: ObjectPose, cup: ObjectPose) -> bool:
        """`o` rests higher than `cup` and some of its surface lies over the cup's footprint, above the cup's
        centre: lifting the cup would hit it (o leans into, onto or across the cup)."""
        if o.T_base_obj[2, 3] <= cup.T_base_obj[2, 3]:
            return False
        lo, hi, _ = footprint(self.inventory[cup.obj_id], cup.T_base_obj)
        m = self.inventory[o.obj_id]
        P = m.points @ o.T_base_obj[:3, :3].T + o.T_base_obj[:3, 3]
        inside = np.all((P[:, :2] > lo) & (P[:, :2] < hi), axis=1) & (P[:, 2] > cup.T_base_obj[2, 3])
        return bool(inside.any())

    def blockers(self, poses: list[ObjectPose]) -> list[ObjectPose]:
        """Objects in the sink this task does not want that rest on or over a cup it wants (or on such an
        object, transitively): they have to be moved out of the way first."""
        todo = [p for p in poses if self.in_sink(p) and self.wants(p)]
        out: list[ObjectPose] = []
        grew = True
        while grew:
            grew = False
            for o in poses:
                if self.wants(o) or not self.in_sink(o) or any(o is b for b in out):
                    continue
                if any(self._rests_over(o, c) for c in todo + out):
                    out.append(o)
                    grew = True
        return out

    def remaining(self, poses: list[ObjectPose]) -> list[ObjectPose]:
        """The cups still in the sink plus what rests on them; those blockers first (uncovered ones first, top
        down), then the cups in Task.remaining's order."""
        cups = super().remaining(poses)
        blocking = self.blockers(poses)
        return sorted(blocking, key=lambda p: (self._covered(p, poses), -p.T_base_obj[2, 3])) + cups

    def targets(self, obj: ObjectPose, belief: Holdings) -> list[PlaceTarget] | NoFreeSlot:
        if not self.wants(obj):
            return self._out_of_the_way(obj, belief)
        return self._stack_targets(obj, belief)

    def _out_of_the_way(self, obj: ObjectPose, belief: Holdings) -> list[PlaceTarget] | NoFreeSlot:
        """A blocker goes to the counter drop zone: upright, or (not upright in the sink, where no grasp may
        reach upright) set down the way it lies."""
        model = self.inventory[obj.obj_id]
        out = _drop_zone_targets(model, self.cell.spec.drop_zone, list(belief.placed), 3)
        for t in out:
            t.support = "counter (out of a cup's way)"
        R = obj.T_base_obj[:3, :3]
        if not is_upright(obj.T_base_obj):
            z = self.cell.spec.drop_zone
            lo = np.array(z.origin_xy)
            for T in area_spots(model, lo, lo + np.array(z.size_xy), z.z, list(belief.placed), as_is(R), 2,
                                centre_inside="any"):
                out.append(PlaceTarget(T, "drop", free_yaw=False, support="counter (out of a cup's way, as it lay)"))
        return out or NoFreeSlot(f"drop zone has no free spot to move the {obj.cls} off a cup")

    def target_areas(self, cls: str) -> list[tuple[np.ndarray, np.ndarray]]:
        a = self.cell.spec.stacking_area
        return [(np.array(a.origin_xy), np.array(a.origin_xy) + np.array(a.size_xy))]

    def _stack_targets(self, obj: ObjectPose, belief: Holdings) -> list[PlaceTarget] | NoFreeSlot:
        model = self.inventory[obj.obj_id]
        stacked = [p for p in belief.placed if p.obj_id == obj.obj_id and p.target.kind in ("stack", "stack_base")]
        area = self.cell.spec.stacking_area
        top: list[PlaceTarget] = []
        # each stack of this type (cups standing on one spot), the highest first: on its top while it holds fewer
        # than MAX_STACK cups and stays under MAX_STACK_HEIGHT with this one
        stacks: list[list] = []
        for p in stacked:
            for s in stacks:
                if np.hypot(*(p.T_base_obj[:2, 3] - s[0].T_base_obj[:2, 3])) < STACK_RADIUS:
                    s.append(p)
                    break
            else:
                stacks.append([p])
        for s in sorted(stacks, key=lambda s: -max(p.T_base_obj[2, 3] for p in s)):
            T = on_top_of_same(model, s, nest_offset_of(model)) if len(s) < MAX_STACK else None
            if T is not None and T[2, 3] - DROP_HEIGHT + model.extents[2] / 2 - area.z <= MAX_STACK_HEIGHT:
                top.append(PlaceTarget(T, "stack", free_yaw=True, support=f"stack of {model.name}"))
        top = top[:2]
        lo = np.array(area.origin_xy)
        # A new stack of the same type after the top of the existing one (the planner takes the first it reaches),
        # as a person starts another stack when the first one's top cannot be reached with the cup's grasps (a
        # cup flipped on the counter is held by its side, level, and a stack's top may be out of that grasp's reach).
        spots = area_spots(model, lo, lo + np.array(area.size_xy), area.z, list(belief.placed), upright,
                           3 if not top else 2)
        out = top + [PlaceTarget(T, "stack_base", free_yaw=True, support="stacking_area") for T in spots]
        return out or NoFreeSlot(f"stacking area has no free spot for a new {model.name} stack")
