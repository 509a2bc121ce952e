"""The planning entry points the executive calls: pick an object, place the held object, move.

``Planner`` owns the robot model (IK), the collision world and the settings. Each call builds the scene's
collision objects from what perception returned (object poses + unexplained map points) and returns a plan or
a typed :class:`~kitchenbot.planning.types.PlanningFailure` (never raises for planning outcomes; bad inputs
give ``InvalidInput``).

Pick = approach (RRT-Connect to the pre-grasp, gripper open at the grasp's opening) + grasp_in (straight line
along the approach axis, pads may touch the target) + lift (straight up with the object attached).
Place = transfer (RRT-Connect with the object attached to the pre-place pose above the target) + lower
(straight down) + retreat (straight back along the approach axis after opening).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import coal
import numpy as np

from kitchenbot.drivers.errors import LimitViolation
from kitchenbot.drivers.safety import SafetyLimits
from kitchenbot.drivers.ur_kinematics import ur_model
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.collision import TOOL_PARTS, CollisionWorld, Held, Scene, SceneObject, coal_transform
from kitchenbot.planning.doubtful_support import (NARROWING_TOL, POINT_REACH, POSE_ERROR, approaches_points,
                                                  own_axis_directions, pose_doubtful)
from kitchenbot.planning.grasp_synthesis import ensure_grasps
from kitchenbot.planning.grasps import VOXELS, GraspStats, object_name, select_grasps
from kitchenbot.planning.lift import (base_directions, directions_away, lift_fallbacks, repeats_stopped,
                                      separating_legs, sidesteps)
from kitchenbot.planning.lift_gaps import LiftGaps
from kitchenbot.planning.motion import cartesian_line, plan_joint_path, reach_bounds, segment_free
from kitchenbot.planning.place_reach import OnDemand, PlaceReach
from kitchenbot.planning.resting import clear_travel, lies_on
from kitchenbot.planning.robot import RobotModel
from kitchenbot.planning.settings import PlanningSettings
from kitchenbot.planning.timing import time_parameterise
from kitchenbot.planning.types import (
    CartesianPathFailed,
    Grasp,
    InvalidInput,
    MovePlan,
    NoFeasiblePlacement,
    NoFreeSlot,
    PickPlan,
    PlaceTarget,
    PlacePlan,
    PlanningFailure,
    StartInCollision,
    Trajectory,
    marks_of,
)
from kitchenbot.transforms import check_rigid, inv, rot_z, trans
from kitchenbot.world.attitude import is_lying
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory


LIFT_CONTACT_TRAVEL = 0.03  # m of lift during which the held object may still touch what it rested on
# A contact the held object has at the grasp may last longer, up to this many metres of lift, when it is left
# for good (one unbroken run from the start): with estimated poses, an item and the one it rests in (a glass
# leaning into a cup) often overlap by more than 3 cm in the model while, in the world, they only touch. The
# simulator (fakes/collision.py) tolerates such a start contact for 10 cm.
LIFT_CLEAR_TRAVEL = 0.06
# m: how much deeper than at the grasp the held item may overlap a neighbour it does not rest on during the first
# LIFT_CONTACT_TRAVEL of its lift (the mesh overlap's measurement noise; any real deepening is a new contact)
LIFT_DEEPEN_TOL = 0.00025
# m: how much of a neighbour's clearance at the grasp a lift may use up (see Planner._plan_pick_with: the lift keeps
# the clearance the held item has from a neighbour at the grasp, up to the collision margin)
LIFT_CLEARANCE_TOL = 0.001
# m: an up-then-away lift (Planner._up_then_away): straight up this far (the start contacts' travel), then away, its
# start contacts allowed for this much more of the second leg
UP_THEN_AWAY = (LIFT_CONTACT_TRAVEL, 0.01)
PLACED_ID = 1_000_000  # instance id of the just-released object in the retreat scene
# Gaps (m, per pad) the pads open to past the held item's width at release when the grasp's full opening would put
# a pad into a neighbour at the target (a bowl set on its rim beside a plate in a rack: its rim pinch opens 3.5 cm,
# 1.5 cm past the rim on each side; the plate stands a few mm from the closed pad). Any opening wider than the item
# lets it go (a 2 mm gap: as far as the pads' grasp margin).
RELEASE_GAPS = (0.008, 0.005, 0.002)


def release_openings(opening: float, width: float) -> list[float]:
    """Gripper openings to release an item held at `width` with, widest first: the grasp's own `opening`, then
    the item's width plus each of RELEASE_GAPS per pad where that is narrower (a tighter spot at the target)."""
    out = [float(opening)]
    for gap in RELEASE_GAPS:
        o = float(width) + 2.0 * gap
        if o < out[-1] - 1e-3:
            out.append(o)
    return out


