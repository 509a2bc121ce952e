"""Slide an item sideways with the closed fingers pressing on it: the move that frees the top plate of a stack.

A plate nested on another one cannot be pinched: the lip of the plate below is a few millimetres under its lip,
where a finger would have to go. People (and this robot) slide the top plate a few centimetres sideways first;
then its lip overhangs the one below and a tilted lip pinch fits under it.

Plan (all in the base frame): press point = where a vertical line through the item's centre meets its top
surface; the closed gripper comes down on it pointing straight down (the Fin-Ray tips 3 mm into the surface:
their compliance gives the normal force), moves ``distance`` sideways level, and goes back up. The direction is
the first of eight (most free room first) in which the moved item stays inside the sink, touches nothing new,
and (if asked) can then be picked. The item is modelled as held during the slide; its contacts with what it
rests on are allowed for the whole slide (it slides on them).
"""

from __future__ import annotations

import time
from dataclasses import replace

import coal
import numpy as np
import open3d as o3d

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.collision import Held
from kitchenbot.planning.grasps import _tf, object_name
from kitchenbot.planning.motion import cartesian_line
from kitchenbot.planning.types import CartesianPathFailed, NoIK, PlanningFailure, SlidePlan
from kitchenbot.transforms import inv, make_T, rot_z, trans
from kitchenbot.world.gripper import FINGERS

PRESS_DEPTH = 0.003  # m the finger tips go into the surface (the simulator's tips; see fakes.arm._press_drag)


def _moved(o: ObjectPose, shift: np.ndarray) -> ObjectPose:
    return replace(o, T_base_obj=trans(*shift) @ np.asarray(o.T_base_obj, float),
                   points=np.asarray(o.points).reshape(-1, 3) + shift)


def press_point(model, T_base_obj: np.ndarray) -> np.ndarray | None:
    """Top surface point (base frame) on the vertical line through the item's centre, or None if it misses."""
    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.geometry.TriangleMesh(model.mesh)
    mesh.transform(np.asarray(T_base_obj, float))
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    c = np.asarray(T_base_obj, float)[:3, 3]
    ray = np.array([[c[0], c[1], c[2] + 0.3, 0.0, 0.0, -1.0]], np.float32)
    t = float(scene.cast_rays(o3d.core.Tensor(ray))["t_hit"].numpy()[0])
    return None if not np.isfinite(t) else np.array([c[0], c[1], c[2] + 0.3 - t])


