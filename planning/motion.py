"""Joint-space motion planning (OMPL RRT-Connect + simplification), straight Cartesian segments, dense checks.

Checking resolution. Rotating joint j by dq_j moves any robot point by at most r_j * |dq_j|, where r_j bounds
the distance of every geometry distal to joint j (links, tool, held object) from joint j's origin
(:func:`reach_bounds`); a joint step moves no point more than ``sum_j r_j |dq_j|`` (:func:`point_step`).

- RRT-Connect checks motions at ``planning_resolution`` of point travel (OMPL's discrete motion validator,
  resolution set from ``||r||_2``, which bounds ``sum_j r_j |dq_j|`` for an L2 joint step). Because every
  checked state keeps ``margin`` (1 cm) of clearance and no point moves more than ``planning_resolution``
  (1.5 cm) between them, every intermediate configuration keeps at least ``margin - resolution / 2`` > 0:
  the path cannot pass through anything, a 5 mm wall included.
- Every returned segment is then re-checked densely at ``validity_resolution`` (4 mm of point travel,
  :func:`check_segment`); a path that fails the dense check is never returned (the query is re-planned at
  the fine resolution once, then reported as a failure).

Budget. By default a query searches for ``timeout`` seconds and simplifies for ``simplify_timeout`` seconds of
wall time, so on a loaded machine it does less work and may fail or return another path. With ``max_iterations``
the search stops after that many RRT-Connect iterations (termination checks) and every simplification step runs;
with ``seed`` OMPL is reseeded before the query, so its plan does not depend on what was planned before it in the
process. Both together make a plan a function of its inputs alone (tests; reproducible benchmarks).
"""

from __future__ import annotations

import copy
import time
import weakref
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from kitchenbot.planning.collision import Scene, tcp_positions
from kitchenbot.planning.robot import RobotModel
from kitchenbot.planning.shortcut import shortcut_path
from kitchenbot.planning.types import (
    CartesianPathFailed,
    GoalInCollision,
    InvalidInput,
    NoIK,
    PlannerTimeout,
    PlanningFailure,
    StartInCollision,
)

ou.setLogLevel(ou.LogLevel.LOG_WARN)
try:  # OMPL seeds once per process, before its first sample: plans are reproducible run to run
    ou.RNG.setSeed(1)
except Exception:  # noqa: BLE001 - already sampling (another module used OMPL first): keep its seed
    pass


def _reseed_ompl(seed: int) -> None:
    """Restart OMPL's seed generator: the RNGs a query creates next (its state sampler, the path simplifier's)
    draw their seeds from it in creation order. OMPL logs an error for a reseed after sampling started (it is
    only non-deterministic across threads, and planning runs on one), so its log is muted meanwhile."""
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    try:
        ou.RNG.setSeed(int(seed) % (2**32 - 1) + 1)  # OMPL ignores 0
    finally:
        ou.setLogLevel(ou.LogLevel.LOG_WARN)


# ---- point-travel bounds ---------------------------------------------------------------------------------------
def reach_bounds(scene: Scene) -> np.ndarray:
    """r (6,): metres of travel of the farthest robot point per radian of each joint (upper bounds)."""
    model = scene.model
    # chain lengths between joint origins: placement of joint k+1 in joint k
    L = np.array([np.linalg.norm(model.jointPlacements[k + 1].translation) for k in range(1, 6)] + [0.0])
    ext: list[tuple[int, float]] = []
    for go in scene.gm.geometryObjects:
        j = go.parentJoint
        if j == 0:
            continue
        g = go.geometry
        p = go.placement
        c = float(np.linalg.norm(p.translation))
        if hasattr(g, "halfLength") and hasattr(g, "radius"):
            e = c + float(g.halfLength) + float(g.radius)
        elif hasattr(g, "halfSide"):
            e = c + float(np.linalg.norm(g.halfSide))
        else:  # mesh: bound by its vertices
            g.computeLocalAABB()
            aabb = g.aabb_local
            e = c + float(np.linalg.norm(np.maximum(np.abs(aabb.min_), np.abs(aabb.max_))))
        ext.append((j, e))
    r = np.zeros(6)
    for j in range(1, 7):
        best = 0.0
        for jg, e in ext:
            if jg >= j:
                best = max(best, float(np.sum(L[j - 1 : jg - 1])) + e)
        r[j - 1] = best
    return r