class Planner:
    """Plans pick, place and free motions for one cell (robot + tool + fixed geometry + inventory)."""

    def __init__(
        self,
        robot: RobotModel,
        cell: Cell,
        inventory: Inventory,
        settings: PlanningSettings | None = None,
        T_flange_cam: np.ndarray | None = None,
    ):
        self.robot = robot
        self.cell = cell
        self.settings = settings or PlanningSettings()
        # models that come without grasps get synthesised ones
        self.inventory = ensure_grasps(inventory, self.settings.grasp_cache_dir)
        s = self.settings
        self.world = CollisionWorld(
            robot, cell, T_flange_cam, margin=s.collision_margin, grasp_margin=s.grasp_margin, voxel_size=s.map_voxel_size
        )
        self._placeable: dict = {}  # (obj_id, grasp name, targets) -> a release pose exists
        self._fits: dict = {}  # grasp candidates' checks, kept with what they depend on (grasps.select_grasps' memo)
        self._place_reach = PlaceReach(robot, self.world)  # release-pose geometry, kept across queries
        self._turns_cache: dict = {}  # (obj_id, target pose, ...) -> the turns _place_turns allows
        self._voxel_cache: dict = {}
        # where the arm comes back to between items (the executive sets it: the last scan waypoint), or None: a
        # grasp's joints are then turned for the way out and back (RobotModel.wrap_round_trip), not only out
        self.q_rest: np.ndarray | None = None
        # OMPL's check step must stay below twice the margin (see planning.motion); never above it.
        self.planning_resolution = min(s.planning_resolution, max(2 * s.collision_margin - 0.002, s.validity_resolution))

    @property
    def limits(self) -> SafetyLimits:
        return self.robot.limits

    @classmethod
    def from_config(cls, cfg, inventory: Inventory | None = None) -> "Planner":
        """Build from an executive CellConfig (duck-typed: robot.model, safety_limits(), planning, cell,
        calibration); `inventory` defaults to the builtin one."""
        limits = cfg.safety_limits()
        robot = RobotModel(ur_model(cfg.robot.model), limits.T_flange_tcp, limits)
        T_fc = cfg.T_flange_cam() if callable(getattr(cfg, "T_flange_cam", None)) else cfg.calibration.T_flange_cam.matrix()
        return cls(robot, Cell(cfg.cell), inventory or Inventory.builtin(), cfg.planning, T_fc)

    # ---- scene assembly ----------------------------------------------------------------------------------------
    def _scene_objects(self, objects: Sequence[ObjectPose], exclude: ObjectPose | None = None) -> list[SceneObject]:
        out = []
        for k, o in enumerate(objects):
            if exclude is not None and (o is exclude or (exclude.instance_id >= 0 and o.instance_id == exclude.instance_id)):
                continue
            if o.obj_id not in self.inventory.models:
                continue
            out.append(SceneObject(object_name(o, k), self.inventory[o.obj_id], np.asarray(o.T_base_obj, float)))
        return out

    def scene(
        self,
        objects: Sequence[ObjectPose] = (),
        map_points: np.ndarray | None = None,
        *,
        exclude: ObjectPose | None = None,
        held: Grasp | None = None,
        opening: float | None = None,
        own: Sequence[ObjectPose] | None = None,
    ) -> Scene:
        """The collision scene of one query (perceived objects minus `exclude`, unexplained map points, held).

        Map points are explained by every perceived object (the excluded and the held one included: their
        points were mapped where they were before the pick). `own`: the only objects whose observed points
        explain themselves where their fitted model does not cover them (the grasp target, the held item;
        None: every object, see CollisionWorld.explained); a neighbour's points off its model stay obstacles."""
        explainers = list(objects)
        for o in (exclude, held.obj if held is not None else None):  # each once: the held item is often `exclude`
            if o is not None and not any(o is x for x in explainers):
                explainers.append(o)
        known = [o for o in explainers if o.obj_id in self.inventory.models]
        voxels = self._voxels(map_points, known, own)
        objs = self._scene_objects(objects, exclude=exclude)
        h = None
        if held is not None:
            h = Held(self.inventory[held.obj.obj_id], held.T_tcp_obj, held.spec.width)
        kw = {} if opening is None else {"opening": opening}
        return self.world.scene(objs, voxels, h, **kw)

    def unexplained(self, points: np.ndarray | None, objects: Sequence[ObjectPose] = ()) -> np.ndarray:
        """Centres of the voxels of `points` (base frame: a view's, not the fused map) that neither the cell nor
        one of `objects` explains: where something unknown stands, as the map's unexplained points become
        obstacles (CollisionWorld.unexplained_voxels)."""
        return self.world.unexplained_voxels(points, self._scene_objects(objects))

    def without_points_of(self, map_points: np.ndarray | None, obj: ObjectPose) -> np.ndarray | None:
        """`map_points` less those that `obj` explains where it was perceived: after it has been taken away they
        are a record of where it was, and with nothing there any more to explain them they would be planned
        around as unknown obstacles (a phantom pile where the picked item stood)."""
        if map_points is None or len(map_points) == 0 or obj.obj_id not in self.inventory.models:
            return map_points
        if marks_of(map_points):
            raise ValueError("without_points_of: expected the perceived map points, got map points with marks")
        P = np.asarray(map_points, float).reshape(-1, 3)
        gone = self.world.explained(P, self._scene_objects([obj]), instance_points=[obj.points])
        return P[~gone]

    def _voxels(self, map_points: np.ndarray | None, known: list[ObjectPose],
                own: Sequence[ObjectPose] | None = None) -> np.ndarray:
        """Unexplained map points as voxel centres; cached, since one pick or place asks several times for the
        same map and objects (tens of ms for a fused map of ~50k points)."""
        if map_points is None or len(map_points) == 0:
            return np.zeros((0, 3))
        marks = marks_of(map_points)  # the last rows: contact marks, keep-outs; nothing explains them away
        P = np.asarray(map_points)
        known = [o for o in known if o.obj_id in self.inventory.models]  # as _scene_objects keeps them
        mine = None if own is None else [any(o is x for x in own) for o in known]
        key = (id(map_points), P.shape, float(P.reshape(-1)[:: max(1, P.size // 97)].sum()),
               tuple(sorted((o.obj_id, o.instance_id, np.asarray(o.T_base_obj, float).tobytes()) for o in known)),
               None if mine is None else tuple(sorted(o.instance_id for o, m in zip(known, mine) if m)), marks)
        hit = self._voxel_cache.get(key)
        if hit is None:
            n = len(P) - marks
            hit = self.world.unexplained_voxels(P[:n], self._scene_objects(known), instance_points=[o.points for o in known],
                                                self_explaining=mine)
            if marks:
                hit = np.unique(np.vstack([hit, self.world.occupied_voxels(P[n:])]).round(9), axis=0)
            if len(self._voxel_cache) > 8:
                self._voxel_cache.clear()
            self._voxel_cache[key] = hit
        return hit

    # ---- helpers -------------------------------------------------------------------------------------------------
    def _check_q(self, q, name: str) -> np.ndarray | InvalidInput:
        q = np.asarray(q, float)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            return InvalidInput(f"{name}: expected 6 finite joint values, got shape {q.shape}")
        return q

    # motions that end in or make contact: timed slower (PlanningSettings.contact_speed_scale)
    CONTACT_MOTIONS = frozenset({"grasp_in", "lower", "press", "slide", "escape"})

    def _time(self, Q: np.ndarray, name: str, mode: str, free=None) -> Trajectory | PlanningFailure:
        s = self.settings
        c = s.contact_speed_scale if name in self.CONTACT_MOTIONS else 1.0
        try:
            return time_parameterise(
                Q, self.limits, self.robot.ur, velocity_scale=s.velocity_scale * c,
                acceleration_scale=s.acceleration_scale * c, mode=mode, name=name, free=free,
            )
        except LimitViolation as e:
            return CartesianPathFailed(f"{name}: {e}")

    def _joint_motion(self, scene: Scene, q0, q1, name: str, timings: dict,
                      timeout_scale: float = 1.0) -> Trajectory | PlanningFailure:
        s = self.settings
        t0 = time.perf_counter()
        # a work budget (max_iterations) grows with the time budget: a repeatable search given the same budget
        # again fails the same way
        iterations = None if s.planner_max_iterations is None else max(1, round(s.planner_max_iterations * timeout_scale))
        res = plan_joint_path(
            scene, q0, q1, timeout=s.planner_timeout * timeout_scale, simplify_timeout=s.simplify_timeout,
            planning_resolution=self.planning_resolution, validity_resolution=s.validity_resolution,
            max_iterations=iterations, seed=s.planner_seed, shortcut_rounds=s.shortcut_rounds,
            joint_speeds=np.asarray(self.limits.max_joint_speed, float) * s.velocity_scale,
            tcp_speed=self.limits.max_tcp_speed,
        )
        timings[f"{name}_plan_ms"] = (time.perf_counter() - t0) * 1e3
        if isinstance(res, PlanningFailure):
            res.details.setdefault("segment", name)
            return res
        timings[f"{name}_search_ms"] = res.plan_ms
        timings[f"{name}_simplify_ms"] = res.simplify_ms
        timings[f"{name}_recheck_ms"] = res.recheck_ms
        timings[f"{name}_rrt"] = float(res.used_rrt)
        timings[f"{name}_shortcut_ms"] = res.shortcut_ms
        # The RRT path and its shortcut (planning/shortcut.py; both densely checked): each timed, the faster kept
        # (the shortcut is chosen on an estimate of the arm's time; the timing below is the arm's time itself).
        t1 = time.perf_counter()
        best: Trajectory | PlanningFailure | None = None
        for k, path in enumerate([res.path] + ([res.shortcut] if res.shortcut is not None else [])):
            traj, blended = self._timed_path(scene, path, name)
            if best is None or (not isinstance(traj, PlanningFailure)
                                and (isinstance(best, PlanningFailure) or traj.duration < best.duration)):
                best = traj
                timings[f"{name}_shortcut"] = float(k)
                timings[f"{name}_blended"] = float(blended)
        timings[f"{name}_blend_ms"] = (time.perf_counter() - t1) * 1e3
        return best

    def _timed_path(self, scene: Scene, path: np.ndarray, name: str) -> tuple[Trajectory | PlanningFailure, bool]:
        """A checked joint polyline timed: through its vertices without stopping where the blended path is proven
        free at the planner's dense re-check resolution (planning/timing.py); else it stops at each vertex, on the
        checked polyline. With whether the blend was proven free."""
        if len(path) < 3:
            return self._time(path, name, "stop_at_vertices"), False
        r = reach_bounds(scene)
        proof: dict = {}

        def free(q: np.ndarray) -> bool:
            proof["free"] = segment_free(scene, q, r, self.settings.validity_resolution)
            return proof["free"]

        traj = self._time(path, name, "blended", free=free)
        return traj, bool(proof.get("free", False))

    def _line(self, scene: Scene, q0, T_goal, name: str, *, check_start: bool = True, start_scene: Scene | None = None,
              start_travel: float = 0.0, clear_within: float = 0.0, clear_scene: Scene | None = None,
              info: dict | None = None) -> tuple[Trajectory, np.ndarray] | PlanningFailure:
        Q = cartesian_line(self.robot, scene, q0, T_goal, step=self.settings.validity_resolution,
                           check_step=self.settings.validity_resolution, check_start=check_start,
                           start_scene=start_scene, start_travel=start_travel, clear_within=clear_within,
                           clear_scene=clear_scene, info=info)
        if isinstance(Q, PlanningFailure):
            Q.message = f"{name}: {Q.message}"
            Q.details.setdefault("segment", name)
            return Q
        if info is not None:
            info["path"] = Q
        traj = self._time(Q, name, "along_path")
        if isinstance(traj, PlanningFailure):
            return traj
        return traj, Q[-1]

    # ---- grasps -------------------------------------------------------------------------------------------------
    def select_grasps(
        self,
        q_current: np.ndarray,
        objects: Sequence[ObjectPose],
        *,
        target: ObjectPose | None = None,
        map_points: np.ndarray | None = None,
        place_target: PlaceTarget | Sequence[PlaceTarget] | None = None,
        stats: GraspStats | None = None,
        limit: int | None = None,
        scene: Scene | None = None,
        avoid_grasps: Sequence[str] = (),
    ) -> list[Grasp] | PlanningFailure:
        """Ranked feasible grasps (best first) over `objects` (or only `target`); `limit`: stop checking once
        that many are feasible; `avoid_grasps`: grasp names not to use, with their tilted variants (planning.grasps.select_grasps)."""
        q = self._check_q(q_current, "q_current")
        if isinstance(q, PlanningFailure):
            return q
        if scene is None:
            scene = self.scene(objects, map_points, own=None if target is None else [target])
        flt = None
        if place_target is not None:
            targets = [place_target] if isinstance(place_target, PlaceTarget) else list(place_target)
            bad = [type(t).__name__ for t in targets if not isinstance(t, PlaceTarget)]
            if bad:
                return InvalidInput(f"place_target: expected a PlaceTarget or a sequence of them, got items of type {bad[:3]}")
            targets = targets[: self.settings.max_place_targets]

            known = [o for o in objects if o.obj_id in self.inventory.models]
            voxels = self._voxels(map_points, known)
            # the release pose is checked as plan_place will: gripper and held object (grasp margins) against
            # the cell, the other objects (e.g. what is already in the rack) and the map
            world_key = tuple(sorted((o.obj_id, np.round(np.asarray(o.T_base_obj, float), 4).tobytes()) for o in known))

            def flt(obj, spec, T_base_tcp):
                # a target's turns (free_yaw, flip_ok) and release height are part of the question, not only its pose
                key = (obj.obj_id, spec.name, tuple((t.T_base_obj.tobytes(), bool(t.free_yaw), t.flip_ok, t.kind,
                                                     float(t.clearance), t.approach_distance) for t in targets),
                       world_key, voxels.tobytes())
                if key not in self._placeable:
                    held = Held(self.inventory[obj.obj_id], inv(spec.T_obj_tcp), spec.width)

                    def build(obj=obj, held=held):
                        pre = self.world.scene(self._scene_objects(objects, exclude=obj), voxels, held)  # full margins above the release (plan_place)
                        return pre.for_release(None), pre  # the release: a variant of it, the grasp margins
                    scenes = OnDemand(held, held.width, build)  # most queries never need them (planning/place_reach.py)
                    ok = any(
                        self._place_tcp_options(t, spec.T_obj_tcp, q, scenes, first_only=True, obj_id=obj.obj_id)
                        for t in targets
                    )
                    if len(self._placeable) >= 5000:  # bounded: emptied before this answer is kept, not after
                        self._placeable.clear()
                    self._placeable[key] = ok
                return self._placeable[key]

            def approachable(obj, T_obj_tcps: np.ndarray) -> np.ndarray:
                """Per grasp (object frame, (N, 4, 4)), whether it could pass flt: some turn of some target puts
                its approach no more upwards than max_approach_up. The first cut of the release poses
                (PlaceReach.options keeps only such turns), without IK: False means flt refuses it."""
                Z = np.asarray(T_obj_tcps, float).reshape(-1, 4, 4)[:, :3, 2].T  # approach axes, (3, N)
                ok = np.zeros(Z.shape[1], bool)
                for t in targets:
                    T_obj = np.asarray(t.T_base_obj, float)
                    rows = np.array([(T_obj @ Rt)[2, :3] for Rt in self._place_turns(t, obj.obj_id)])
                    ok |= np.any(rows @ Z <= self.settings.max_approach_up, axis=0)
                return ok

            flt.approachable = approachable

        return select_grasps(self.robot, scene, self.inventory, objects, q, settings=self.settings,
                             target=target, grasp_filter=flt, stats=stats, limit=limit, avoid=avoid_grasps,
                             q_rest=self.q_rest, memo=self._fits)

    # ---- pick ------------------------------------------------------------------------------------------------------
    def plan_pick(
        self,
        q_start: np.ndarray,
        objects: Sequence[ObjectPose],
        *,
        target: ObjectPose | None = None,
        map_points: np.ndarray | None = None,
        place_target: PlaceTarget | Sequence[PlaceTarget] | None = None,
        avoid_grasps: Sequence[str] = (),
        stopped_lifts: Sequence[np.ndarray] = (),
    ) -> PickPlan | PlanningFailure:
        """Pick the best graspable object in `objects` (or `target`): approach, straight grasp-in, lift.

        `objects`: every perceived object (all are obstacles, candidates unless `target` is given);
        `map_points`: (N, 3) fused map points in the base frame; those no object or cell surface explains become
        voxel obstacles; `place_target`: when given, only grasps that can also reach that placement (one of
        them, for a list) are kept (e.g. cups to be inverted into the upper rack need side grasps);
        `avoid_grasps`: grasp names not to use, with their tilted variants (those that closed on nothing on this item
        before, or whose place did not plan);
        `stopped_lifts`: directions (unit, base frame) in which a lift of `target` was cut short by a protective stop
        (the item let go where it was taken): no lift of it starts within planning.lift.STOPPED_LIFT_ANGLE of one
        (planning.lift.lift_fallbacks; the two-leg lifts' first legs likewise).
        """
        q0 = self._check_q(q_start, "q_start")
        if isinstance(q0, PlanningFailure):
            return q0
        timings: dict = {}
        t0 = time.perf_counter()
        base_scene = self.scene(objects, map_points, own=None if target is None else [target])
        grasps = self.select_grasps(q0, objects, target=target, map_points=map_points, place_target=place_target,
                                    limit=self.settings.max_grasp_candidates, scene=base_scene,
                                    avoid_grasps=avoid_grasps)
        timings["grasp_selection_ms"] = (time.perf_counter() - t0) * 1e3
        if isinstance(grasps, PlanningFailure):
            if target is not None and grasps.kind in ("no_graspable_object", "no_collision_free_grasp"):
                # hidden under, or crowded by, what rests on it: those items are the ones to pick first; with
                # nothing on it, the neighbours its grasps collided with, most often first (taking one of them
                # out first frees it)
                blockers = self._resting_on(target, objects)
                crowded_by = grasps.details.get("crowded_by") or {}
                if not blockers and grasps.kind == "no_collision_free_grasp":
                    self._report_voxels(grasps, crowded_by)
                    blockers = self._crowding(target, objects, crowded_by)
                self._report_blocking(grasps, target, objects, blockers)
            return grasps
        last: PlanningFailure | None = None
        tried = 0
        hit: dict[str, int] = {}  # object name -> lift failures it took part in
        why: list[str] = []  # per candidate tried: "grasp: kind: segment: what failed" (the failure's details["candidates"])
        for g in grasps[: self.settings.max_grasp_candidates]:
            tried += 1
            res = self._plan_pick_with(q0, g, objects, map_points, base_scene, timings,
                                       stopped=tuple(np.asarray(d, float) for d in stopped_lifts))
            if not isinstance(res, PlanningFailure):
                res.candidates_tried = tried
                timings["total_ms"] = (time.perf_counter() - t0) * 1e3
                return res
            for n in res.details.pop("lift_objects", ()):
                hit[n] = hit.get(n, 0) + 1
            why.append(f"{g.spec.name}: {res.kind}: {res.message}")
            last = res
            if res.details.pop("held_blocked", False):
                break  # the held item itself cannot be lifted out in any direction: no other grasp changes that
        assert last is not None
        # ``pinned``: at its grasp the item is within the margin of what lies on it (_pinned_by): every grasp fails
        # so while it and those items lie as they do (the executive does not plan it again until then)
        last.details["candidates_tried"] = tried
        last.details["candidates"] = why
        if hit and target is not None:
            names = {object_name(o, k): o for k, o in enumerate(objects)}
            hit_objs = [names[n] for n in sorted(hit, key=lambda n: -hit[n]) if n in names]
            self._report_blocking(last, target, objects, [o for o in hit_objs if self._lies_on(o, target)])
        return last

    # ---- what blocks a pick ------------------------------------------------------------------------------------
    @staticmethod
    def _report_blocking(failure: PlanningFailure, target: ObjectPose, objects, blockers: list[ObjectPose]) -> None:
        """details["blocking"]: instance id of the item to pick before `target` (it lies on it, or in the way
        of its lift), -1 when that item has no instance id; details["blocking_all"]: every such item, most
        in the way first, as (instance id, class)."""
        if not blockers:
            return
        ids = [int(o.instance_id) for o in blockers]
        failure.details["blocking"] = ids[0]
        failure.details["blocking_all"] = [(i, o.cls) for i, o in zip(ids, blockers)]
        named = f"the {blockers[0].cls}" + (f" {ids[0]}" if ids[0] >= 0 else "")
        # where map points no item explains met the grasps more often (_report_voxels), the item is named second
        failure.message += f" (fewer met {named})" if "blocked_by_voxels" in failure.details else f" (blocked by {named})"

    @staticmethod
    def _report_voxels(failure: PlanningFailure, crowded_by: dict) -> None:
        """Where the map's voxels (map points no perceived object explains: contact marks, an unseen item's points)
        crowd the rejected grasps at least as often as any perceived neighbour, the failure says so first
        (details["blocked_by_voxels"]: how many rejected grasps collided with them): a neighbour a few of them also
        touched is not what blocks the item."""
        n = int(crowded_by.get(VOXELS, 0))
        if n and n >= max((c for k, c in crowded_by.items() if k != VOXELS), default=0):
            failure.details["blocked_by_voxels"] = n
            failure.message += f" (blocked by map points no perceived item explains: {n} rejected grasps met them)"

    @staticmethod
    def _crowding(target: ObjectPose, objects, crowded_by: dict) -> list[ObjectPose]:
        """The perceived objects (not `target`) named in a grasp failure's ``crowded_by``, most often first."""
        names = {object_name(o, k): o for k, o in enumerate(objects)}
        out = [names[n] for n in sorted(crowded_by, key=lambda n: -crowded_by[n]) if n in names]
        return [o for o in out if o is not target and not (target.instance_id >= 0 and o.instance_id == target.instance_id)]

    def _vertical_clear_travel(self, a: ObjectPose, b: ObjectPose, height: float = 0.12, step: float = 0.005) -> float:
        """Metres `a` must be translated straight up to be clear of `b` for good (`height` + step if it never
        is within `height`); 0 when they do not touch (perceived poses, no margin): planning.resting.clear_travel."""
        ma, mb = self.inventory.models.get(a.obj_id), self.inventory.models.get(b.obj_id)
        if ma is None or mb is None:
            return 0.0
        return clear_travel(self.world.bvh(ma), a.T_base_obj, self.world.bvh(mb), b.T_base_obj, height, step)

    def _lies_on(self, other: ObjectPose, target: ObjectPose) -> bool:
        """Whether `other` lies on (or over) `target` rather than under it: lifting `target` straight up runs
        into `other` for longer than lifting `other` runs into `target` (a glass leaning into a cup lies on the
        cup; the cup does not lie on the glass, although each one's lift first touches the other)."""
        mo, mt = self.inventory.models.get(other.obj_id), self.inventory.models.get(target.obj_id)
        return mo is not None and mt is not None and lies_on(self.world.bvh(mo), other.T_base_obj,
                                                             self.world.bvh(mt), target.T_base_obj)

    def items_on(self, target: ObjectPose, objects: Sequence[ObjectPose]) -> list[ObjectPose]:
        """The perceived items lying on (or over) `target`, most in the way first: pick those before it (what
        a pick failure names in ``details["blocking"]``; cheap: a few ms per neighbour, no IK)."""
        return self._resting_on(target, objects)

    def _resting_on(self, target: ObjectPose, objects, reach: float = 0.01) -> list[ObjectPose]:
        """Perceived items that lie on `target` (see _lies_on), within `reach` of it, most overlapping first."""
        if target.obj_id not in self.inventory.models:
            return []
        mt = self.inventory[target.obj_id]
        pt = np.asarray(target.T_base_obj, float)[:3, 3]
        out = []
        for o in objects:
            if o is target or (target.instance_id >= 0 and o.instance_id == target.instance_id):
                continue
            m = self.inventory.models.get(o.obj_id)
            if m is None or np.linalg.norm(np.asarray(o.T_base_obj, float)[:3, 3] - pt) > (m.diameter + mt.diameter) / 2 + reach:
                continue
            lift = self._vertical_clear_travel(target, o)
            if lift > 0 and lift > self._vertical_clear_travel(o, target):
                out.append((lift, o))
        return [o for _, o in sorted(out, key=lambda x: -x[0])]

    def _plan_pick_with(self, q0, g: Grasp, objects, map_points, base_scene: Scene, timings: dict,
                        keep_wall_gaps: bool = False, stopped: tuple = ()) -> PickPlan | PlanningFailure:
        """Grasp-in and lift of grasp `g`, then the approach. `keep_wall_gaps`: the basin walls the held item is
        within the grasp margin of, but clear of, at the grasp keep that gap for the whole lift (_wall_gaps): the
        last resort, tried when every lift with the walls checked as before failed. `stopped`: directions of lifts
        of this item a protective stop cut short, not planned again (plan_pick's `stopped_lifts`)."""
        s = self.settings
        name = None
        for k, o in enumerate(objects):
            if o is g.obj:
                name = object_name(o, k)
        # The straight segments (grasp-in, lift) do not depend on the approach: plan them first, so a grasp
        # whose lift is blocked costs no RRT-Connect query.
        base_scene.set_opening(g.spec.opening)
        grasp_scene = base_scene.for_grasp(name)
        if g.pad_contacts:  # the pads may brush a neighbour within their give (planning/pad_give.py)
            grasp_scene = grasp_scene.allowing_keep_zone(g.pad_contacts)
        r = self._line(grasp_scene, g.q_pregrasp, g.T_base_tcp, "grasp_in")
        if isinstance(r, PlanningFailure):
            return r
        grasp_in, q_grasp = r
        g.q = q_grasp
        # Lift: the held object leaves the contacts it rests in (sink floor, a stack) during the first
        # LIFT_CONTACT_TRAVEL metres (those pairs only are not checked there); above that, everything is.
        held_scene = self.scene(objects, map_points, exclude=g.obj, held=g, own=[g.obj])
        lift_scene = held_scene.for_release(None)
        # contacts the held object has where it rests (its support, a stack) may last for the first few
        # centimetres; anything else it would touch is checked from the start
        at_grasp = lift_scene.colliding_pairs(q_grasp)
        # The release margins (the grasp margin, 2 mm) are for what the held item rests against where it is taken:
        # a neighbour it stands clear of there keeps, for the whole lift, the clearance it has at the grasp, up to
        # the full collision margin; the lift may pass it as close as it already is, not closer. Its pose is an
        # estimate (an item 11 % visible, 5 mm off): a lift tilted towards it, checked with 2 mm, drove the held
        # item into it.
        near = {frozenset(p) for p in at_grasp}
        clear = {}
        for p in lift_scene.pair_names:
            if "held" in p and any(x.startswith("obj:") or x == "voxels" for x in p) and frozenset(p) not in near:
                d = lift_scene.clearance(q_grasp, p, s.collision_margin)
                if d > s.grasp_margin + LIFT_CLEARANCE_TOL:
                    clear[p] = d - LIFT_CLEARANCE_TOL
        if clear:
            lift_scene = lift_scene.with_pair_margins(clear)
        # A basin wall the held item is within the grasp margin of, but clear of, at the grasp: on the last resort
        # (keep_wall_gaps) the lift keeps the gap it has there, for the whole lift (not closer); see _wall_gaps.
        walls = self._wall_gaps(lift_scene, q_grasp, at_grasp)
        if keep_wall_gaps:
            lift_scene = lift_scene.with_pair_margins(walls)
            at_grasp = [p for p in at_grasp if p not in walls]
        # ... but not with an item lying on it (leaning on its rim): lifted, the item drags that one along, and
        # where the estimated poses are a millimetre off they are apart at the start in the world and meet on
        # the way up (a plate lifted along a glass leaning on it, with perceived poses: a protective stop)
        by_name = {f"obj:{object_name(o, j)}": o for j, o in enumerate(objects)}
        on_it = {x for p in at_grasp if "held" in p for x in p if x in by_name and self._lies_on(by_name[x], g.obj)}
        start_contacts = [p for p in at_grasp if "held" in p and not on_it.intersection(p)]
        # ... and a neighbour it does not rest on (one beside it, or interlocked with it: a plate's rim in a lying
        # glass's mouth) may keep its overlap but not get deeper: where the estimated poses overlap, the real
        # items may be a fraction of a millimetre apart, and a lift that drives one into the other makes a
        # contact (a protective stop) that the overlap at the start hid. Supports (what it lies on) are left
        # by a lift straight up or along the item's own axis and stay unchecked for its first centimetres.
        side = {p: lift_scene.penetration(q_grasp, p) for p in start_contacts
                if any(x in by_name for x in p) and not any(x in by_name and self._lies_on(g.obj, by_name[x]) for x in p)}
        deeper = {p: -(d + LIFT_DEEPEN_TOL) for p, d in side.items()}
        # Any other lift (tilted away from what it ran into, a sidestep) may slide the item along a tilted support
        # instead of leaving it: there a support too may keep its overlap but not get deeper. Unchecked, a lift
        # tilted 45 degrees drove a mug lying on a tilted plate along the plate into it (model overlap 1.5 -> 3.1 mm).
        supports = {p: lift_scene.penetration(q_grasp, p) for p in start_contacts
                    if p not in side and any(x in by_name for x in p)}
        tilted_deeper = {**deeper, **{p: -(d + LIFT_DEEPEN_TOL) for p, d in supports.items()}}
        # A basin wall the held item is clear of at the grasp (by WALL_GAP_MIN or more: not leaning on it) is no
        # contact to leave: in the first LIFT_CONTACT_TRAVEL the lift may not close that gap (_wall_gaps' margin)
        # either. Unchecked there, a lift tilted a little towards the wall drove a plate standing 1 mm off it into it.
        deeper.update({p: m for p, m in walls.items() if p in start_contacts})
        tilted_deeper.update({p: m for p, m in walls.items() if p in start_contacts})
        free_start = [p for p in start_contacts if p not in side and p not in walls]
        start_scene = lift_scene.allowing([p for p in free_start if p not in supports]).with_pair_margins(tilted_deeper)
        # The fingers too start within the transport margin of what lies next to or under the item (the plate
        # below in a stack): grasp_in checked them with the grasp margin. Lifting straight up (or along the
        # item's own axis) moves them away, so those pairs are not checked for the first few centimetres.
        tool_contacts = [p for p in at_grasp if p not in start_contacts and any(x in TOOL_PARTS for x in p)]
        vertical_start_scene = lift_scene.allowing(free_start + tool_contacts).with_pair_margins(deeper)
        # Beyond LIFT_CONTACT_TRAVEL only the held object's contacts with other items may last (until they clear,
        # see LIFT_CLEAR_TRAVEL), and only on a lift straight up or along the item's axis: an item sliding up
        # along a basin wall or dragging a finger is not lifted out, nor one pulled sideways through a neighbour
        # whose estimated pose it overlaps (in the world it may be inside that neighbour, not beside it).
        # Only contacts with what the item itself lies on (its supports: lifting it moves away from them).
        item_contacts = [p for p in start_contacts
                         if any(x in by_name and self._lies_on(g.obj, by_name[x]) for x in p)]
        clear_scene = lift_scene.allowing(item_contacts) if item_contacts else None
        # Every lift may leave those start contacts with other items, none may meet one again once left (see
        # _contact_comes_back): the margins above see one unbroken contact where the items part and meet again.
        held_item_pairs = [p for p in start_contacts if any(x in by_name for x in p)]
        # ... allowing, for a support whose fitted pose is doubtful (planning/doubtful_support.py), for that pose's
        # error: a gap to it that narrows again after parting, within that error, may be the contact coming back
        doubtful = {x for p in held_item_pairs for x in p
                    if x in by_name and pose_doubtful(by_name[x], s.visible_fraction_unoccluded)}
        # An item lying on the held one is checked from the lift's first state (above): where the held item is
        # already within the margin of it at the grasp, every lift (each direction, each sidestep) fails at that
        # first state, and so does every other grasp of the item (the held item's pose is the same). Said once.
        pinned = self._pinned_by(vertical_start_scene, start_scene, q_grasp, on_it)
        if pinned is not None:
            return pinned

        def with_approach(lift: Trajectory, contact_travel: float, **marks: float) -> PickPlan | PlanningFailure:
            """The plan with this lift, its approach planned last (RRT-Connect only for a grasp that lifts out);
            `marks` go into the timings (which fallback lifted it)."""
            base_scene.set_opening(g.spec.opening)
            approach = self._joint_motion(base_scene, q0, g.q_pregrasp, "approach", timings)
            if isinstance(approach, PlanningFailure):
                return approach
            timings.update(marks)
            return PickPlan(g, approach, grasp_in, lift, timings_ms=timings, lift_contact_travel=contact_travel)

        # Straight up first; an item resting tilted in a stack comes off along its own axis (as it was
        # stacked); an item leaning on a basin wall (or in a corner) would slide up along it, so then up and
        # away from the walls (towards the sink's middle), tilted by 30 / 50 degrees.
        first: PlanningFailure | None = None
        lift_objects: set[str] = set()  # perceived objects the failed lifts ran into (reported as blockers)
        lift_unknown: set = set()  # map voxels (no perceived object) the failed lifts ran into: tilted away from too
        # whether every direction failed because the held item itself runs into something (then every grasp of
        # it fails the same way: the directions depend on the item only, not on the grasp)
        held_only = True
        near_wall = self._near_sink_wall(g.obj)
        centre = np.asarray(g.obj.T_base_obj, float)[:3, 3]
        separated = False  # whether the lift that first parts the held item from what it touches was tried
        remade: list = []  # (lift, end) of up-then-away lifts refused only because a contact may be made within the fits
        # the first lift refused only because its start contact may break within the fits' resolution (lift, end,
        # info): used when nothing else plans (before that rule, it was planned)
        fallback = None
        for d, along in lift_fallbacks(self.cell.sink_interior, g.obj.T_base_obj, objects, lift_objects,
                                       near_wall=near_wall, ran_into_unknown=lift_unknown, stopped=stopped):
            T_lift = trans(*(s.lift_height * d)) @ g.T_base_tcp
            info: dict = {}
            r = self._line(lift_scene, q_grasp, T_lift, "lift", check_start=False,
                           start_scene=vertical_start_scene if along else start_scene,
                           start_travel=LIFT_CONTACT_TRAVEL,
                           clear_within=LIFT_CLEAR_TRAVEL if along and clear_scene is not None else 0.0,
                           clear_scene=clear_scene, info=info)
            if isinstance(r, PlanningFailure):
                pairs = r.details.get("pairs", ())
                held_only &= bool(pairs) and all("held" in p for p in pairs)
                first = first or r
                lift_objects.update(n[4:] for p in pairs for n in p if n.startswith("obj:"))
                lift_unknown.update(self._voxels_hit(lift_scene, r, g))
            else:
                lift, q_lifted = r
                back = self._contact_comes_back(lift_scene, lift.q, held_item_pairs)
                maybe = None if back is not None else self._remade_in_fit(lift_scene, lift.q, held_item_pairs,
                                                                          doubtful)
                if back is not None or maybe is not None:
                    if back is not None:
                        lift_objects.update(n[4:] for n in back if n.startswith("obj:"))
                        first = first or CartesianPathFailed(
                            "lift: the held item leaves a neighbour it started against and meets it again",
                            {"pairs": [back], "segment": "lift"})
                    elif fallback is None:  # kept, the last resort: it planned as before (see _remade_in_fit)
                        fallback = (lift, q_lifted, info)
                    if not separated:  # once: first along the direction that parts it from those it touches
                        separated = True
                        r = self._separating_lift(lift_scene, start_scene, held_scene, q_grasp, g, held_item_pairs,
                                                  by_name, stopped)
                        if r is not None:
                            return with_approach(r[0], LIFT_CONTACT_TRAVEL,
                                                 lift_separate_m=float(np.linalg.norm(r[2])))
                    continue
                if not held_scene.valid(q_lifted):
                    # An item that rested against a basin wall is lifted along it with the grasp margin (2 mm)
                    # and ends within the transport margin of it: move it on, away from the walls
                    ext = self._lift_clear_of_walls(lift_scene, held_scene, q_lifted, info["path"], centre)
                    if ext is not None:
                        lift, q_lifted = ext
                if held_scene.valid(q_lifted):  # plan_place starts here with the full margins
                    return with_approach(lift, float(info.get("contact_travel", LIFT_CONTACT_TRAVEL)))
                pairs = held_scene.colliding_pairs(q_lifted)
                held_only &= bool(pairs) and all("held" in p for p in pairs)
                first = first or CartesianPathFailed("lift: the lifted pose is within the collision margin",
                                                     {"pairs": pairs, "segment": "lift"})
        # Every line ran into perceived items or unexplained voxels (one overhanging it): out from under them nearly
        # level, then up.
        for leg in (sidesteps(centre, objects, lift_objects, unknown=sorted(lift_unknown))
                    if lift_objects or lift_unknown else []):
            r = self._two_leg_lift(lift_scene, start_scene, q_grasp, g.T_base_tcp, leg, stopped)
            if isinstance(r, PlanningFailure):
                pairs = r.details.get("pairs", ())
                held_only &= bool(pairs) and all("held" in p for p in pairs)
                continue
            lift, q_lifted = r
            if self._contact_comes_back(lift_scene, lift.q, held_item_pairs) is not None or \
                    self._may_meet_doubtful_again(lift_scene, lift.q, held_item_pairs, doubtful) is not None:
                continue
            if held_scene.valid(q_lifted):
                return with_approach(lift, LIFT_CONTACT_TRAVEL, lift_sidestep_m=float(np.linalg.norm(leg[:2])))
        if fallback is not None:
            lift, q_lifted, info = fallback
            if not held_scene.valid(q_lifted):
                ext = self._lift_clear_of_walls(lift_scene, held_scene, q_lifted, info["path"], centre)
                if ext is not None:
                    lift, q_lifted = ext
            if held_scene.valid(q_lifted):
                return with_approach(lift, float(info.get("contact_travel", LIFT_CONTACT_TRAVEL)),
                                     lift_fit_fallback=1.0)
        # Every line and sidestep failed, and the held item touches a basin wall at the grasp: up along the wall
        # first (within the start contacts' travel), then away from it (_up_then_away)
        touching = [p for p in start_contacts if any(x.startswith("cell:") for x in p)]
        if touching and not keep_wall_gaps and not repeats_stopped(np.array([0.0, 0.0, 1.0]), stopped):
            r = self._up_then_away(lift_scene, vertical_start_scene, start_scene, held_scene, q_grasp, g.T_base_tcp,
                                   centre, held_item_pairs, doubtful, remade=remade)
            if r is not None:
                return with_approach(r[0], UP_THEN_AWAY[0] + UP_THEN_AWAY[1], lift_up_then_away=1.0)
        # No line planned, so none reached the lift that first parts the item from what it touches. Where the fitted
        # pose of what it nests in is doubtful (doubtful_support.pose_doubtful: a bowl under it seen in part, fitted a
        # centimetre off) and reaches deep into it, every line keeps that overlap past the travel a start contact may
        # last; lifted first along its own axis, checked against that support's seen points, it comes out. Only off
        # a doubtful support: tried for every support, it changed picks elsewhere whose grasps then missed.
        # Likewise off any support where the up-then-away lift planned but was refused because a start contact may be
        # made again within the fits' error (a bowl's foot under a plate's flange, the bowl by a basin wall).
        if not separated and not keep_wall_gaps and (remade or any(
                pose_doubtful(by_name[x], s.visible_fraction_unoccluded) for p in held_item_pairs for x in p if x in by_name)):
            r = self._separating_lift(lift_scene, start_scene, held_scene, q_grasp, g, held_item_pairs, by_name,
                                      stopped)
            if r is not None:
                return with_approach(r[0], LIFT_CONTACT_TRAVEL, lift_separate_m=float(np.linalg.norm(r[2])),
                                     lift_separate_last=1.0)
        if remade:  # the last resort: the up-then-away lift as it planned before the fits' rules applied to it
            return with_approach(remade[0][0], UP_THEN_AWAY[0] + UP_THEN_AWAY[1], lift_up_then_away=1.0,
                                 lift_fit_fallback=1.0)
        if walls and not keep_wall_gaps:
            # every lift failed with the walls checked as before: once more keeping the gaps to the walls (a lift
            # that planned before is unchanged: a plate leaning on a wall still leaves it tilted away from it)
            again = self._plan_pick_with(q0, g, objects, map_points, base_scene, timings, keep_wall_gaps=True,
                                         stopped=stopped)
            if not isinstance(again, PlanningFailure):
                return again
        if first is None:  # every lift there was to try repeats one a protective stop cut short
            first = CartesianPathFailed("lift: every lift repeats one a protective stop cut short", {"segment": "lift"})
        if lift_objects:
            first.details["lift_objects"] = sorted(lift_objects)
        first.details["held_blocked"] = held_only
        return first

    # m: least gap to a basin wall at the grasp that a lift keeps as its margin with that wall (_wall_gaps); a
    # smaller one is a contact (an item leaning on the wall), left within LIFT_CONTACT_TRAVEL as before
    WALL_GAP_MIN = 0.0005

    def _wall_gaps(self, scene: Scene, q_grasp: np.ndarray, pairs) -> dict:
        """{(held, cell:...): margin} for the held item's pairs with the cell's fixed surfaces among `pairs` (those
        within the grasp margin at the grasp) where it is clear of that surface by at least WALL_GAP_MIN: the
        margin is that gap less LIFT_CLEARANCE_TOL (at least WALL_GAP_MIN / 2). The cell's surfaces are known
        exactly; an item standing a millimetre or two off a basin wall (a glass lying tilted over a cup, its upper
        end by the wall) is lifted straight up past it keeping that gap, where the grasp margin (2 mm) failed the
        lift as a slide along the wall once the first LIFT_CONTACT_TRAVEL was used up, and every lift tilted away
        from the wall ran into the cup. A last resort (see _plan_pick_with): with the wall checked as before, an
        item leaning on it leaves it at once, tilted away."""
        out = {}
        for p in pairs:
            if "held" not in p or not any(x.startswith("cell:") for x in p):
                continue
            d = scene.clearance(q_grasp, p, self.settings.grasp_margin)
            if d >= self.WALL_GAP_MIN:
                out[tuple(p)] = max(d - LIFT_CLEARANCE_TOL, self.WALL_GAP_MIN / 2)
        return out

    @staticmethod
    def _pinned_by(vertical_start_scene: Scene, start_scene: Scene, q_grasp: np.ndarray,
                   on_it: set[str]) -> CartesianPathFailed | None:
        """The lift's failure when the held item, at the grasp, is within the margin of an item lying on it (names
        in `on_it`, ``obj:...``), else None. Every lift line starts at the grasp and checks that pair from its first
        state on, in either start scene, so each direction and sidestep would fail there: the failure the first
        (straight up) line gives, with what the others would add (``lift_objects``), and ``held_blocked`` (no other
        grasp of the item changes it; the item lying on it goes first)."""
        if not on_it:
            return None
        pairs = vertical_start_scene.colliding_pairs(q_grasp)
        if not any("held" in p and on_it.intersection(p) for p in pairs):
            return None
        names = {n[4:] for p in pairs + start_scene.colliding_pairs(q_grasp) for n in p if n.startswith("obj:")}
        what = ", ".join(f"{a}/{b}" for a, b in pairs[:4])
        return CartesianPathFailed(f"lift: straight line collides ({what})",
                                   {"pairs": pairs, "q": np.asarray(q_grasp).tolist(), "segment": "lift",
                                    "lift_objects": sorted(names), "held_blocked": True, "pinned": True})

    # m of gap after which the held item has left a neighbour it started against (a touch after that is a new
    # contact): none, as in the simulator and a real arm's contact detection, where any configuration at which the
    # two no longer touch ends the contact (a bowl lifted along a tilted bowl's wall parts from it by a fraction of
    # a millimetre and presses into it again a few millimetres higher: with a 0.5 mm allowance that was one contact)
    CONTACT_LEFT_GAP = 0.0

    def _contact_comes_back(self, scene: Scene, Q: np.ndarray, pairs: list[tuple[str, str]]) -> tuple[str, str] | None:
        """The first of `pairs` (the held item with a neighbour it touches at the start of the lift `Q`) that the
        lift parts by more than CONTACT_LEFT_GAP and then brings into contact again (no margin), or None. The
        simulator, like a real arm's contact detection, tolerates a resting contact that lasts while the item is
        lifted off, not one that breaks and comes back: a bowl lying across the mouth of a tilted bowl, lifted
        straight up, leaves its rim and runs into the tilted bowl's raised wall a centimetre higher. The lift's
        own check lets such a pair touch for the first centimetres (a support is left by any lift) and, within the
        margins, saw one unbroken contact."""
        if not pairs or len(Q) < 2:
            return None
        Q = np.asarray(Q, float)
        Q = np.vstack([np.vstack([a, (a + b) / 2]) for a, b in zip(Q[:-1], Q[1:])] + [Q[-1:]])  # half steps
        for p in pairs:
            apart = np.flatnonzero(~scene.touching(Q, p, self.CONTACT_LEFT_GAP))
            if len(apart) and scene.touching(Q[apart[0]:], p).any():
                return p
        return None

    def _remade_in_fit(self, scene: Scene, Q: np.ndarray, pairs: list[tuple[str, str]],
                       doubtful: set[str] = frozenset(), gaps: LiftGaps | None = None) -> tuple[str, str] | None:
        """The first of `pairs` (the held item with a neighbour it touches at the start of the lift `Q`) whose contact
        may, within the fits' resolution, break and be made again (_remade_within_fit on the half-step samples'
        signed gaps), or, for a neighbour named in `doubtful` (its pose doubtful), within that pose's error
        (_may_meet_doubtful_again); or None. A lift refused for it alone is the last resort
        (Planner._plan_pick_with): the other directions, and first of all the one that parts the item from what it
        touches, come before it. `gaps`: the lift's signed gaps where the caller has them (planning/lift_gaps.py),
        else computed here; both checks read the same ones."""
        if not pairs or len(Q) < 2:
            return None
        gaps = gaps or LiftGaps(scene, Q)
        for p in pairs:
            s = gaps.of(p)
            if self._remade_within_fit(np.clip(s, -self.GAP_SPAN, self.GAP_SPAN)) or \
                    self._remade_within(s, self.FIT_POSE_REACH, NARROWING_TOL):
                return p
        return self._may_meet_doubtful_again(scene, Q, pairs, doubtful, gaps)

    def _may_meet_doubtful_again(self, scene: Scene, Q: np.ndarray, pairs: list[tuple[str, str]],
                                 doubtful: set[str], gaps: LiftGaps | None = None) -> tuple[str, str] | None:
        """The first of `pairs` with a neighbour named in `doubtful` (a support whose fitted pose is doubtful,
        doubtful_support.pose_doubtful) whose gap to the held item, along the lift `Q` (half steps), narrows again
        after parting while within doubtful_support.POSE_ERROR of the start's (each by more than NARROWING_TOL), or
        None. In the world the two touch at the start, and the support's wall may be POSE_ERROR nearer than its fit
        says: a bowl lifted along its own axis out of a bowl seen 11 % parted from its fitted pose to 1.9 mm and
        narrowed back to 1.6 mm; in the world the gap opened to 0.9 mm and closed (the simulator's collision). A lift
        straight up, parting steadily, passes. `gaps`: as for _remade_in_fit."""
        mine = [p for p in pairs if doubtful.intersection(p)]
        if not mine or len(Q) < 2:
            return None
        gaps = gaps or LiftGaps(scene, Q)
        for p in mine:
            s = gaps.of(p)
            if len(s) and s[0] < -POSE_ERROR:
                # the fit overlaps the held item deeper than POSE_ERROR at the grasp, where in the world the two only
                # touch: it is off by more than this rule allows for and cannot say where the support's wall is (a
                # bowl seen 10 %, fitted 1.1 cm and 16 degrees off into the bowl resting in it). Its seen points decide
                # (doubtful_support.approaches_points, on every leg off a doubtful support)
                continue
            if self._remade_within(s, POSE_ERROR, NARROWING_TOL):
                return p
        return None

    # m: how far the fitted poses may be off in how deep two resting items overlap (fits within a few tenths of a
    # millimetre): in the world the two only touch where the fitted poses overlap by up to this much
    FIT_RESOLUTION = 0.0005
    # m: how much nearer than their fits say two well-seen resting items may be where a lift closes the gap between
    # them again after parting (a bowl fitted 0.6 degrees off in tilt, 0.7 mm off, on a plate 0.4 mm off: its foot
    # passed the plate's rim 1.0 mm clear in the fits and met it in the world)
    FIT_POSE_REACH = 0.002
    # m: a change in the overlap that counts (the signed gaps' bisection is 0.02 mm)
    CONTACT_REMAKE_TOL = 0.00005
    # m: the overlaps and gaps measured along a lift (deeper or farther ones are clipped)
    GAP_SPAN = 0.003

    @classmethod
    def _remade_within_fit(cls, s: np.ndarray) -> bool:
        """Whether a start contact whose signed gap along the lift is `s` (m, from the grasp on; negative: overlap,
        as the fitted poses have it) may, in the world, break and be made again: the items only touch at the start
        (their true gap is the fitted one less s[0], up to FIT_RESOLUTION deeper), so the contact may break where the
        fitted overlap gets shallower than at the start and be made again where it deepens after that, back to
        within FIT_RESOLUTION of the start's. Both by more than CONTACT_REMAKE_TOL. A bowl lying tilted in another,
        lifted straight up, slides along the lower one's wall: in the world the two parted by 0.16 mm and met again,
        while the fitted poses overlapped by 0.73 to 0.85 mm and then deeper, one contact at zero gap."""
        return cls._remade_within(s, cls.FIT_RESOLUTION, cls.CONTACT_REMAKE_TOL)

    @staticmethod
    def _remade_within(s: np.ndarray, reach: float, tol: float) -> bool:
        """Whether the signed gaps `s` (m, along a lift from its start) get wider than at the start and then narrow
        again, both by more than `tol`, to within `reach` of the start's."""
        s = np.asarray(s, float)
        if len(s) < 3:
            return False
        peak = np.maximum.accumulate(s)[:-1]  # the shallowest overlap (or widest gap) before each state
        later = s[1:]
        return bool(np.any((peak > s[0] + tol) & (peak - later > tol) & (later <= s[0] + reach)))

    def _separating_lift(self, lift_scene: Scene, start_scene: Scene, held_scene: Scene, q_grasp: np.ndarray,
                         g: Grasp, pairs: list[tuple[str, str]],
                         by_name: dict, stopped: tuple = ()) -> tuple[Trajectory, np.ndarray, np.ndarray] | None:
        """(lift, its end, first leg) of a lift in two legs whose first opens the held item's start contacts with the
        items in `pairs` at once (planning.lift.separating_legs, on the perceived poses: out of the item it nests
        in along the contact's normal until clear of it by the grasp margin), then straight up; or None where no
        direction parts them, or every one's lift collides, makes a contact again (_contact_comes_back,
        _remade_in_fit) or ends within the transport margins (`held_scene`). The directions are tried best first, each checked against everything else with the lift's
        margins: the one that parts the item fastest from what it rests in may lead it towards something else (a
        third bowl under the two, perceived as none, whose points stay obstacles). `stopped`: directions of lifts a
        protective stop cut short: no first leg along one (_two_leg_lift)."""
        names = sorted({x for p in pairs for x in p if x in by_name})
        if not names:
            return None
        doubtful = [n for n in names if pose_doubtful(by_name[n], self.settings.visible_fraction_unoccluded)]
        if doubtful:  # its pose may not choose the direction (planning/doubtful_support.py)
            return self._lift_off_doubtful(lift_scene, start_scene, held_scene, q_grasp, g, pairs, by_name, doubtful,
                                           stopped)
        held_bvh = self.world.bvh(self.inventory[g.obj.obj_id])
        T_held = np.asarray(g.obj.T_base_obj, float)
        others = [(self.world.bvh(self.inventory[by_name[n].obj_id]), coal_transform(by_name[n].T_base_obj))
                  for n in names]

        def gap(offset: np.ndarray, other) -> float:
            T = T_held.copy()
            T[:3, 3] += offset
            T_c = coal_transform(T)
            if coal.collide(held_bvh, T_c, other[0], other[1], coal.CollisionRequest(), coal.CollisionResult()):
                return 0.0
            return float(coal.distance(held_bvh, T_c, other[0], other[1], coal.DistanceRequest(),
                                       coal.DistanceResult()))

        for leg in separating_legs(gap, others, self.settings.grasp_margin):
            r = self._two_leg_lift(lift_scene, start_scene, q_grasp, g.T_base_tcp, leg, stopped)
            if isinstance(r, PlanningFailure):
                continue
            lift, q_lifted = r
            if held_scene.valid(q_lifted) and self._contact_comes_back(lift_scene, lift.q, pairs) is None and \
                    self._remade_in_fit(lift_scene, lift.q, pairs) is None:
                return lift, q_lifted, leg
        return None

    def _lift_off_doubtful(self, lift_scene: Scene, start_scene: Scene, held_scene: Scene, q_grasp: np.ndarray,
                           g: Grasp, pairs: list[tuple[str, str]], by_name: dict,
                           doubtful: list[str], stopped: tuple = ()) -> tuple[Trajectory, np.ndarray, np.ndarray] | None:
        """_separating_lift's answer where some of the items the held one touches at the grasp (`doubtful`, their
        pairs' names) have poses too poorly supported by what was seen of them to choose a direction
        (doubtful_support.pose_doubtful): a lift in two legs, first LIFT_CONTACT_TRAVEL along the held item's own
        axis or in a cone about it (doubtful_support.own_axis_directions: off whatever it rests on, wherever that
        is), then straight up. Those items' fitted poses are not checked for collisions with the held item; their
        own points are instead (doubtful_support.approaches_points: no point may come nearer the swept item than at
        the grasp while within POINT_REACH of it), and the gap to their fitted poses may not narrow again after
        parting within their error (_may_meet_doubtful_again). Everything else is checked as on the separating lift.
        None where no such lift plans."""
        skip = [p for p in lift_scene.pair_names if "held" in p and any(x in doubtful for x in p)]
        trusted = [p for p in pairs if not any(x in doubtful for x in p)]
        lift_free, start_free = lift_scene.allowing(skip), start_scene.allowing(skip)
        held_bvh = self.world.bvh(self.inventory[g.obj.obj_id])
        points = np.vstack([np.asarray(by_name[n].points, float).reshape(-1, 3) for n in doubtful])
        T_tcp_obj = inv(g.spec.T_obj_tcp)
        for d in own_axis_directions(g.obj.T_base_obj):
            leg = LIFT_CONTACT_TRAVEL * d
            r = self._two_leg_lift(lift_free, start_free, q_grasp, g.T_base_tcp, leg, stopped)
            if isinstance(r, PlanningFailure):
                continue
            lift, q_lifted = r
            gaps = LiftGaps(lift_scene, lift.q)
            if not held_scene.valid(q_lifted) or self._contact_comes_back(lift_scene, lift.q, trusted) is not None \
                    or self._remade_in_fit(lift_scene, lift.q, trusted, gaps=gaps) is not None \
                    or self._may_meet_doubtful_again(lift_scene, lift.q, pairs, set(doubtful), gaps) is not None:
                continue
            path = [self.robot.fk_tcp(q) @ T_tcp_obj for q in lift.q]
            if approaches_points(held_bvh, path, points, POINT_REACH):
                continue
            return lift, q_lifted, leg
        return None

    # m around the TCP and the flange within which a voxel the gripper (palm 75 x 140 mm, pads, camera) ran into lies
    TOOL_REACH = 0.08

    def _voxels_hit(self, scene: Scene, failure: PlanningFailure, g: Grasp) -> list:
        """The map voxels (centres, as tuples: each counts once however many lifts ran into it) a failed lift of `g`
        ran into, where the line collided with ``voxels``: those within the held item's reach of its centre, or
        within TOOL_REACH of the TCP or the flange (none when the line collided with no voxel)."""
        q = failure.details.get("q")
        if q is None or not any("voxels" in p for p in failure.details.get("pairs", ())) or not len(scene.voxels):
            return []
        T_tcp = self.robot.fk_tcp(np.asarray(q, float))
        T_obj = T_tcp @ inv(g.spec.T_obj_tcp)
        flange = (T_tcp @ inv(self.robot.T_flange_tcp))[:3, 3]
        v, pad = scene.voxels, self.world.voxel_size
        near = np.linalg.norm(v - T_obj[:3, 3], axis=1) <= self.inventory[g.obj.obj_id].diameter / 2 + pad
        for c in (T_tcp[:3, 3], flange):
            near |= np.linalg.norm(v - c, axis=1) <= self.TOOL_REACH + pad
        return [tuple(x) for x in v[near]]

    def _two_leg_lift(self, lift_scene: Scene, start_scene: Scene, q_grasp: np.ndarray, T_grasp: np.ndarray,
                      leg: np.ndarray, stopped: tuple = ()) -> tuple[Trajectory, np.ndarray] | PlanningFailure:
        """A lift in two straight legs: by `leg` (base frame, m: nearly level, out from under what overhangs the
        item; the held item may leave its start contacts during the first LIFT_CONTACT_TRAVEL as on any lift),
        then straight up by lift_height; timed as one path (planning.lift.sidesteps). Refused where `leg` runs
        along one of the `stopped` directions (a lift of this item a protective stop cut short)."""
        if repeats_stopped(leg, stopped):
            return CartesianPathFailed("lift: its first leg repeats a lift a protective stop cut short",
                                       {"segment": "lift"})
        info1: dict = {}
        r = self._line(lift_scene, q_grasp, trans(*leg) @ T_grasp, "lift", check_start=False,
                       start_scene=start_scene, start_travel=LIFT_CONTACT_TRAVEL, info=info1)
        if isinstance(r, PlanningFailure):
            return r
        q1 = r[1]
        info2: dict = {}
        r = self._line(lift_scene, q1, trans(0.0, 0.0, self.settings.lift_height) @ self.robot.fk_tcp(q1), "lift",
                       check_start=False, info=info2)
        if isinstance(r, PlanningFailure):
            return r
        Q = np.vstack([info1["path"], info2["path"][1:]])
        traj = self._time(Q, "lift", "along_path")
        if isinstance(traj, PlanningFailure):
            return traj
        return traj, Q[-1]

    def _up_then_away(self, lift_scene: Scene, vertical_start_scene: Scene, start_scene: Scene, held_scene: Scene,
                      q_grasp: np.ndarray, T_grasp: np.ndarray, centre: np.ndarray,
                      held_item_pairs, doubtful: set[str] = frozenset(),
                      remade: list | None = None) -> tuple[Trajectory, np.ndarray] | None:
        """(lift, end) in two straight legs for an item that touches a basin wall at the grasp, or None: straight up by
        UP_THEN_AWAY[0] (its start contacts may last, as on any lift straight up), then tilted towards the sink's
        middle (planning.lift.base_directions' tilts) by lift_height, its start contacts allowed for the first
        UP_THEN_AWAY[1] of that leg (it leaves the wall it slid up along). An item leaning on a wall with its lower
        end in a neighbour (an upturned cup on an upturned cup, tilted against the wall) slides along the wall on
        every line straight up, and drags its lower end through the neighbour on every line tilted from the grasp;
        up out of the neighbour first, then away from the wall, it comes out. The simulator, like a real arm,
        tolerates a start contact that lasts unbroken for 10 cm of travel (fakes/collision.py); here at most
        UP_THEN_AWAY[0] + UP_THEN_AWAY[1], and a neighbour's contact, once left, may not come back (nor come near
        again within the fits' error, as on every other lift: _remade_in_fit, which includes
        _may_meet_doubtful_again). A lift refused for the fits' error alone is appended to `remade` (lift, end), where
        given: the caller's last resort, after the separating lift (it planned before that rule)."""
        up, keep = UP_THEN_AWAY
        info1: dict = {}
        r = self._line(vertical_start_scene, q_grasp, trans(0.0, 0.0, up) @ T_grasp, "lift", check_start=False,
                       info=info1)  # the whole leg is within the start contacts' travel
        if isinstance(r, PlanningFailure):
            return None
        q1 = r[1]
        T1 = self.robot.fk_tcp(q1)
        for d in self._lift_directions(centre)[1:]:
            info2: dict = {}
            r = self._line(lift_scene, q1, trans(*(self.settings.lift_height * d)) @ T1, "lift", check_start=False,
                           start_scene=start_scene, start_travel=keep, info=info2)
            if isinstance(r, PlanningFailure) or not held_scene.valid(r[1]):
                continue
            Q = np.vstack([info1["path"], info2["path"][1:]])
            if self._contact_comes_back(lift_scene, Q, held_item_pairs) is not None:
                continue
            gaps = LiftGaps(lift_scene, Q)
            if self._remade_in_fit(lift_scene, Q, held_item_pairs, doubtful, gaps) is not None:
                # refused for the fits' error alone (not a doubtful support's): kept as the last resort
                if remade is not None and \
                        self._may_meet_doubtful_again(lift_scene, Q, held_item_pairs, doubtful, gaps) is None:
                    traj = self._time(Q, "lift", "along_path")
                    if not isinstance(traj, PlanningFailure):
                        remade.append((traj, Q[-1]))
                continue
            traj = self._time(Q, "lift", "along_path")
            if not isinstance(traj, PlanningFailure):
                return traj, Q[-1]
        return None

    # after a lift that ends within the transport margin: short moves towards the sink's middle (level, then up)
    LIFT_CLEAR_MOVES = ((0.02, 0.0), (0.04, 0.0), (0.03, 0.05))

    def _lift_clear_of_walls(self, lift_scene: Scene, held_scene: Scene, q_lifted: np.ndarray, Q_lift: np.ndarray,
                             centre: np.ndarray) -> tuple[Trajectory, np.ndarray] | None:
        """(lift trajectory, end) extended by a short straight move towards the sink's middle (LIFT_CLEAR_MOVES:
        metres level, metres up) after which the lifted pose keeps the full margins, or None. The move is
        checked like the rest of the lift (grasp margins, no start contacts); the lift is re-timed as one path."""
        lo, hi = self.cell.sink_interior
        to_mid = (np.asarray(lo, float) + np.asarray(hi, float))[:2] / 2 - np.asarray(centre, float)[:2]
        if np.linalg.norm(to_mid) < 1e-6:
            return None
        to_mid /= np.linalg.norm(to_mid)
        T_end = self.robot.fk_tcp(q_lifted)
        for level, up in self.LIFT_CLEAR_MOVES:
            T_goal = trans(level * to_mid[0], level * to_mid[1], up) @ T_end
            Q = cartesian_line(self.robot, lift_scene, q_lifted, T_goal, step=self.settings.validity_resolution,
                               check_step=self.settings.validity_resolution, check_start=False)
            if isinstance(Q, PlanningFailure) or not held_scene.valid(Q[-1]):
                continue
            traj = self._time(np.vstack([Q_lift, Q[1:]]), "lift", "along_path")
            if not isinstance(traj, PlanningFailure):
                return traj, Q[-1]
        return None

    @staticmethod
    def _lift_directions_away(centre: np.ndarray, objects, names: set[str], have: list[np.ndarray]) -> list[np.ndarray]:
        """planning.lift.directions_away."""
        return directions_away(centre, objects, names, have)

    def _near_sink_wall(self, o: ObjectPose, clearance: float = 0.03) -> bool:
        """Whether the object reaches within `clearance` of a basin wall (its bounding sphere)."""
        if o.obj_id not in self.inventory.models:
            return True
        lo, hi = self.cell.sink_interior
        c = np.asarray(o.T_base_obj, float)[:2, 3]
        gap = min(float(np.min(c - np.asarray(lo, float)[:2])), float(np.min(np.asarray(hi, float)[:2] - c)))
        return gap < self.inventory[o.obj_id].diameter / 2 + clearance

    def _lift_directions(self, p: np.ndarray, T_base_obj: np.ndarray | None = None, *,
                         away_from_walls: bool = True) -> list[np.ndarray]:
        """planning.lift.base_directions for this cell's sink."""
        return base_directions(self.cell.sink_interior, p, T_base_obj, away_from_walls=away_from_walls)

    # ---- place -----------------------------------------------------------------------------------------------------
    def _place_turns(self, target: PlaceTarget, obj_id: int) -> list[np.ndarray]:
        """Object-frame rotations (4x4, applied as T_base_obj @ R) the planner may use for this target."""
        key = (obj_id, np.asarray(target.T_base_obj, float).tobytes(), bool(target.free_yaw), target.flip_ok,
               target.kind)
        hit = self._turns_cache.get(key)
        if hit is None:
            if len(self._turns_cache) > 2000:
                self._turns_cache.clear()
            hit = self._turns_cache[key] = self._place_turns_uncached(target, obj_id)
        return hit

    def _place_turns_uncached(self, target: PlaceTarget, obj_id: int) -> list[np.ndarray]:
        model = self.inventory.models.get(obj_id)
        sym = model is not None and model.is_rotationally_symmetric
        T_obj = np.asarray(target.T_base_obj, float)
        turns = [rot_z(a) for a in np.linspace(0, 2 * np.pi, 12, endpoint=False)] if (target.free_yaw or sym) else [np.eye(4)]
        flip = target.flip_ok
        if flip is None:
            flip = target.kind == "slot" and sym and is_lying(T_obj)
        if flip:
            # pi about the base vertical through the object's origin, expressed in the object frame
            R = np.eye(4)
            R[:3, :3] = T_obj[:3, :3].T @ rot_z(np.pi)[:3, :3] @ T_obj[:3, :3]
            turns = turns + [R @ t for t in turns]
        return turns

    def _place_tcp_options(self, target: PlaceTarget, T_obj_tcp: np.ndarray, q_ref: np.ndarray,
                           release_scene: Scene | OnDemand | None = None, first_only: bool = False, obj_id: int | None = None,
                           pre_scene: Scene | None = None):
        """[(T_base_obj, T_base_tcp, q)] reachable release poses for `target` with this grasp, closest first.

        With `pre_scene` (the transfer's scene: full margins, the object held), a release pose counts only if
        its pre-place pose (straight above it by the approach distance, reached from it without changing the IK
        branch) is free too: plan_place comes down from there. Without this check the grasp filter kept grasps
        whose only release poses had the wrist in the gripper's palm 10 cm higher up (a cup turned over with a
        level side grasp: staged items were never picked again).

        Free-yaw targets are turned about the object's own axis in 30 degree steps. When `release_scene` is
        given, a release pose whose gripper/held object collides is raised in 1 cm steps up to
        ``settings.max_release_drop`` (the object then drops that far when released, e.g. a cup inverted over
        a rack whose rails are taller than the gripper can reach past).

        Every closed-form IK branch of a release pose is tried (numerical IK only where there is none, at wrist
        singularities): over a rack the branch nearest `q_ref` often has its elbow or wrist in a rack wall where
        another branch is free. The answer then does not depend on `q_ref` either: the grasp filter (which asks
        from the arm's configuration before the pick) and plan_place (from the lifted configuration) agree; with
        one numerically found branch per pose they did not (a grasp chosen for its reachable release, then
        ``no_feasible_placement`` in plan_place)."""
        T_obj = np.asarray(target.T_base_obj, float)

        def turns() -> list[np.ndarray]:
            if obj_id is not None:
                return self._place_turns(target, obj_id)
            return [rot_z(a) for a in np.linspace(0, 2 * np.pi, 12, endpoint=False)] if target.free_yaw else [np.eye(4)]

        c = float(max(target.clearance, 0.0))
        raises = np.arange(c, c + self.settings.max_release_drop + 1e-9, 0.01) if release_scene is not None else np.array([c])
        up = target.approach_distance if target.approach_distance is not None else self.settings.approach_distance
        # the geometry (IK branches, checks against the cell alone) is kept across queries: planning/place_reach.py
        T_obj_tcp = np.asarray(T_obj_tcp, float)
        key = (obj_id, T_obj_tcp.tobytes(), T_obj.tobytes(), bool(target.free_yaw), target.flip_ok, target.kind,
               raises.tobytes(), float(up), float(self.settings.max_approach_up))
        return self._place_reach.options(key, turns, T_obj, T_obj_tcp, raises, up, self.settings.max_approach_up,
                                         np.asarray(q_ref, float), release_scene, pre_scene, first_only)

    def _within_reach(self, T_base_tcp: np.ndarray) -> bool:
        """Whether the wrist centre of a TCP pose is within the arm's reach of the shoulder (an IK pre-filter)."""
        ur = self.robot.ur
        reach = abs(ur.a[1]) + abs(ur.a[2]) + np.hypot(ur.d[3], ur.d[4]) + 0.02
        wrist = T_base_tcp[:3, 3] - T_base_tcp[:3, :3] @ self.robot.T_flange_tcp[:3, 3]
        return bool(np.linalg.norm(wrist - np.array([0.0, 0.0, ur.d[0]])) <= reach)

    def plan_place(
        self,
        q_start: np.ndarray,
        grasp: Grasp,
        target: PlaceTarget | Sequence[PlaceTarget],
        *,
        objects: Sequence[ObjectPose] = (),
        map_points: np.ndarray | None = None,
    ) -> PlacePlan | PlanningFailure:
        """Carry the object held with `grasp` to `target` (or the first feasible of a list): transfer, straight
        lower, (open), straight retreat. `objects` are the other perceived objects (the held one is excluded by
        identity or instance id)."""
        q0 = self._check_q(q_start, "q_start")
        if isinstance(q0, PlanningFailure):
            return q0
        targets = [target] if isinstance(target, PlaceTarget) else list(target)
        bad = [type(t).__name__ for t in targets if not isinstance(t, PlaceTarget)]
        if bad:
            return InvalidInput(f"plan_place target: expected a PlaceTarget or a sequence of them, got items of type {bad[:3]}")
        targets = targets[: self.settings.max_place_targets]
        if not targets:
            return NoFreeSlot("plan_place: no target given")
        for t in targets:
            try:
                check_rigid(t.T_base_obj, "PlaceTarget.T_base_obj")
            except ValueError as e:
                return InvalidInput(str(e))
        s = self.settings
        timings: dict = {}
        t_start = time.perf_counter()
        held_scene = self.scene(objects, map_points, exclude=grasp.obj, held=grasp, own=[grasp.obj])
        release_scene = held_scene.for_release(None)
        last: PlanningFailure | None = None
        for tgt in targets:
            options = self._place_tcp_options(tgt, grasp.T_obj_tcp, q0, release_scene, obj_id=grasp.obj.obj_id,
                                              pre_scene=held_scene)
            if not options:
                if last is None or last.kind == "no_feasible_placement":  # keep a more specific failure
                    last = NoFeasiblePlacement(f"no reachable release pose for target {tgt.slot or tgt.kind}")
                continue
            for T_obj, T_tcp, q_place in options[:4]:
                up = tgt.approach_distance if tgt.approach_distance is not None else s.approach_distance
                T_pre = trans(0.0, 0.0, up) @ T_tcp
                q_pre = self.robot.ik_q(T_pre, q_place, max_seeds=0)
                if q_pre is None or not held_scene.valid(q_pre):
                    last = NoFeasiblePlacement("pre-place pose unreachable or in collision")
                    continue
                transfer = self._joint_motion(held_scene, q0, q_pre, "transfer", timings)
                if isinstance(transfer, PlanningFailure):
                    last = transfer
                    if transfer.kind in ("start_in_collision",):
                        return transfer
                    continue
                r = self._line(release_scene, q_pre, T_tcp, "lower")
                if isinstance(r, PlanningFailure):
                    last = r
                    continue
                lower, q_rel = r
                # after release: the object rests at the target height (it fell by the release drop, if any);
                # the open pads back out along the approach axis
                T_rest = T_obj.copy()
                T_rest[2, 3] = min(T_obj[2, 3], float(np.asarray(tgt.T_base_obj)[2, 3]))
                placed = ObjectPose(grasp.obj.obj_id, grasp.obj.cls, T_rest, 1.0, instance_id=PLACED_ID)
                r = self._retreat(objects, map_points, grasp, placed, q_rel, T_tcp, up)
                if isinstance(r, PlanningFailure):
                    last = r
                    continue
                retreat, opening = r
                timings["total_ms"] = (time.perf_counter() - t_start) * 1e3
                return PlacePlan(tgt, T_obj, T_tcp, transfer, lower, retreat, timings_ms=timings,
                                 release_opening=opening)
        assert last is not None
        return last

    def _retreat(self, objects, map_points, grasp: Grasp, placed: ObjectPose, q_rel: np.ndarray, T_tcp: np.ndarray,
                 up: float) -> tuple[Trajectory, float] | PlanningFailure:
        """(retreat, gripper opening at release) after letting go of `placed` at q_rel: the open pads back out along
        the approach (else straight up), ending with the full margins; only where no opening allows either, a few
        centimetres back and then up (_two_leg_retreat). The widest opening (release_openings: the
        grasp's own, then down to a few mm per pad past the item's width) whose pads, opened at the release pose,
        touch nothing but the released item (a neighbour in a rack stands a few mm from a pad) and whose retreat
        is free; where none is, the grasp's own opening with only the retreat checked (as the release pose itself
        may then touch: the pads leave the item along the approach)."""
        first: PlanningFailure | None = None
        widest = grasp.spec.opening
        tried: list[tuple[float, Scene, Scene]] = []
        for opening, start_clear in [*((o, True) for o in release_openings(widest, grasp.spec.width)),
                                     (widest, False)]:
            after = self.scene([*objects, placed], map_points, exclude=grasp.obj, opening=opening)
            after_scene = after.for_grasp(object_name(placed, 0))
            if start_clear and not after_scene.valid(q_rel):
                continue
            tried.append((opening, after_scene, after))
            for T_back in (T_tcp @ trans(0.0, 0.0, -up), trans(0.0, 0.0, up) @ T_tcp):
                r = self._line(after_scene, q_rel, T_back, "retreat", check_start=False)
                if not isinstance(r, PlanningFailure):
                    if after.valid(r[1]):  # the next plan starts here, with the full margins
                        return r[0], opening
                    r = CartesianPathFailed("retreat: ends within the collision margin",
                                            {"pairs": after.colliding_pairs(r[1]), "segment": "retreat"})
                first = first or r
        # Only where no opening has a one-leg retreat: a retreat that works in one leg is shorter and is kept.
        for opening, after_scene, after in tried:
            r = self._two_leg_retreat(after_scene, after, q_rel, T_tcp, up)
            if r is not None:
                return r, opening
        assert first is not None
        return first

    # The first leg of a back-out-then-up retreat: metres back along the approach axis. A side grasp's pads and
    # palm hug the released item (straight up, the palm drags along it), while backing out the full approach
    # distance can put the wrist into what stands behind the gripper (a counter wall behind a staging spot): a
    # few centimetres back clear the item, then straight up clears the rest.
    RETREAT_BACK_LEGS = (0.03, 0.05)

    def _two_leg_retreat(self, after_scene: Scene, after: Scene, q_rel: np.ndarray, T_tcp: np.ndarray,
                         up: float) -> Trajectory | None:
        """A retreat in two straight legs: back along the approach axis by one of RETREAT_BACK_LEGS, then straight
        up by `up`; checked like the one-leg retreats (`after_scene`, the release pose itself excused; ends with the
        full margins in `after`), timed as one path. None when no such retreat is free."""
        for back in self.RETREAT_BACK_LEGS:
            info1: dict = {}
            r = self._line(after_scene, q_rel, T_tcp @ trans(0.0, 0.0, -back), "retreat", check_start=False,
                           info=info1)
            if isinstance(r, PlanningFailure):
                continue
            q1 = r[1]
            info2: dict = {}
            r = self._line(after_scene, q1, trans(0.0, 0.0, up) @ self.robot.fk_tcp(q1), "retreat", info=info2)
            if isinstance(r, PlanningFailure) or not after.valid(r[1]):
                continue
            traj = self._time(np.vstack([info1["path"], info2["path"][1:]]), "retreat", "along_path")
            if not isinstance(traj, PlanningFailure):
                return traj
        return None

    # ---- free motion -----------------------------------------------------------------------------------------------
    def plan_slide(self, q_start: np.ndarray, objects: Sequence[ObjectPose], target: ObjectPose, *,
                   map_points: np.ndarray | None = None, distance: float = 0.06, then_pickable: bool = True,
                   off: Sequence[ObjectPose] = (), avoid: Sequence = ()):
        """Slide `target` sideways with the closed fingers pressing on it, so that it can be picked afterwards
        (the top plate of a nested stack; `then_pickable`), or so that it no longer lies on the items `off` (it
        blocks their lifts); `avoid`: (T_base_press, direction) of its slides that stopped: see planning.slide."""
        from kitchenbot.planning.slide import plan_slide

        q0 = self._check_q(q_start, "q_start")
        if isinstance(q0, PlanningFailure):
            return q0
        return plan_slide(self, q0, list(objects), target, map_points=map_points, distance=distance,
                          then_pickable=then_pickable, off=off, avoid=avoid)

    def onward_staging(self, q_current: np.ndarray, stage: Sequence[PlaceTarget], obj: ObjectPose,
                       targets, objects: Sequence[ObjectPose] = (), *,
                       map_points: np.ndarray | None = None) -> list[PlaceTarget]:
        """The staging targets from which the item, set down there, offers a grasp that reaches one of `targets`
        (a list, or a function of the item resting there giving its targets there; turn fixed where it matters):
        see planning.regrasp."""
        from kitchenbot.planning.regrasp import onward_staging

        return onward_staging(self, stage, obj, targets, objects, map_points, np.asarray(q_current, float))

    def plan_escape(self, q_start: np.ndarray, objects: Sequence[ObjectPose] = (), *,
                    map_points: np.ndarray | None = None, held: Grasp | None = None,
                    opening: float | None = None) -> MovePlan | PlanningFailure:
        """A short straight TCP line out of a stop within the collision margin (`opening`: the open gripper's pad
        distance, when known): see planning.escape."""
        from kitchenbot.planning.escape import plan_escape

        q0 = self._check_q(q_start, "q_start")
        if isinstance(q0, PlanningFailure):
            return q0
        return plan_escape(self, q0, list(objects), map_points=map_points, held=held, opening=opening)

    def points_at_robot(self, q: np.ndarray, points: np.ndarray, *, held: Grasp | None = None) -> np.ndarray:
        """Which of `points` (N, 3, base frame) make `q` collide as map points: those whose voxel lies within the
        collision margin of the arm, the tool (pads fully open, as plan_move has them) or `held` there."""
        P = np.asarray(points, float).reshape(-1, 3)
        if not len(P):
            return np.zeros(0, bool)
        vs = self.world.voxel_size
        cells, inverse = np.unique(np.floor(P / vs).astype(np.int64), axis=0, return_inverse=True)
        h = None if held is None else Held(self.inventory[held.obj.obj_id], held.T_tcp_obj, held.spec.width)
        hit = self.world.scene([], None, h).voxels_at_robot(q, (cells + 0.5) * vs)
        return hit[np.asarray(inverse).reshape(-1)]

    def plan_move(
        self,
        q_start: np.ndarray,
        q_goal: np.ndarray,
        *,
        objects: Sequence[ObjectPose] = (),
        held: Grasp | None = None,
        map_points: np.ndarray | None = None,
        timeout_scale: float = 1.0,
        opening: float | None = None,
    ) -> MovePlan | PlanningFailure:
        """Collision-free joint motion (e.g. to a scan waypoint or home), with `held` attached if given;
        `timeout_scale` times the configured RRT-Connect budget. Planned with the pads fully open; where the
        tool starts within the margin of items (after a release: `opening`, the pads' real distance), it first
        leaves the way it came in (planning.leave)."""
        q0 = self._check_q(q_start, "q_start")
        if isinstance(q0, PlanningFailure):
            return q0
        q1 = self._check_q(q_goal, "q_goal")
        if isinstance(q1, PlanningFailure):
            return q1
        timings: dict = {}
        scene = self.scene(objects, map_points, exclude=held.obj if held is not None else None, held=held)
        traj = self._joint_motion(scene, q0, q1, "move", timings, timeout_scale)
        if isinstance(traj, StartInCollision) and held is None:
            # the tool stands within the margin of items it let go among (planning.leave): out the way it came in
            # first, the start's pairs relaxed on that leg only; from there a motion with the full margins
            from kitchenbot.planning.leave import join, leave_leg, tool_item_pairs

            pairs = scene.colliding_pairs(q0)
            if not tool_item_pairs(pairs):
                return traj
            at = scene if opening is None else self.scene(objects, map_points, opening=opening)
            leg = leave_leg(self, scene, at, q0, pairs)
            if isinstance(leg, PlanningFailure):
                return leg
            rest = self._joint_motion(scene, leg[1], q1, "move", timings, timeout_scale)
            if isinstance(rest, PlanningFailure):
                rest.message = f"after leaving {pairs} along the tool axis: {rest.message}"
                return rest
            timings["left_start_pairs"] = float(len(pairs))
            return MovePlan(join(leg[0], rest, "move"), timings)
        if isinstance(traj, PlanningFailure):
            return traj
        return MovePlan(traj, timings)