class SupportHeight:
    """How high an item rests (its pose dropped straight down onto the other items and the cell) at any pose:
    the slide lifts the pressing fingers as the item climbs out of the one it is nested in."""

    def __init__(self, planner, target: ObjectPose, others: list[ObjectPose]):
        self.scene = o3d.t.geometry.RaycastingScene()
        for b in planner.cell.boxes:
            m = o3d.geometry.TriangleMesh.create_box(*np.asarray(b.size, float))
            m.translate(np.asarray(b.lower, float))
            self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
        for o in others:
            if o.obj_id not in planner.inventory.models:
                continue
            m = o3d.geometry.TriangleMesh(planner.inventory[o.obj_id].mesh)
            m.transform(np.asarray(o.T_base_obj, float))
            self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
        V = np.asarray(planner.inventory[target.obj_id].mesh.vertices)
        self.V = V[:: max(1, len(V) // 1500)]

    def drop(self, T_base_obj: np.ndarray) -> float:
        """How far (m) the item at `T_base_obj` would move down to rest (negative: up, it intersects)."""
        T = np.asarray(T_base_obj, float)
        P = self.V @ T[:3, :3].T + T[:3, 3]
        lift = 0.03  # rays start this far above each vertex (an intersecting item is pushed up by up to this)
        rays = np.hstack([P + [0.0, 0.0, lift], np.tile([0.0, 0.0, -1.0], (len(P), 1))]).astype(np.float32)
        t = self.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        t = t[np.isfinite(t)]
        return float(np.min(t) - lift) if len(t) else 1.0


def _touching(planner, a: ObjectPose, b: ObjectPose, gap: float = 0.003) -> bool:
    if a.obj_id not in planner.inventory.models or b.obj_id not in planner.inventory.models:
        return False
    d = coal.distance(planner.world.bvh(planner.inventory[a.obj_id]), _tf(a.T_base_obj),
                      planner.world.bvh(planner.inventory[b.obj_id]), _tf(b.T_base_obj),
                      coal.DistanceRequest(), coal.DistanceResult())
    return d < gap


def _cell_touching(planner, a: ObjectPose, gap: float = 0.003) -> list:
    """The cell's boxes (the sink floor, a basin wall) within `gap` of item `a`."""
    if a.obj_id not in planner.inventory.models:
        return []
    bvh, T = planner.world.bvh(planner.inventory[a.obj_id]), _tf(a.T_base_obj)
    out = []
    for b in planner.cell.boxes:
        d = coal.distance(bvh, T, coal.Box(*np.asarray(b.size, float)), _tf(make_T(t=b.centre)),
                          coal.DistanceRequest(), coal.DistanceResult())
        if d < gap:
            out.append(b)
    return out


def slide_directions(planner, target: ObjectPose, others: list, distance: float) -> list[tuple[np.ndarray, float]]:
    """(unit direction, clearance) of each of 8 horizontal directions the item can slide `distance` along:
    it stays inside the sink (5 mm from the walls), touches nothing it does not already touch and ends farther from
    the centre of each item it lies on. Most room first."""
    model = planner.inventory[target.obj_id]
    T0 = np.asarray(target.T_base_obj, float)
    V = np.asarray(model.mesh.vertices) @ T0[:3, :3].T + T0[:3, 3]
    lo, hi = planner.cell.sink_interior
    bvh = planner.world.bvh(model)
    req = coal.CollisionRequest()
    touching = set()
    for k, o in enumerate(others):
        if coal.collide(bvh, _tf(T0), planner.world.bvh(planner.inventory[o.obj_id]), _tf(o.T_base_obj), req,
                        coal.CollisionResult()):
            touching.add(k)
        elif planner._lies_on(target, o):
            # further down the stack the item rests on (the plate under the one under it): the item climbs over
            # it as it slides (the path follows its resting height), which this level shift does not model
            touching.add(k)
    # A slide takes the item off what it rests on: it must end farther (horizontally) from the centre of each item
    # it lies on than it starts. Those items are passed over by the contact test above, so without this a slide
    # back towards the middle of the plate below passed as "free" (a second slide undid the first and left the
    # plate squarely nested again).
    under = [np.asarray(o.T_base_obj, float)[:2, 3] for o in others if planner._lies_on(target, o)]
    out = []
    for a in np.radians(np.arange(0, 360, 45)):
        d = np.array([np.cos(a), np.sin(a), 0.0])
        c1 = T0[:2, 3] + distance * d[:2]
        if any(np.linalg.norm(c1 - c) <= np.linalg.norm(T0[:2, 3] - c) for c in under):
            continue
        W = V + distance * d
        room = min(float(np.min(W[:, :2] - lo[:2])), float(np.min(hi[:2] - W[:, :2])))
        if room < 0.005:
            continue
        T1 = trans(*(distance * d)) @ T0
        hit = False
        for k, o in enumerate(others):
            if k in touching:
                continue
            dreq = coal.DistanceRequest()
            dres = coal.DistanceResult()
            dist = coal.distance(bvh, _tf(T1), planner.world.bvh(planner.inventory[o.obj_id]), _tf(o.T_base_obj),
                                 dreq, dres)
            if dist < 0.005:
                hit = True
                break
            room = min(room, dist)
        if not hit:
            out.append((d, room))
    out.sort(key=lambda x: -x[1])
    return out


def _slide_path(planner, scene, q_press, T_press, target, d, distance, support: SupportHeight,
                step: float = 0.01):
    """The slide as straight pieces every `step` metres whose heights follow the item's resting height (it
    climbs out of the one it is nested in): (trajectory, q_end, T_base_tcp_end, T_base_obj_end) or a failure.
    The item may not need to rise faster than 1:1 (the fingers would push it into its support)."""
    T_obj = np.asarray(target.T_base_obj, float)
    z0 = support.drop(T_obj)  # ~0: it rests where it is
    Q = [np.asarray(q_press, float)]
    T_end, T1 = T_press, T_obj
    prev_rise = 0.0
    n = int(np.ceil(distance / step))
    for k in range(1, n + 1):
        shift = distance * k / n * d
        T1 = trans(*shift) @ T_obj
        rise = -(support.drop(T1) - z0)
        if rise - prev_rise > distance / n:
            return CartesianPathFailed("slide: the item would have to climb too steeply", {"segment": "slide"})
        prev_rise = rise
        T1 = trans(0.0, 0.0, rise) @ T1
        T_end = trans(shift[0], shift[1], rise) @ T_press
        r = cartesian_line(planner.robot, scene, Q[-1], T_end, step=planner.settings.validity_resolution,
                           check_step=planner.settings.validity_resolution, check_start=False)
        if isinstance(r, PlanningFailure):
            r.message = f"slide: {r.message}"
            r.details.setdefault("segment", "slide")
            return r
        Q.extend(r[1:])
    traj = planner._time(np.asarray(Q), "slide", "along_path")
    if isinstance(traj, PlanningFailure):
        return traj
    return traj, Q[-1], T_end, T1


def plan_slide(planner, q_start: np.ndarray, objects: list[ObjectPose], target: ObjectPose, *,
               map_points: np.ndarray | None = None, distance: float = 0.06,
               then_pickable: bool = True) -> SlidePlan | PlanningFailure:
    """Plan sliding `target` sideways by `distance` (or 3/4, 1/2 of it where there is no room; see the module
    docstring); with `then_pickable`, only a slide after which `planner.select_grasps` finds a grasp of the moved
    item is used."""
    t0 = time.perf_counter()
    s = planner.settings
    q0 = np.asarray(q_start, float)
    model = planner.inventory[target.obj_id]
    names = [object_name(o, k) for k, o in enumerate(objects)]
    k_t = next((k for k, o in enumerate(objects) if o is target), None)
    if k_t is None:
        return CartesianPathFailed("slide: the target is not among the objects", {})
    others = [o for o in objects if o is not target]
    on_it = planner._resting_on(target, objects)
    if on_it:
        # the fingers would press on (and through) what lies on it, and a loaded item is not pushed (the
        # simulator stops the arm): the item on top goes first (the middle plate of a stack is slid after the top one)
        f = CartesianPathFailed(f"slide: the {on_it[0].cls} lies on the item", {"segment": "slide"})
        planner._report_blocking(f, target, objects, on_it)
        return f
    p = press_point(model, target.T_base_obj)
    if p is None:
        return NoIK("slide: no top surface above the item's centre", {})
    # the longest slide that has room first (most overhang afterwards), shorter ones where the sink is full
    cands = [(dist, d) for dist in (distance, 0.75 * distance, 0.5 * distance)
             for d, _room in slide_directions(planner, target, others, dist)]
    if not cands:
        return CartesianPathFailed("slide: no direction with room to slide the item", {"segment": "slide"})
    support = SupportHeight(planner, target, others)
    voxels = planner._voxels(map_points, [o for o in objects if o.obj_id in planner.inventory.models])
    base_scene = planner.scene(objects, map_points)
    base_scene.set_opening(0.0)
    # the fingers press on the item, towards what it rests on (never reaching it: the item is between; the
    # planner's fingers are 2 mm longer than the simulator's, so they may seem to); what it rests on may be the
    # cell itself (a plate lying on the sink floor whose well is one thin wall: its fingers seem to reach the floor)
    under = [f"obj:{names[k]}" for k, o in enumerate(objects) if o is not target and _touching(planner, target, o)]
    under += [f"cell:{b.name}" for b in _cell_touching(planner, target)]
    press_scene = base_scene.for_grasp(names[k_t])
    if under:
        press_scene = press_scene.allowing([(u, pad) for u in under for pad in ("pad_a", "pad_b")])
    z_tcp = p[2] + FINGERS.tip_z - PRESS_DEPTH
    timings: dict = {}
    first: PlanningFailure | None = None
    for dist, d in cands:
        T1 = trans(*(dist * d)) @ np.asarray(target.T_base_obj, float)
        if then_pickable:
            moved = [o if o is not target else _moved(o, dist * d) for o in objects]
            grasps = planner.select_grasps(q0, moved, target=moved[k_t], map_points=None, limit=1)
            if isinstance(grasps, PlanningFailure):
                first = first or CartesianPathFailed("slide: the item would still not be pickable there",
                                                     {"segment": "slide", "after": grasps.kind})
                continue
        for yaw in np.radians((0.0, 90.0, 45.0, 135.0)):
            # closed fingers pointing down; the closing axis across the slide or along it
            a = float(np.arctan2(d[1], d[0])) + yaw
            T_press = make_T(rot_z(a)[:3, :3] @ np.diag([1.0, -1.0, -1.0]), (p[0], p[1], z_tcp))
            T_pre = trans(0.0, 0.0, s.approach_distance) @ T_press
            q_pre = None
            for qb in planner.robot.ik_all(T_pre, q0):
                if base_scene.valid(qb):
                    q_pre = qb
                    break
            if q_pre is None:
                first = first or NoIK("slide: no collision-free configuration above the press point", {})
                continue
            r = planner._line(press_scene, q_pre, T_press, "press")
            if isinstance(r, PlanningFailure):
                first = first or r
                continue
            press, q_press = r
            held = Held(model, inv(T_press) @ np.asarray(target.T_base_obj, float), 0.0)
            slide_scene = planner.world.scene(planner._scene_objects(others), voxels, held, opening=0.0)
            slide_scene = slide_scene.for_grasp(None)  # grasp margins: the fingers work close to the item
            # it slides on what it rests on; the fingers press through it towards those items (never reaching
            # them: the item is between), so those pairs are not checked either
            resting = [pr for pr in slide_scene.colliding_pairs(q_press) if "held" in pr]
            under = {b if a == "held" else a for a, b in resting}
            shielded = [(f, u) for f in ("pad_a", "pad_b") for u in under]
            r = _slide_path(planner, slide_scene.allowing(resting + shielded), q_press, T_press, target, d,
                            dist, support)
            if isinstance(r, PlanningFailure):
                first = first or r
                continue
            slide, q_end, T_end, T1 = r
            T_up = trans(0.0, 0.0, s.approach_distance) @ T_end
            after = [o if o is not target else _moved(o, T1[:3, 3] - np.asarray(target.T_base_obj)[:3, 3])
                     for o in objects]
            up_scene = planner.scene(after, map_points)
            up_scene.set_opening(0.0)
            r = planner._line(up_scene.for_grasp(names[k_t]), q_end, T_up, "release", check_start=False)
            if isinstance(r, PlanningFailure):
                first = first or r
                continue
            release, _ = r
            approach = planner._joint_motion(base_scene, q0, q_pre, "approach", timings)
            if isinstance(approach, PlanningFailure):
                first = first or approach
                continue
            timings["total_ms"] = (time.perf_counter() - t0) * 1e3
            return SlidePlan(target, T1, d, dist, approach, press, slide, release, timings)
    return first or CartesianPathFailed("slide: no plannable slide", {"segment": "slide"})