def point_step(r: np.ndarray, dq: np.ndarray) -> float:
    return float(np.sum(r * np.abs(dq)))


def densify(Q: np.ndarray, r: np.ndarray, step: float) -> np.ndarray:
    """The polyline Q with points inserted so that no point moves more than `step` between rows (vertices kept)."""
    Q = np.asarray(Q, float)
    out = [Q[:1]]
    for k in range(len(Q) - 1):
        n = max(1, int(np.ceil(point_step(r, Q[k + 1] - Q[k]) / step)))
        s = np.arange(1, n + 1)[:, None] / n
        out.append(Q[k] + s * (Q[k + 1] - Q[k]))
    return np.vstack(out)


def check_segment(scene: Scene, Q: np.ndarray, r: np.ndarray, step: float) -> int:
    """Dense re-check of the polyline Q: index of the first invalid densified state, or -1 when all valid."""
    return scene.first_invalid(densify(Q, r, step))


def segment_free(scene: Scene, Q: np.ndarray, r: np.ndarray, step: float) -> bool:
    """Whether the polyline Q passes the dense re-check (``check_segment(...) < 0``: the same densified states,
    the same checks), where only yes or no is wanted: the states are asked coarse to fine (both ends, then the
    midpoints of ever finer halvings, :func:`coarse_to_fine`) in one batch that stops at the first collision. A
    segment that collides mostly does so over a stretch, which the first few states of that order reach; asked
    from the start (check_segment) every state before the stretch was checked first."""
    D = densify(Q, r, step)
    return scene.all_valid(D[coarse_to_fine(len(D))])


def coarse_to_fine(n: int) -> np.ndarray:
    """Indices 0..n-1 ordered coarse to fine: 0 and n-1 first, then by the number of trailing zero bits of the
    index, most first (n/2, then n/4 and 3n/4, ...; ties in index order). A permutation of range(n), kept."""
    out = _COARSE_TO_FINE.get(n)
    if out is None:
        i = np.arange(1, max(n - 1, 1))
        tz = np.zeros(len(i), int)
        m = i.copy()
        while True:
            even = (m > 0) & (m % 2 == 0)
            if not even.any():
                break
            tz[even] += 1
            m[even] //= 2
        inner = i[np.lexsort((i, -tz))]
        out = np.concatenate([[0], [n - 1] if n > 1 else [], inner]).astype(int)
        if len(_COARSE_TO_FINE) > 4096:
            _COARSE_TO_FINE.clear()
        _COARSE_TO_FINE[n] = out
    return out


_COARSE_TO_FINE: dict[int, np.ndarray] = {}


def _why(scene: Scene, q: np.ndarray, pairs: list) -> str:
    robot = scene.world.robot
    if not robot.within_limits(q):
        return "is outside the joint limits"
    if pairs:
        return "collides (within the margin): " + ", ".join(f"{a}/{b}" for a, b in pairs[:4])
    return "puts the TCP outside the safety workspace"


# ---- RRT-Connect -----------------------------------------------------------------------------------------------
@dataclass
class JointPlan:
    path: np.ndarray  # (K, 6) simplified polyline, start and goal included
    plan_ms: float
    simplify_ms: float
    recheck_ms: float
    used_rrt: bool = True  # False: the straight joint line was free
    # the RRT path shortened for the arm's time along it (planning/shortcut.py), densely re-checked; None where
    # not asked for, or where no shortcut was found. The caller times both and keeps the faster.
    shortcut: np.ndarray | None = None
    shortcut_ms: float = 0.0


