"""What lies on what: the geometry behind a pick's "blocked by" (an item lifted straight up runs into the one lying
on it for longer than that one, lifted, runs into it) and behind the tasks' pick order (the item on top first).

Meshes of the inventory's models at their perceived poses, no margin, no robot: a few coal collision queries per
pair (about a millisecond each); answers are kept per pair of poses, since the pick order asks again every cycle
for the same belief.
"""

from __future__ import annotations

from collections.abc import Sequence

import coal
import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.collision import model_bvh
from kitchenbot.world.inventory import Inventory, ObjectModel

CLEAR_HEIGHT = 0.12  # m: how far up an item is moved to see whether it clears another
CLEAR_STEP = 0.005  # m
REACH = 0.01  # m past the two items' bounding spheres within which one may lie on the other
# m by which, for the pick order, the lift of the item below must run into the one on it longer than the other way
# round: two items side by side whose estimated poses overlap (each one's lift runs into the other about as long)
# are neither on the other
ORDER_BY = 0.01
# m: for the pick order, the item on top, lifted, must leave the one below within this travel (it rests on it; two
# items whose estimated poses run deep into each other, as a hand-placed heap's can, are not judged at all)
LEAVES_WITHIN = 0.02
# m: for the pick order, the item on top has its origin at least this much higher than the one below (not two items
# placed into each other at one height)
ABOVE = 0.005

_travel_cache: dict = {}


def clear_travel(bvh_a, T_a: np.ndarray, bvh_b, T_b: np.ndarray, height: float = CLEAR_HEIGHT,
                 step: float = CLEAR_STEP) -> float:
    """Metres `a` must be translated straight up to be clear of `b` for good (`height` + step if it never is within
    `height`); 0 when they do not touch (no margin)."""
    Ta, Tb = np.asarray(T_a, float), np.asarray(T_b, float)
    key = (id(bvh_a), Ta.tobytes(), id(bvh_b), Tb.tobytes(), height, step)
    hit = _travel_cache.get(key)
    if hit is not None:
        return hit
    tb = coal.Transform3s(Tb[:3, :3].copy(), Tb[:3, 3].copy())
    req = coal.CollisionRequest()
    last = -1.0
    for t in np.arange(0.0, height + 1e-9, step):
        ta = coal.Transform3s(Ta[:3, :3].copy(), Ta[:3, 3] + np.array([0.0, 0.0, t]))
        if coal.collide(bvh_a, ta, bvh_b, tb, req, coal.CollisionResult()):
            last = t
    out = 0.0 if last < 0 else last + step
    if len(_travel_cache) > 4000:
        _travel_cache.clear()
    _travel_cache[key] = out
    return out


def lies_on(other_bvh, T_other: np.ndarray, target_bvh, T_target: np.ndarray, by: float = 0.0,
            leaves_within: float | None = None) -> bool:
    """Whether `other` lies on (or over) `target` rather than under it: lifting `target` straight up runs into
    `other` for longer (by more than `by` metres) than lifting `other` runs into `target` (a glass leaning into a
    cup lies on the cup; the cup does not lie on the glass, although each one's lift first touches the other);
    with `leaves_within`, `other` lifted must also clear `target` within that many metres."""
    up_target = clear_travel(target_bvh, T_target, other_bvh, T_other)
    if up_target <= 0:
        return False
    up_other = clear_travel(other_bvh, T_other, target_bvh, T_target)
    return up_target > up_other + by and (leaves_within is None or up_other <= leaves_within)


def near(a: ObjectModel, T_a: np.ndarray, b: ObjectModel, T_b: np.ndarray, reach: float = REACH) -> bool:
    """Whether the two items' bounding spheres (about their origins) come within `reach` of each other."""
    d = np.linalg.norm(np.asarray(T_a, float)[:3, 3] - np.asarray(T_b, float)[:3, 3])
    return bool(d <= (a.diameter + b.diameter) / 2 + reach)


def lying_on(target: ObjectPose, objects: Sequence[ObjectPose], inventory: Inventory,
             reach: float = REACH, by: float = ORDER_BY, leaves_within: float = LEAVES_WITHIN) -> list[ObjectPose]:
    """The items of `objects` (known models, not `target` itself, their origins ABOVE higher) that lie on `target`
    (see lies_on, by `by` metres, leaving it within `leaves_within`), within `reach` of it."""
    mt = inventory.models.get(target.obj_id)
    if mt is None:
        return []
    out = []
    for o in objects:
        if o is target or (target.instance_id >= 0 and o.instance_id == target.instance_id):
            continue
        m = inventory.models.get(o.obj_id)
        if m is None or not near(m, o.T_base_obj, mt, target.T_base_obj, reach) \
                or o.T_base_obj[2, 3] <= target.T_base_obj[2, 3] + ABOVE:
            continue
        if lies_on(model_bvh(m), o.T_base_obj, model_bvh(mt), target.T_base_obj, by, leaves_within):
            out.append(o)
    return out
