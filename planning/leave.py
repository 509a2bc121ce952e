"""Leaving a start within the margin of the items the tool let go among, the way it came in.

After a release the retreat ends with the full margins at the opening the pads let go with (`Planner._retreat`);
free motions are planned with the pads fully open (`Planner.plan_move`), so the wider pads can stand within the
collision margin of the item just let go and its neighbours in a rack. RRT-Connect refuses such a start
(`start_in_collision`) and the arm could not move at all: no way home, the run gave up with items left.

As a lift leaves what its item rested on (`LIFT_CONTACT_TRAVEL`), the motion first leaves along the way the tool
came in: straight back along the tool's approach axis (the place approach and the retreat reversed), else straight
up. On that first leg only the pairs within the margin at the start (the tool's parts and items, nothing else)
are relaxed: unchecked for the first `LEAVE_CONTACT_TRAVEL` metres, then at zero margin (they may stay closer than
the margin, never touch); everything else keeps its margins all along, and the leg must end with every margin
kept, so that the rest is planned as any motion (full margins).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from kitchenbot.planning.collision import TOOL_PARTS, Scene
from kitchenbot.planning.types import PlanningFailure, StartInCollision, Trajectory
from kitchenbot.transforms import trans

LEAVE_DISTANCES = (0.05, 0.10)  # m of the first leg, shortest first
LEAVE_CONTACT_TRAVEL = 0.03  # m of the first leg in which the start pairs are not checked (as a lift's)


def tool_item_pairs(pairs: Sequence[tuple[str, str]]) -> bool:
    """Whether every pair is one of the tool's parts against a perceived or placed item (what a release leaves
    close); an arm link, the cell or a map voxel within the margin is no release's doing."""
    def ok(a: str, b: str) -> bool:
        return a in TOOL_PARTS and b.startswith("obj:")
    return bool(pairs) and all(ok(a, b) or ok(b, a) for a, b in pairs)


def leave_leg(planner, scene: Scene, at: Scene, q0: np.ndarray,
              pairs: Sequence[tuple[str, str]]) -> tuple[Trajectory, np.ndarray] | PlanningFailure:
    """(first leg, its end): a straight TCP line from `q0` back along the tool axis (else straight up) by one of
    LEAVE_DISTANCES, checked in `at` (the scene with the pads where they really are, e.g. at the opening they let
    go with; else `scene`): the start `pairs` unchecked for LEAVE_CONTACT_TRAVEL, then at zero margin, everything
    else with the margins; the end valid in `scene` (the rest's). A StartInCollision naming the pairs when none
    is."""
    inner = at.touching_only(pairs)
    first = at.allowing(pairs)
    T0 = planner.robot.fk_tcp(q0)
    why: list[str] = []
    for dist in LEAVE_DISTANCES:
        for how, T_goal in (("back", T0 @ trans(0.0, 0.0, -dist)), ("up", trans(0.0, 0.0, dist) @ T0)):
            r = planner._line(inner, q0, T_goal, "leave", check_start=False, start_scene=first,
                              start_travel=min(LEAVE_CONTACT_TRAVEL, dist))
            if isinstance(r, PlanningFailure):
                why.append(f"{how} {dist:.2f} m: {r.message}")
                continue
            if not scene.valid(r[1]):
                why.append(f"{how} {dist:.2f} m: ends within the margin of {scene.colliding_pairs(r[1])}")
                continue
            return r
    return StartInCollision(f"start configuration within the margin of {_names(pairs)}; no way out along the tool "
                            f"axis or up: {'; '.join(why)}", {"pairs": list(pairs), "q": q0.tolist()})


def rise_keeping_own_margins(planner, q0: np.ndarray, up: float) -> tuple[Trajectory, np.ndarray] | PlanningFailure:
    """(trajectory, its end): the TCP straight up by `up` m from `q0` with the arm's own pairs (its links, and the
    tool against them) checked with the full margin all along, the end included; nothing else is checked (a move
    out of the sink after a failed grasp or a slip, from wherever the tool stopped among the items, as an
    unplanned straight-up move would be). A straight TCP line can swing the wrist into the forearm: unchecked, it
    could end within the margin of the arm's own links, a start every planner then refuses (no way out by
    moving the tool, the arm's own geometry goes along)."""
    scene = planner.world.scene()
    own = scene.allowing([(a, b) for a, b in scene.pair_names if a.startswith("cell:") or b.startswith("cell:")])
    return planner._line(own, q0, trans(0.0, 0.0, up) @ planner.robot.fk_tcp(q0), "back_out", check_start=False)


def _names(pairs: Sequence[tuple[str, str]]) -> str:
    return ", ".join(f"{a}/{b}" for a, b in pairs)


def join(first: Trajectory, rest: Trajectory, name: str) -> Trajectory:
    """`first` then `rest` (which starts where `first` ends, both at rest there), one sample interval apart."""
    dt = float(first.times[1] - first.times[0]) if len(first.times) > 1 else 0.008
    t = np.concatenate([first.times, first.times[-1] + dt + (rest.times[1:] - rest.times[0])])
    return Trajectory(t, np.vstack([first.q, rest.q[1:]]), name)


__all__ = ["LEAVE_CONTACT_TRAVEL", "LEAVE_DISTANCES", "join", "leave_leg", "rise_keeping_own_margins",
           "tool_item_pairs"]