def plan_joint_path(
    scene: Scene,
    q_start: np.ndarray,
    q_goal: np.ndarray,
    *,
    timeout: float = 1.0,
    simplify_timeout: float = 0.2,
    planning_resolution: float = 0.015,
    validity_resolution: float = 0.004,
    max_iterations: int | None = None,
    seed: int | None = None,
    shortcut_rounds: int = 0,
    joint_speeds: np.ndarray | None = None,
    tcp_speed: float | None = None,
) -> JointPlan | PlanningFailure:
    """Collision-free joint polyline from q_start to q_goal (RRT-Connect, simplified, densely re-checked).
    `max_iterations` replaces the wall-clock budgets by a work budget; `seed` makes the search repeatable.
    With `shortcut_rounds` > 0 and the arm's `joint_speeds` (rad/s) and `tcp_speed` (m/s), an RRT path is also
    shortened for the time the arm takes along it (:func:`kitchenbot.planning.shortcut.shortcut_path`, every new
    segment checked at `validity_resolution`; the draws seeded by `seed`, else 0) and returned beside it."""
    if max_iterations is not None and max_iterations < 1:
        return InvalidInput(f"max_iterations {max_iterations}: expected a positive number of iterations")
    q_start, q_goal = np.asarray(q_start, float), np.asarray(q_goal, float)
    if q_start.shape != (6,) or q_goal.shape != (6,) or not (np.all(np.isfinite(q_start)) and np.all(np.isfinite(q_goal))):
        return InvalidInput("q_start/q_goal: expected 6 finite joint values each")
    if not scene.valid(q_start):
        pairs = scene.colliding_pairs(q_start)
        return StartInCollision(f"start configuration {_why(scene, q_start, pairs)}", {"pairs": pairs, "q": q_start.tolist()})
    if not scene.valid(q_goal):
        pairs = scene.colliding_pairs(q_goal)
        return GoalInCollision(f"goal configuration {_why(scene, q_goal, pairs)}", {"pairs": pairs, "q": q_goal.tolist()})
    r = reach_bounds(scene)
    t0 = time.perf_counter()
    # Straight line first: most short motions in an uncluttered cell need no search.
    if segment_free(scene, np.vstack([q_start, q_goal]), r, planning_resolution):
        t1 = time.perf_counter()
        if segment_free(scene, np.vstack([q_start, q_goal]), r, validity_resolution):
            t2 = time.perf_counter()
            return JointPlan(np.vstack([q_start, q_goal]), (t1 - t0) * 1e3, 0.0, (t2 - t1) * 1e3, used_rrt=False)
    for resolution in (planning_resolution, validity_resolution):
        res = _rrt_connect(scene, q_start, q_goal, r, timeout, simplify_timeout, resolution, max_iterations, seed)
        if isinstance(res, PlanningFailure):
            return res
        path, plan_ms, simp_ms = res
        t1 = time.perf_counter()
        free = segment_free(scene, path, r, validity_resolution)
        recheck_ms = (time.perf_counter() - t1) * 1e3
        if free:
            plan = JointPlan(path, plan_ms, simp_ms, recheck_ms)
            if shortcut_rounds > 0 and joint_speeds is not None and tcp_speed is not None:
                _shortcut(plan, scene, r, validity_resolution, shortcut_rounds, joint_speeds, tcp_speed, seed)
            return plan
    return PlannerTimeout("no path passed the dense re-check", {"resolution": validity_resolution})


def _shortcut(plan: JointPlan, scene: Scene, r: np.ndarray, resolution: float, rounds: int,
              joint_speeds: np.ndarray, tcp_speed: float, seed: int | None) -> None:
    """Sets ``plan.shortcut``: the plan's path shortened for the arm's time, where that changed it and the whole
    shortened path passes the dense check at `resolution` (its new segments were checked so already)."""
    t0 = time.perf_counter()
    robot = scene.world.robot
    P = shortcut_path(plan.path, lambda Q: segment_free(scene, Q, r, resolution),
                      np.asarray(joint_speeds, float), float(tcp_speed), lambda Q: tcp_positions(robot, Q),
                      rounds=rounds, rng=np.random.default_rng(0 if seed is None else seed))
    if (P.shape != plan.path.shape or not np.array_equal(P, plan.path)) and segment_free(scene, P, r, resolution):
        plan.shortcut = P
    plan.shortcut_ms = (time.perf_counter() - t0) * 1e3


