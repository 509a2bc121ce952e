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
is solved numerically from the query's configuration each time, as before, unless it is clearly out of reach
(planning.ur_ik.surely_unreachable: numerical IK cannot succeed there, and near the reach limit such poses were most
of the planner's numerical IK).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from kitchenbot.planning.collision import CollisionWorld, Held, Scene
from kitchenbot.planning.robot import RobotModel
from kitchenbot.planning.ur_ik import ik_flange_batch, surely_unreachable
from kitchenbot.transforms import trans

# Entries kept before the cache is emptied (one entry: one item model, grasp and target; up to ~1 kB per pose kept).
MAX_ENTRIES = 2000


@dataclass
class _Candidate:
    """One IK branch of a release pose that the cell alone leaves free (canonical joints)."""

    q: np.ndarray
    pre_free: bool | None = None  # its pre-place pose reachable and free of the cell; None: not checked yet
    q_pre: np.ndarray | None = None  # that pre-place configuration (from q)


@dataclass
class _Pose:
    """One candidate release pose (one raise, one turn)."""

    T_obj: np.ndarray
    T_tcp: np.ndarray
    branches: list[_Candidate] = field(default_factory=list)
    numeric: bool = False  # no closed-form branch but within reach: numerical IK per query


@dataclass
class _Entry:
    raises: list[list[_Pose] | None]  # lowest release first; per raise, the turns (None: not solved yet)
    live: list[np.ndarray]  # the target's turns whose approach is from above


class OnDemand:
    """A query's (release, pre-place) scenes, built when first needed. What the cell-only relaxation needs (the
    held item, the pads' opening) is known at once; the scenes themselves (~3 ms each to build) only where a
    candidate survives the relaxation, which most grasp-filter queries never reach (on a development run 46 of
    1808 queries checked a candidate against their own scene)."""

    def __init__(self, held: Held | None, opening: float, build: Callable[[], tuple[Scene, Scene]]):
        self.held = held
        self.opening = float(opening)
        self._build = build
        self._scenes: tuple[Scene, Scene] | None = None

    def scenes(self) -> tuple[Scene, Scene]:
        if self._scenes is None:
            self._scenes = self._build()
        return self._scenes


class PlaceReach:
    """The release-pose geometry cache of one planner (one robot, cell and settings)."""

    def __init__(self, robot: RobotModel, world: CollisionWorld):
        self.robot = robot
        self.world = world
        self._entries: dict[tuple, _Entry] = {}
        self._cell_scenes: dict[tuple, tuple[Scene, Scene]] = {}
        self.stats = {"poses_solved": 0, "queries": 0}

    # ---- the cell alone ----------------------------------------------------------------------------------------
    def _cell_only(self, release_scene: Scene | OnDemand) -> tuple[Scene, Scene]:
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

    def _solve_row(self, entry: _Entry, i: int, dz: float, T_obj_tcp: np.ndarray,
                   cell_release: Callable[[], Scene] | None) -> list[_Pose]:
        """Raise `i` of an entry: every turn's closed-form IK branches at once (planning.ur_ik.ik_flange_batch),
        those the cell alone (`cell_release()`, asked only where there are branches to check) leaves free (one
        batched check)."""
        robot = self.robot
        rows = [trans(0.0, 0.0, float(dz)) @ To0 for To0 in entry.live]
        poses = [_Pose(To, To @ T_obj_tcp) for To in rows]
        entry.raises[i] = poses
        if not poses:
            return poses
        self.stats["poses_solved"] += len(poses)
        T_flange = np.array([p.T_tcp for p in poses]) @ np.linalg.inv(robot.T_flange_tcp)
        Q, ok = ik_flange_batch(robot.ur, T_flange)
        idx = np.argwhere(ok)
        Qc = Q[ok]  # canonical: angles in [-pi, pi); those outside the limits wrapped near zero
        inside = np.all((Qc >= robot.lower - 1e-9) & (Qc <= robot.upper + 1e-9), axis=1)
        keep = np.ones(len(Qc), bool)
        for k in np.flatnonzero(~inside):
            w = robot.wrap_near(Qc[k], np.zeros(6))
            if w is None:
                keep[k] = False
            else:
                Qc[k] = w
        if cell_release is not None and keep.any():
            keep[keep] = cell_release().valid_batch(Qc[keep])
        for (pi, _), q, k in zip(idx, Qc, keep):
            if k:
                poses[pi].branches.append(_Candidate(q))
        # numerical IK (per query) only where it may find something: not where the pose is clearly out of reach
        none = ~ok.any(axis=1)
        if none.any():
            none[none] = ~surely_unreachable(robot.ur, T_flange[none])
        for pose, maybe in zip(poses, none):
            pose.numeric = bool(maybe) and self._within_reach(pose.T_tcp)
        # only poses that may still yield a release are kept (an unreachable target's entry keeps next to nothing)
        entry.raises[i] = [p for p in poses if p.branches or p.numeric]
        return entry.raises[i]

    # ---- queries -----------------------------------------------------------------------------------------------
    def options(self, key: tuple, turns: Callable[[], list[np.ndarray]], T_target: np.ndarray, T_obj_tcp: np.ndarray,
                raises: np.ndarray, up: float, max_approach_up: float, q_ref: np.ndarray,
                release_scene: Scene | OnDemand | None, pre_scene: Scene | None,
                first_only: bool) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """[(T_base_obj, T_base_tcp, q)] release poses valid in `release_scene` (and with a pre-place pose `up`
        above valid in `pre_scene`), over the lowest raise that has any, nearest `q_ref` first; with
        `first_only` the first one found. `key` names the geometry (item model, grasp, target, scenes' kind).
        `release_scene` an OnDemand: both scenes from it, built when a candidate first needs them."""
        self.stats["queries"] += 1
        robot = self.robot
        on_demand = release_scene if isinstance(release_scene, OnDemand) else None
        has_release = release_scene is not None
        has_pre = pre_scene is not None or on_demand is not None
        cell_release = cell_pre = None
        if has_release:
            # the cell-only scenes when first needed: a query whose rows are all solved, or have no IK branch to
            # check, needs none of them
            src, cell = release_scene, []

            def cell_release() -> Scene:
                if not cell:
                    cell.extend(self._cell_only(src))
                return cell[0]

            if has_pre:
                def cell_pre() -> Scene:
                    cell_release()
                    return cell[1]
            key = key + self._cell_key(release_scene)
        key = key + (has_pre,)
        entry = self._entries.get(key)
        if entry is None:
            if len(self._entries) >= MAX_ENTRIES:
                self._entries.clear()
            live = [T_target @ Rt for Rt in turns() if (T_target @ Rt @ T_obj_tcp)[2, 2] <= max_approach_up]
            entry = self._entries[key] = _Entry([None] * len(raises), live)
        out = []
        for i, dz in enumerate(raises):  # lowest release first, over all turns
            row = entry.raises[i]
            if row is None:
                row = self._solve_row(entry, i, dz, T_obj_tcp, cell_release)
            for pose in row:
                if pose.numeric:
                    q = robot.ik_q(pose.T_tcp, q_ref, max_seeds=2, max_iter=40)
                    cands = [] if q is None else [(None, q)]
                elif pose.branches:
                    W = robot.wrap_near_rows(np.array([c.q for c in pose.branches]), q_ref)
                    cands = list(zip(pose.branches, W))
                else:
                    continue
                for c, q in cands:
                    if q is None:
                        continue
                    if on_demand is not None:
                        release_scene, pre_scene = on_demand.scenes()
                    if has_release and not release_scene.valid(q):
                        continue
                    if has_pre:
                        if c is not None and c.pre_free is None:  # checked once against the cell alone
                            c.q_pre = robot.ik_q(trans(0.0, 0.0, up) @ pose.T_tcp, c.q, max_seeds=0)
                            c.pre_free = c.q_pre is not None and (cell_pre is None or cell_pre().valid(c.q_pre))
                        if c is not None and not c.pre_free:
                            continue
                        if c is not None and np.array_equal(q, c.q):
                            q_pre = c.q_pre
                        else:
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
    def _cell_key(scene: Scene | OnDemand) -> tuple:
        """What the cell-only relaxation of `scene` depends on: the held item and the pads' opening."""
        h = scene.held
        held = (None,) if h is None else (id(h.model), np.asarray(h.T_tcp_obj, float).tobytes(), float(h.width))
        return held + (round(float(scene.opening), 6),)
