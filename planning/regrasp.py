"""Staging for a regrasp that leads somewhere: counter poses from which the next pick reaches a target.

An item that no grasp as it lies can carry to its targets is set down on the counter (``staging``) and picked
again from there. Whether that second pick can reach a target depends on the pose it is set down in: a mug
standing with its handle one way offers a level side grasp that turns it over into the rack, the other way
none does. Without this check a staging spot was taken because the *first* pick and place planned, and the
item then stayed on the counter (``no_feasible_placement`` from the staged pose, every time).

``onward_staging`` answers, before the staging is planned: for each staging target, the turns about the
item's own axis (those the planner would try, ``Planner._place_turns``) at which the item, resting there,
offers a grasp that the grasp filter accepts for the final targets (``Planner.select_grasps`` with
``place_target``: IK, collisions, a reachable release pose and its pre-place pose). Each becomes a target with
that turn fixed. A round item's grasps are the same at every turn, so it is checked at one.

Which turn leads on says nothing of whether the item can be *set down* at that turn with the grasp it is carried
there with: a mug picked by its handle arrives with a level approach fixed by its turn, and at one turn the
straight retreat from the release pulls the wrist back into the upper arm, at another it does not. With one turn
per spot (the first that led on), a staging whose place failed at both spots' first turns was given up, the item
left in the sink and what lay under it pinned for good. So after the first turn of each spot, up to
``MORE_TURNS`` more turns that lead on are kept per spot (checked in the order farthest round the axis from those
already kept: the opposite turn first, where the approach comes from the other side), after all the first ones:
the pick keeps grasps that reach any of them, and the place tries them in order.

The targets checked are those the item will have there (``targets`` a function of the item resting at the staging
pose: the executive passes the task's targets for it), not those it has where it lies: a task gives an item targets
by how it lies (a bowl mouth-down goes into the lower rack mouth-down, one standing on its rim), and the staged
item is planned for the targets of its staged pose. Checked against the targets of where it lay, a bowl lying
tilted mouth-down on two plates (its one free grasp a tilted rim pinch) found no staging spot: standing upright on
the counter no grasp turns it mouth-down, though one stands it on its rim in the lower rack, its targets there.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import PlaceTarget
from kitchenbot.world.gripper import DROP_HEIGHT

MAX_CHECKS = 8  # grasp-filter queries per staging decision (~0.5 s CPU each when nothing is feasible)
MORE_TURNS = 2  # further turns that lead on kept per spot (for a place the first turn's retreat or IK refuses)
MORE_CHECKS = 2 * MORE_TURNS  # grasp-filter queries per spot for those (~0.3 s CPU each where they lead on)


def _resting(T_target: np.ndarray) -> np.ndarray:
    """Where an item released at a target pose rests: DROP_HEIGHT lower (targets keep that clearance)."""
    T = np.array(T_target, float)
    T[2, 3] -= DROP_HEIGHT
    return T


def reaches_from(planner, obj: ObjectPose, T_rest: np.ndarray, targets: Sequence[PlaceTarget],
                 objects: Sequence[ObjectPose], map_points: np.ndarray | None, q: np.ndarray) -> bool:
    """Whether `obj` resting at `T_rest` (with `objects` around it: where it is now is not among them) offers a
    grasp that reaches one of `targets` (the grasp filter of a direct pick, planning.grasps)."""
    model = planner.inventory.models.get(obj.obj_id)
    if model is None:
        return False
    P = np.asarray(model.points, float) @ T_rest[:3, :3].T + T_rest[:3, 3]
    there = ObjectPose(obj.obj_id, obj.cls, T_rest, 1.0, points=P, instance_id=-1)
    res = planner.select_grasps(q, [*objects, there], target=there, map_points=map_points, place_target=list(targets),
                                limit=1)
    return isinstance(res, list) and len(res) > 0


Targets = Sequence[PlaceTarget] | Callable[[ObjectPose], Sequence[PlaceTarget]]


def onward_staging(planner, stage: Sequence[PlaceTarget], obj: ObjectPose, targets: Targets,
                   objects: Sequence[ObjectPose], map_points: np.ndarray | None, q: np.ndarray,
                   max_checks: int = MAX_CHECKS) -> list[PlaceTarget]:
    """The staging targets of `stage` (in order), each with its turn fixed to one from which the item, resting
    there, offers a grasp reaching one of `targets` (a list, or a function of the item resting there giving its
    targets there); those with no such turn are left out. Then, for an item that is not round, up to MORE_TURNS
    more turns per spot that lead on (MORE_CHECKS queries per spot), spot by spot. `objects`: the other items
    (not `obj`). At most `max_checks` grasp-filter queries for the first turns; targets left unchecked then are
    left out too (a staging that cannot be shown to lead on is not made)."""
    model = planner.inventory.models.get(obj.obj_id)
    if model is None or not targets:
        return []
    others = [o for o in objects if o is not obj and not (obj.instance_id >= 0 and o.instance_id == obj.instance_id)]
    round_ = model.is_rotationally_symmetric

    def leads_on(T: np.ndarray) -> bool:
        onward = targets(ObjectPose(obj.obj_id, obj.cls, _resting(T), 1.0)) if callable(targets) else targets
        return bool(onward) and reaches_from(planner, obj, _resting(T), onward, others, map_points, q)

    out: list[PlaceTarget] = []
    first: list[tuple[PlaceTarget, list[np.ndarray], int]] = []  # (spot, its turns, index of the one kept)
    checks = 0
    for t in stage:
        turns = planner._place_turns(t, obj.obj_id)
        if round_:
            turns = turns[:1]  # the same grasps at every turn about its axis
        for k, R in enumerate(turns):
            if checks >= max_checks:
                return out
            checks += 1
            T = np.asarray(t.T_base_obj, float) @ R
            if leads_on(T):
                # a round item keeps its free turn (any of them leads on); another one is set down at this turn
                out.append(t if round_ else replace(t, T_base_obj=T, free_yaw=False, flip_ok=False))
                first.append((t, turns, k))
                break
    if round_:
        return out
    for t, turns, k in first:  # more turns per spot, after every spot's first: see the module's docstring
        left = MORE_TURNS
        for j in _spread(len(turns), k)[:MORE_CHECKS]:
            if left == 0:
                break
            if j < k:  # checked above: it did not lead on
                continue
            T = np.asarray(t.T_base_obj, float) @ turns[j]
            if leads_on(T):
                out.append(replace(t, T_base_obj=T, free_yaw=False, flip_ok=False))
                left -= 1
    return out


def _spread(n: int, k: int) -> list[int]:
    """The turn indices 0..n-1 other than `k` (turns evenly round a circle), each next one the farthest round
    the circle from `k` and those before it (first the opposite one, then the quarter turns, ...)."""
    order, left = [k], [j for j in range(n) if j != k]
    while left:
        j = max(left, key=lambda i: min(min((i - o) % n, (o - i) % n) for o in order))
        order.append(j)
        left.remove(j)
    return order[1:]


__all__ = ["onward_staging", "reaches_from", "MAX_CHECKS", "MORE_TURNS"]