def _bisection_order(nd: int) -> np.ndarray:
    """The order in which OMPL's DiscreteMotionValidator visits the interior states 1..nd-1 of a motion cut in
    nd segments (breadth-first midpoints), after the end state nd."""
    out = _BISECTION.get(nd)
    if out is None:
        order, queue = [nd], [(1, nd - 1)] if nd >= 2 else []
        while queue:
            lo, hi = queue.pop(0)
            mid = (lo + hi) // 2
            order.append(mid)
            if lo < mid:
                queue.append((lo, mid - 1))
            if hi > mid:
                queue.append((mid + 1, hi))
        out = _BISECTION[nd] = np.asarray(order, float) / float(nd)
        if len(_BISECTION) > 4096:
            _BISECTION.clear()
    return out


_BISECTION: dict[int, np.ndarray] = {}


class _BatchMotionValidator(ob.MotionValidator):
    """OMPL's discrete motion check, the same states asked in one batch call: a motion s1 -> s2 is valid when s2
    and the states at j / nd of the way (j = 1..nd-1, nd = the state space's ``validSegmentCount``, interpolated
    as ``RealVectorStateSpace::interpolate`` does: ``a + (b - a) * t``) are all valid; s1 is assumed valid, as
    OMPL's ``DiscreteMotionValidator`` assumes it. The states go to :meth:`Scene.all_valid` in OMPL's bisection
    order, which stops at the first collision; RRT-Connect's per-state Python callback was most of its CPU."""

    def __init__(self, si, space, scene: Scene):
        super().__init__(si)
        self.space = space
        self.scene: Scene | None = scene

    def checkMotion(self, s1, s2) -> bool:  # noqa: N802 - OMPL's name
        a = np.array([s1[0], s1[1], s1[2], s1[3], s1[4], s1[5]])
        b = np.array([s2[0], s2[1], s2[2], s2[3], s2[4], s2[5]])
        t = _bisection_order(max(int(self.space.validSegmentCount(s1, s2)), 1))
        Q = a + (b - a) * t[:, None]
        Q[0] = b  # the end state itself (a + (b - a) * 1 need not round to b)
        return self.scene.all_valid(Q)


