"""Getting out of a stop within the collision margin.

A motion the arm stopped early (a protective stop next to a rack wall, a slip, a stop request) can leave the
gripper a few millimetres from something: closer than the 1 cm every planned motion keeps. RRT-Connect then
refuses the start (`start_in_collision`) and, without this, the arm could never move again. What a person at the
teach pendant does is jog the tool straight out; this plans the same: a short straight TCP line, straight up
first, then up and sideways, on which the pairs that are within the margin at the start may stay closer than the
margin but never touch (zero margin), and everything else keeps its usual margin. It must end with every margin
kept, so the next planned motion starts valid.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from kitchenbot.perception.types import ObjectPose
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


def plan_escape(planner, q_start: np.ndarray, objects: Sequence[ObjectPose] = (), *,
                map_points: np.ndarray | None = None, held: Grasp | None = None) -> MovePlan | PlanningFailure:
    """A short straight TCP line from `q_start` (within the margin of something) to a configuration that keeps
    every margin, in the scene `Planner.plan_move` plans in (the gripper fully open, or around `held`), so that the
    next planned motion can start there. `StartInCollision` when q_start touches something (zero margin)."""
    q0 = np.asarray(q_start, float)
    scene = planner.scene(objects, map_points, exclude=held.obj if held is not None else None, held=held)
    pairs = scene.colliding_pairs(q0)
    if not pairs:
        return StartInCollision("nothing to escape from: the start keeps every margin", {"q": q0.tolist()})
    close = scene.touching_only(pairs)
    if not close.valid(q0):
        return StartInCollision(f"the start touches {pairs}: no straight way out is safe", {"pairs": pairs})
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
