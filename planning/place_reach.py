"""Release poses for placing an item with a grasp at a target, the geometry computed once and kept.

Which release poses reach a place target depends on the item's model, the grasp (its pose in the item frame), the
target and the fixed cell, not on where the item lies in the sink or on the arm's configuration: the IK branches of
every candidate release pose (each turn about a free axis, each raise of the release), the pre-place IK above it
and their checks against the cell alone are computed the first time they are needed and kept. A query (the grasp
filter of plan_pick, plan_place) then checks only the candidates that the cell leaves free against its own scene
(the perceived objects, the map, what is already in the rack): the cell-only scene holds a subset of the query
scene's geometry with the same margins, so a candidate it rejects the query scene rejects too, and the answer is
the one the full enumeration gives (tests/planning/test_place_reach.py). The grasp filter and plan_place call the
same code, so they agree.

Kept per candidate in a canonical form (joints wrapped near zero): collisions and the workspace do not change under
2*pi turns of a joint, and a query wraps each joint to the value nearest its own reference configuration, as the
closed-form IK would (``RobotModel.ik_all``). A release pose without a closed-form branch (a wrist singularity)
is solved numerically from the query's configuration each time, as before (rare).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kitchenbot.planning.collision import CollisionWorld, Scene
from kitchenbot.planning.robot import RobotModel
from kitchenbot.planning.ur_ik import ik_flange
from kitchenbot.transforms import trans

# Entries kept before the cache is emptied (one entry: one item model, grasp and target; a few kB each).
MAX_ENTRIES = 4000


@dataclass
class _Pose:
    """One candidate release pose (one raise, one turn) and its IK branches that the cell leaves free."""

    T_obj: np.ndarray
    T_tcp: np.ndarray
    branches: list[np.ndarray] | None = None  # canonical joints; None: not computed yet
    numeric: bool = False  # no closed-form branch but within reach: numerical IK per query


@dataclass
class _Entry:
    raises: list[list[_Pose]] = field(default_factory=list)  # lowest release first; per raise, the turns


class PlaceReach:
    """The release-pose geometry cache of one planner (one robot, cell and settings)."""

    def __init__(self, robot: RobotModel, world: CollisionWorld):
        self.robot = robot
        self.world = world
        self._entries: dict[tuple, _Entry] = {}
        self._cell_scenes: dict[tuple, tuple[Scene, Scene]] = {}
        self.stats = {"poses_solved": 0, "queries": 0}

    # ---- the cell alone ----------------------------------------------------------------------------------------
    def _cell_only(self, release_scene: Scene) -> tuple[Scene, Scene]:
        """(release, pre-place) scenes with the cell and the held item only: the query scenes' relaxation."""
        h = release_scene.held
        key = (None,) if h is None else (id(h.model), np.asarray(h.T_tcp_obj, float).tobytes(), float(h.width))
        hit = self._cell_scenes.get(key)
        if hit is None or (h is not None and hit[0].held.model is not h.model):
            pre = self.world.scene([], None, h, opening=release_scene.opening)
            hit = (pre.for_release(None), pre)
            if len(self._cell_scenes) > 256:
                self._cell_scenes.clear()
            self._cell_scenes[key] = hit
        return hit

    def _within_reach(self, T_base_tcp: np.ndarray) -> bool:
        ur = self.robot.ur
        reach = abs(ur.a[1]) + abs(ur.a[2]) + np.hypot(ur.d[3], ur.d[4]) + 0.02
        wrist = T_base_tcp[:3, 3] - T_base_tcp[:3, :3] @ self.robot.T_flange_tcp[:3, 3]
        return bool(np.linalg.norm(wrist - np.array([0.0, 0.0, ur.d[0]])) <= reach)

    def _solve(self, pose: _Pose, cell_release: Scene | None, cell_pre: Scene | None, up: float) -> None:
        """The pose's closed-form IK branches (canonical) that the cell leaves free, with a free pre-place."""
        self.stats["poses_solved"] += 1
        robot = self.robot
        T_flange = pose.T_tcp @ np.linalg.inv(robot.T_flange_tcp)
        zero = np.zeros(6)
        raw = [q for q in (robot.wrap_near(q, zero) for q in ik_flange(robot.ur, T_flange)) if q is not None]
        pose.numeric = not raw and self._within_reach(pose.T_tcp)
        out = []
        for q in raw:
            if cell_release is not None and not cell_release.valid(q):
                continue
            if cell_pre is not None:
                q_pre = robot.ik_q(trans(0.0, 0.0, up) @ pose.T_tcp, q, max_seeds=0)
                if q_pre is None or not cell_pre.valid(q_pre):
                    continue
            out.append(q)
        pose.branches = out

    # ---- queries -----------------------------------------------------------------------------------------------
    def options(self, key: tuple, turns: list[np.ndarray], T_target: np.ndarray, T_obj_tcp: np.ndarray,
                raises: np.ndarray, up: float, max_approach_up: float, q_ref: np.ndarray,
                release_scene: Scene | None, pre_scene: Scene | None,
                first_only: bool) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """[(T_base_obj, T_base_tcp, q)] release poses valid in `release_scene` (and with a pre-place pose `up`
        above valid in `pre_scene`), over the lowest raise that has any, nearest `q_ref` first; with
        `first_only` the first one found. `key` names the geometry (item model, grasp, target, scenes' kind)."""
        self.stats["queries"] += 1
        robot = self.robot
        cell_release = cell_pre = None
        if release_scene is not None:
            cell_release, cell_pre = self._cell_only(release_scene)
            key = key + self._cell_key(release_scene)
        if pre_scene is None:
            cell_pre = None
        key = key + (pre_scene is not None,)
        entry = self._entries.get(key)
        if entry is None:
            if len(self._entries) >= MAX_ENTRIES:
                self._entries.clear()
            entry = self._entries[key] = _Entry()
            live = [T_target @ Rt for Rt in turns if (T_target @ Rt @ T_obj_tcp)[2, 2] <= max_approach_up]
            for dz in raises:
                row = []
                for To0 in live:
                    To = trans(0.0, 0.0, float(dz)) @ To0
                    row.append(_Pose(To, To @ T_obj_tcp))
                entry.raises.append(row)
        out = []
        for row in entry.raises:  # lowest release first, over all turns
            for pose in row:
                if pose.branches is None:
                    self._solve(pose, cell_release, cell_pre, up)
                if pose.numeric:
                    q = robot.ik_q(pose.T_tcp, q_ref, max_seeds=2, max_iter=40)
                    cands = [] if q is None else [q]
                else:
                    cands = [q for q in (robot.wrap_near(q, q_ref) for q in pose.branches) if q is not None]
                for q in cands:
                    if release_scene is not None and not release_scene.valid(q):
                        continue
                    if pre_scene is not None:
                        q_pre = robot.ik_q(trans(0.0, 0.0, up) @ pose.T_tcp, q, max_seeds=0)
                        if q_pre is None or not pre_scene.valid(q_pre):
                            continue
                    out.append((pose.T_obj, pose.T_tcp, q))
                    if first_only:
                        return out
            if out:
                break
        out.sort(key=lambda x: float(np.max(np.abs(x[2] - q_ref))))
        return out

    @staticmethod
    def _cell_key(scene: Scene) -> tuple:
        """What the cell-only relaxation of `scene` depends on: the held item and the pads' opening."""
        h = scene.held
        held = (None,) if h is None else (id(h.model), np.asarray(h.T_tcp_obj, float).tobytes(), float(h.width))
        return held + (round(float(scene.opening), 6),)