def _rrt_connect(scene, q_start, q_goal, r, timeout, simplify_timeout, resolution, max_iterations=None, seed=None):
    robot = scene.world.robot
    if seed is not None:
        _reseed_ompl(seed)
    space = ob.RealVectorStateSpace(6)
    bounds = ob.RealVectorBounds(6)
    # Search box: the joint limits, narrowed to a turn around start and goal (no multi-turn detours).
    lo = np.maximum(robot.lower, np.minimum(q_start, q_goal) - np.pi)
    hi = np.minimum(robot.upper, np.maximum(q_start, q_goal) + np.pi)
    for i in range(6):
        bounds.setLow(i, float(lo[i]))
        bounds.setHigh(i, float(hi[i]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    valid = scene.valid

    def checker(s) -> bool:
        return valid(np.array([s[0], s[1], s[2], s[3], s[4], s[5]]))

    ss.setStateValidityChecker(checker)
    si = ss.getSpaceInformation()
    step_l2 = resolution / float(np.linalg.norm(r))
    si.setStateValidityCheckingResolution(step_l2 / space.getMaximumExtent())
    motions = _BatchMotionValidator(si, space, scene)
    si.setMotionValidator(motions)
    planner = og.RRTConnect(si)
    planner.setRange(0.8)
    ss.setPlanner(planner)
    start, goal = space.allocState(), space.allocState()
    for i in range(6):
        start[i] = float(q_start[i])
        goal[i] = float(q_goal[i])
    ss.setStartAndGoalStates(start, goal)
    t0 = time.perf_counter()
    if max_iterations is None:
        solved = ss.solve(float(timeout))
        budget = f"{timeout:.2f} s"
    else:
        checks = [0]

        def spent() -> bool:  # OMPL evaluates it once per iteration (and before each goal sample)
            checks[0] += 1
            return checks[0] > max_iterations

        solved = ss.solve(ob.PlannerTerminationCondition(spent))
        budget = f"{max_iterations} iterations"
    t1 = time.perf_counter()
    if not solved or not ss.haveExactSolutionPath():
        return PlannerTimeout(f"RRT-Connect found no path in {budget}", {"resolution": resolution})
    if simplify_timeout > 0:
        # OMPL's PathSimplifier steps, not simplifySolution(): that one runs B-spline smoothing passes that
        # overshoot any time budget here (~200-400 ms per query with Python validity checks) for a ~20 %
        # shorter path; vertex reduction + partial shortcuts take ~20 ms. Steps stop once the budget is spent.
        ps = ss.getPathSimplifier()
        path = ss.getSolutionPath()
        for step in (ps.reduceVertices, ps.collapseCloseVertices, ps.partialShortcutPath, ps.reduceVertices):
            if max_iterations is None and time.perf_counter() - t1 > simplify_timeout:
                break  # with a work budget every step runs: the path must not depend on the machine's load
            step(path)
    t2 = time.perf_counter()
    motions.scene = None  # OMPL's objects may outlive the query: do not keep the scene alive with them
    p = ss.getSolutionPath()
    path = np.array([[p.getState(k)[i] for i in range(6)] for k in range(p.getStateCount())])
    path[0], path[-1] = q_start, q_goal
    return path, (t1 - t0) * 1e3, (t2 - t1) * 1e3


def _line_collides(scene: Scene, q: np.ndarray, at: float | None) -> CartesianPathFailed:
    pairs = scene.colliding_pairs(q)
    what = ", ".join(f"{a}/{b}" for a, b in pairs[:4]) or "TCP leaves the workspace"
    return CartesianPathFailed(f"straight line collides ({what})", {"pairs": pairs, "q": np.asarray(q).tolist()})


# ---- straight Cartesian segments ----------------------------------------------------------------------------------
class _LinePath(np.ndarray):
    """A straight line's joint polyline (rows), with the line's start TCP position `p0`."""

    p0: np.ndarray


# Straight lines whose IK is kept per robot model (one entry: the polyline of one line, ~100 rows of 6 floats).
LINE_IK_ENTRIES = 512
_line_ik_kept: "weakref.WeakKeyDictionary[RobotModel, OrderedDict]" = weakref.WeakKeyDictionary()


def line_ik(robot: RobotModel, q_start: np.ndarray, T_goal: np.ndarray,
            step: float) -> _LinePath | PlanningFailure:
    """The joint polyline of :func:`cartesian_line` before any collision check: IK at every `step` metres along
    the line, seeded with the previous solution; a failure where a step has no IK or the solution jumps.

    It depends on the robot, `q_start`, `T_goal` and `step` alone (the numerical IK is deterministic), not on the
    scene, so it is kept (least recently used dropped): the planner asks for the same line in several scenes
    (a retreat per gripper opening at release, a line re-planned after a scene changed only elsewhere), and
    each repeat costs only its collision check. Callers must not modify the returned array."""
    q_start = np.asarray(q_start, float)
    T_goal = np.asarray(T_goal, float)
    key = (q_start.tobytes(), T_goal.tobytes(), float(step))
    kept = _line_ik_kept.get(robot)
    if kept is None:
        kept = _line_ik_kept[robot] = OrderedDict()
    hit = kept.get(key)
    if hit is not None:
        kept.move_to_end(key)
        return hit if not isinstance(hit, PlanningFailure) else copy.deepcopy(hit)
    out = _solve_line_ik(robot, q_start, T_goal, step)
    kept[key] = out
    if len(kept) > LINE_IK_ENTRIES:
        kept.popitem(last=False)
    return out if not isinstance(out, PlanningFailure) else copy.deepcopy(out)


def _solve_line_ik(robot: RobotModel, q_start: np.ndarray, T_goal: np.ndarray,
                   step: float) -> _LinePath | PlanningFailure:
    from scipy.spatial.transform import Rotation, Slerp

    T0 = robot.fk_tcp(q_start)
    p0, p1 = T0[:3, 3], np.asarray(T_goal, float)[:3, 3]
    rots = Rotation.from_matrix(np.stack([T0[:3, :3], np.asarray(T_goal)[:3, :3]]))
    ang = float(np.linalg.norm((rots[0].inv() * rots[1]).as_rotvec()))
    dist = float(np.linalg.norm(p1 - p0))
    n = max(1, int(np.ceil(max(dist / step, ang * 0.2 / step))))
    slerp = Slerp([0.0, 1.0], rots)
    R_line = slerp(np.arange(1, n + 1) / n).as_matrix()  # every step's orientation at once (the same values)
    Q = [q_start]
    q = q_start
    for k in range(1, n + 1):
        s = k / n
        T = np.eye(4)
        T[:3, :3] = R_line[k - 1]
        T[:3, 3] = p0 + s * (p1 - p0)
        res = robot.ik(T, q, max_seeds=0)
        if res.q is None:
            return NoIK(f"straight line: no IK at {s * 100:.0f} % of the segment", {"T": T.tolist()})
        # No branch flip: the joint-space chord between consecutive solutions must keep the TCP on the line
        # (its midpoint within 2 mm of the line's), and no joint may turn by more than 0.5 rad in one step.
        mid = robot.fk_tcp((q + res.q) / 2)[:3, 3]
        ideal = p0 + (s - 0.5 / n) * (p1 - p0)
        if np.linalg.norm(mid - ideal) > max(0.002, 0.5 * step) or np.max(np.abs(res.q - q)) > 0.5:
            return CartesianPathFailed("straight line: the IK solution jumps (singularity or branch change)",
                                       {"at": s})
        q = res.q
        Q.append(q)
    out = np.asarray(Q).view(_LinePath)
    out.p0 = p0.copy()
    out.flags.writeable = False
    return out


def cartesian_line(
    robot: RobotModel,
    scene: Scene,
    q_start: np.ndarray,
    T_goal: np.ndarray,
    *,
    step: float = 0.004,
    check_step: float = 0.004,
    check_start: bool = True,
    start_scene: Scene | None = None,
    start_travel: float = 0.0,
    clear_within: float = 0.0,
    clear_scene: Scene | None = None,
    info: dict | None = None,
) -> np.ndarray | PlanningFailure:
    """Joint polyline moving the TCP on a straight line (orientation interpolated) from FK(q_start) to T_goal.

    IK at every `step` metres along the line, seeded with the previous solution (no branch switches: a joint
    jump larger than the line step can explain is a failure), each segment densely checked in `scene`.

    `start_scene` (e.g. the lift's scene without the contacts the held object rests in) is used for the first
    `start_travel` metres of TCP travel, `scene` after that. With `clear_within` > `start_travel`, what
    `scene` rejects may also last longer, up to `clear_within` metres, when it is one contact that starts at
    `q_start` and, once it has cleared, never comes back (an item lifted out of a neighbour whose estimated pose
    overlaps it by more than `start_travel`); beyond `start_travel` the states must also be valid in
    `clear_scene` (default `start_scene`: which start contacts may last longer). `info` (a dict) receives
    ``contact_travel``: the metres of travel in which start contacts were allowed.
    """
    q_start = np.asarray(q_start, float)
    Q = line_ik(robot, q_start, T_goal, step)
    if isinstance(Q, PlanningFailure):
        return Q
    p0 = Q.p0
    Q = np.array(Q)  # a plain copy: the kept IK polyline is never handed out
    r = reach_bounds(scene)
    if info is not None:
        info["contact_travel"] = start_travel if start_scene is not None else 0.0
    if start_scene is not None and start_travel > 0:
        # the first `start_travel` metres are checked in `start_scene` (e.g. without the held object, which
        # leaves the contacts it rests in), the rest in `scene`
        m = int(np.searchsorted(np.linalg.norm(np.array([robot.fk_tcp(q)[:3, 3] for q in Q]) - p0, axis=1), start_travel))
        m = min(max(m, 1), len(Q) - 1)
        bad = check_segment(start_scene, Q[: m + 1], r, check_step)
        if bad >= 0:
            dense = densify(Q[: m + 1], r, check_step)
            return _line_collides(start_scene, dense[bad], bad / max(len(dense) - 1, 1) * start_travel)
        bad = check_segment(scene, Q[m:], r, check_step)
        if bad >= 0:
            if clear_within > start_travel:  # a start contact may last longer if it is then left for good
                return _check_leaving_contacts(robot, scene, start_scene, clear_scene or start_scene, Q, p0, r,
                                               check_step, start_travel, clear_within, info)
            dense = densify(Q[m:], r, check_step)
            return _line_collides(scene, dense[bad], None)
        return Q
    # the first state may touch when not check_start (e.g. the release pose): check from the first step on
    checked = Q if check_start else Q[1:]
    bad = check_segment(scene, checked, r, check_step) if len(checked) > 1 or check_start else -1
    if bad >= 0:
        return _line_collides(scene, densify(checked, r, check_step)[bad], None)
    return Q



def _check_leaving_contacts(robot: RobotModel, scene: Scene, start_scene: Scene, clear_scene: Scene, Q: np.ndarray,
                            p0: np.ndarray, r: np.ndarray, check_step: float, start_travel: float, clear_within: float,
                            info: dict | None) -> np.ndarray | PlanningFailure:
    """The check of :func:`cartesian_line` with a contact window that lasts until the start contacts clear.

    Every densified state must be valid in `start_scene` (no contact but the start ones), those beyond
    `start_travel` also in `clear_scene` (no start contact but those that may last). The states `scene`
    rejects must all lie within `start_travel` of the start, or form one unbroken run from the start that ends
    within `clear_within` (the contact is left and not made again: the simulator, like a real arm's contact
    detection, tolerates a resting contact that lasts while the item is lifted out, not one that breaks and
    comes back)."""
    dense = densify(Q, r, check_step)
    travel = np.linalg.norm(tcp_positions(robot, dense) - p0, axis=1)
    ok_start = start_scene.valid_batch(dense)
    if not ok_start.all():
        return _line_collides(start_scene, dense[int(np.argmin(ok_start))], None)
    beyond = np.flatnonzero(travel > start_travel)
    if clear_scene is not start_scene and len(beyond):
        ok_clear = clear_scene.valid_batch(dense[beyond])
        if not ok_clear.all():
            k = int(beyond[np.argmin(ok_clear)])
            f = _line_collides(clear_scene, dense[k], None)
            f.details["travel"] = float(travel[k])
            return f
    bad = np.flatnonzero(~scene.valid_batch(dense))
    window = start_travel
    if len(bad):
        last = int(bad[-1])
        if travel[last] > start_travel:
            unbroken = len(bad) == last + 1  # every state from the start up to `last` is in contact
            if not unbroken or travel[last] > clear_within:
                k = int(bad[np.argmax(travel[bad] > start_travel)])
                f = _line_collides(scene, dense[k], None)
                f.message = (f"{f.message[:-1]}, {travel[k] * 100:.1f} cm into the line: "
                             + ("a start contact lasts too long)" if unbroken else "a contact after the start)"))
                f.details["travel"] = float(travel[k])
                return f
            window = float(travel[min(last + 1, len(travel) - 1)])
    if info is not None:
        info["contact_travel"] = window
    return Q
