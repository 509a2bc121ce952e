"""Getting out of a stop within the collision margin.

A motion the arm stopped early (a protective stop next to a rack wall, a slip, a stop request) can leave the
gripper a few millimetres from something: closer than the 1 cm every planned motion keeps. RRT-Connect then
refuses the start (`start_in_collision`) and, without this, the arm could never move again. What a person at the
teach pendant does is jog the tool straight out; this plans the same: a short straight TCP line, straight up
first, then up and sideways, on which the pairs that are within the margin at the start may stay closer than the
margin but never touch (zero margin), and everything else keeps its usual margin. It must end with every margin
kept, so the next planned motion starts valid.

Where the open pads touch one item (the arm stands where it let an item go, e.g. after backing off a retreat that
was stopped, or a grasp cut short), no line keeps them from touching at the start; they leave it as a planned
retreat does: straight back along the tool's approach axis (else straight up), the pads allowed to touch that
item only within the grasp's contact zone (``Scene.for_grasp``), with the gripper at its real opening.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.collision import PADS
from kitchenbot.planning.types import CartesianPathFailed, Grasp, MovePlan, PlanningFailure, StartInCollision
from kitchenbot.transforms import trans

ESCAPE_DISTANCES = (0.05, 0.10)  # m of straight TCP travel tried, shortest first
ESCAPE_TILTS_DEG = (0.0, 45.0)  # from vertical; the tilted ones in eight horizontal directions


def escape_directions() -> list[np.ndarray]:
    """Unit directions in the base frame: straight up, then up and out at 45 degrees all round."""
    out = [np.array([0.0, 0.0, 1.0])]
    for a in np.radians(np.arange(0.0, 360.0, 45.0)):
        t = np.radians(ESCAPE_TILTS_DEG[1])
        out.append(np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)]))
    return out


def pad_touched(touching: Sequence[tuple[str, str]]) -> str | None:
    """The one object (its collision name, without "obj:") that only the finger pads touch when nothing else is
    touched, else None."""
    names = set()
    for a, b in touching:
        pad, other = (a, b) if a in PADS else (b, a)
        if pad not in PADS or not other.startswith("obj:"):
            return None
        names.add(other[4:])
    return names.pop() if len(names) == 1 else None


def plan_escape(planner, q_start: np.ndarray, objects: Sequence[ObjectPose] = (), *,
                map_points: np.ndarray | None = None, held: Grasp | None = None,
                opening: float | None = None) -> MovePlan | PlanningFailure:
    """A short straight TCP line from `q_start` (within the margin of something) to a configuration that keeps
    every margin, in the scene `Planner.plan_move` plans in (the gripper fully open, or around `held`), so that the
    next planned motion can start there. Where only the open pads touch one item (`opening`: where they are; by
    default fully open), they back out of it (see the module's docstring); `StartInCollision` when anything
    else touches something (zero margin)."""
    q0 = np.asarray(q_start, float)
    scene = planner.scene(objects, map_points, exclude=held.obj if held is not None else None, held=held)
    pairs = scene.colliding_pairs(q0)
    if not pairs:
        return StartInCollision("nothing to escape from: the start keeps every margin", {"q": q0.tolist()})
    close = scene.touching_only(pairs)
    if not close.valid(q0):
        touching = close.colliding_pairs(q0)
        name = pad_touched(touching) if held is None else None
        if name is None:
            return StartInCollision(f"the start touches {touching}: no straight way out is safe", {"pairs": touching})
        return _back_out(planner, scene, q0, name, objects, map_points, opening)
    T0 = planner.robot.fk_tcp(q0)
    last: PlanningFailure | None = None
    for dist in ESCAPE_DISTANCES:
        for d in escape_directions():
            T_goal = trans(*(dist * d)) @ T0
            # the whole line is checked with the close pairs at zero margin; its end must keep every margin
            r = planner._line(close, q0, T_goal, "escape")
            if isinstance(r, PlanningFailure):
                last = r
                continue
            traj, q_end = r
            if not scene.valid(q_end):
                last = CartesianPathFailed("escape: still within the margin at the end", {"pairs": scene.colliding_pairs(q_end)})
                continue
            return MovePlan(traj, {"escape_m": dist, "direction": d.round(3).tolist()})
    assert last is not None
    last.message = f"escape from {pairs}: {last.message}"
    return last


def _back_out(planner, scene, q0: np.ndarray, name: str, objects: Sequence[ObjectPose],
              map_points: np.ndarray | None, opening: float | None) -> MovePlan | PlanningFailure:
    """The open pads touch the object `name` only: straight back along the approach axis (else straight up), the
    pads allowed to touch it within the grasp's contact zone, at the gripper's `opening`; the end keeps every
    margin of `scene` (the next planned motion's)."""
    here = planner.scene(objects, map_points, **({} if opening is None else {"opening": opening}))
    leave = here.for_grasp(name)
    T0 = planner.robot.fk_tcp(q0)
    last: PlanningFailure | None = None
    for dist in ESCAPE_DISTANCES:
        for how, T_goal in (("back", T0 @ trans(0.0, 0.0, -dist)), ("up", trans(0.0, 0.0, dist) @ T0)):
            r = planner._line(leave, q0, T_goal, "escape", check_start=False)
            if isinstance(r, PlanningFailure):
                last = r
                continue
            traj, q_end = r
            if not scene.valid(q_end) or not here.valid(q_end):
                last = CartesianPathFailed("escape: still within the margin at the end",
                                           {"pairs": scene.colliding_pairs(q_end)})
                continue
            return MovePlan(traj, {"escape_m": dist, "backed_out_of": name, "direction": how})
    assert last is not None
    last.message = f"backing out of obj:{name}: {last.message}"
    return last
