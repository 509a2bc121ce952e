"""Slide an item sideways with the closed fingers pressing on it: the move that frees the top plate of a stack.

A plate nested on another one cannot be pinched: the lip of the plate below is a few millimetres under its lip,
where a finger would have to go. People (and this robot) slide the top plate a few centimetres sideways first;
then its lip overhangs the one below and a tilted lip pinch fits under it.

Plan (all in the base frame): press point = where a vertical line through the item's centre meets its top
surface; the closed gripper comes down on it pointing straight down (the Fin-Ray tips 3 mm into the surface:
their compliance gives the normal force), moves ``distance`` sideways level, and goes back up. The direction is
the first of eight (most free room first) in which the moved item stays inside the sink, touches nothing new,
and (if asked) can then be picked. The item is modelled as held during the slide; its contacts with what it
rests on are allowed for the whole slide (it slides on them), and NearItems keeps it off every item that may not
carry it (within a millimetre, which one carries it is below what a fitted pose resolves).
"""

from __future__ import annotations

import time
from dataclasses import replace

import coal
import numpy as np
import open3d as o3d

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.collision import Held, coal_transform
from kitchenbot.planning.grasps import object_name
from kitchenbot.planning.motion import cartesian_line
from kitchenbot.planning.types import CartesianPathFailed, NoIK, PlanningFailure, SlidePlan
from kitchenbot.transforms import inv, make_T, rot_z, trans
from kitchenbot.world.gripper import FINGERS

FLOOR = "cell:sink_floor"  # a slid item that slides off what it rested on comes down onto it (_slide_path)
CLIMB_START, CLIMB_SLOPE = 0.004, 0.4  # m, m/m: the most a slid item may rise over the way slid (_slide_path)
PRESS_DEPTH = 0.003  # m the finger tips go into the surface (the simulator's tips; see fakes.arm._press_drag)
NEAR_GAP = 0.001  # m: an item this near the slid one may be what carries it or not (below what a fit resolves)
NEAR_SLACK = 0.0001  # m: nearer to such an item than at the start, or up or down leaving one, by more (NearItems)
LEAVE_TOL = 0.00001  # m: a gap growing by more than this over a part of a step: that item is being left
SAME_PRESS = 0.005  # m: a press this near a stopped slide's, ...
SAME_WAY = np.radians(10.0)  # rad: ... its closing axis and direction this near that one's, is that slide again


def _moved(o: ObjectPose, shift: np.ndarray) -> ObjectPose:
    return replace(o, T_base_obj=trans(*shift) @ np.asarray(o.T_base_obj, float),
                   points=np.asarray(o.points).reshape(-1, 3) + shift)


TIPS_LEVEL = 0.001  # m: finger tips whose surfaces differ by no more than this press alike (yaw order kept)
PRESS_MAX_DEPTH = 0.005  # m the deeper tip may go into the surface (the simulator stops past 6 mm; 1 mm margin)


class TopSurface:
    """The item's top (its model at its pose) as seen straight down: heights under points and under the two
    closed finger tips of a press."""

    def __init__(self, model, T_base_obj: np.ndarray):
        self.scene = o3d.t.geometry.RaycastingScene()
        mesh = o3d.geometry.TriangleMesh(model.mesh)
        mesh.transform(np.asarray(T_base_obj, float))
        self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        self.top = float(np.asarray(mesh.vertices)[:, 2].max())

    def heights(self, xy: np.ndarray) -> np.ndarray:
        """z (base frame) of the item's top surface under each point of `xy` (N, 2); NaN where it misses."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        start = self.top + 0.05
        rays = np.column_stack([xy, np.full(len(xy), start), np.zeros((len(xy), 2)), -np.ones(len(xy))])
        t = self.scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
        return np.where(np.isfinite(t), start - t, np.nan)


def tip_offset() -> float:
    """How far (m) each closed finger's tip (the middle of its end face) is from the TCP along the closing axis."""
    return FINGERS.finger_thickness / 2


def closing_axis(a: float) -> np.ndarray:
    """The closing axis (level, unit, base frame) of the press pose at yaw `a` (plan_slide's T_press)."""
    return (rot_z(a)[:3, :3] @ np.diag([1.0, -1.0, -1.0]))[:3, 1]


def press_yaws(surface: TopSurface, p: np.ndarray, yaws: list[float]) -> list[tuple[float, float]]:
    """(yaw, z_tcp) of the closed fingers pressing at `p` (base frame) for each usable yaw in `yaws` and the yaw
    whose closing axis lies along the top's level line at `p` (where it slopes), the most level tips first: the
    TCP's height is set from the HIGHER of the two surfaces under the tips (that tip presses PRESS_DEPTH, or as deep
    as puts the other tip on its surface), and a yaw whose deeper tip would then go more than PRESS_MAX_DEPTH in is
    dropped. Before, the height came from the one surface point under the TCP: on a plate leaning 35 degrees, a
    closing axis along its slope put one tip 7 mm into it and the simulated arm stopped. A tip whose line misses
    the item presses nothing (the other one sets the height). The fingers' inner edges meet over `p`: never
    pressed deeper than PRESS_DEPTH there either (a top rounded over, higher there than under both tips)."""
    h = tip_offset()
    zc = surface.heights(np.array([p[:2] + h * np.array(v) for v in ((1, 0), (-1, 0), (0, 1), (0, -1))]))
    yaws = list(yaws)
    if np.all(np.isfinite(zc)):
        grad = np.array([zc[0] - zc[1], zc[2] - zc[3]]) / (2 * h)
        if 2 * h * np.linalg.norm(grad) > TIPS_LEVEL:  # it slopes: the closing axis along its level line first
            yaws.append(float(np.arctan2(grad[1], grad[0])))  # closing_axis(a) = (sin a, -cos a) _|_ grad
    out = []
    for a in yaws:
        ax = closing_axis(a)[:2]
        z = surface.heights(np.array([p[:2] + h * ax, p[:2] - h * ax]))
        z = z[np.isfinite(z)]
        if len(z) == 0:
            z = np.array([p[2]])
        rise = float(z.max() - z.min())  # how much higher the surface is under one tip than under the other
        depth = max(PRESS_DEPTH, rise)  # the deeper tip's: the other one on its surface or PRESS_DEPTH - rise in
        if depth > PRESS_MAX_DEPTH:
            continue
        # never lower than the point between the fingers allows (a top rounded over, higher there than under both)
        z_tcp = max(float(z.max()) + FINGERS.tip_z - depth, float(p[2]) + FINGERS.tip_z - PRESS_DEPTH)
        out.append((rise if rise > TIPS_LEVEL else 0.0, a, z_tcp))
    out.sort(key=lambda x: x[0])  # stable: level tips keep the given order
    return [(a, z) for _, a, z in out]


def repeats(T_base_press: np.ndarray, direction: np.ndarray, stopped) -> bool:
    """Whether pressing at `T_base_press` (the TCP) and sliding along `direction` repeats one of the `stopped`
    slides ((T_base_press, direction) pairs): its press point within SAME_PRESS, its closing axis (either way) and
    its direction within SAME_WAY."""
    for T, d in stopped:
        T = np.asarray(T, float)
        if (np.linalg.norm(T[:3, 3] - T_base_press[:3, 3]) <= SAME_PRESS
                and abs(float(T[:3, 1] @ T_base_press[:3, 1])) >= np.cos(SAME_WAY)
                and float(np.asarray(d, float) @ direction) >= np.cos(SAME_WAY)):
            return True
    return False


def press_point(model, T_base_obj: np.ndarray) -> np.ndarray | None:
    """Top surface point (base frame) on the vertical line through the item's centre, or None if it misses."""
    pts = press_points(model, T_base_obj)  # the centre's point first, [] when its line misses
    return pts[0] if pts else None


PRESS_SHIFTS = (0.02, 0.035)  # m off the centre, along the item's level axes, where the fingers may press too
PRESS_LEVEL = 0.008  # m: such a point is on the item's top, at most this far below the centre's
PRESS_FARTHER, PRESS_EXTRA = 0.01, 2  # m farther from the walls than the centre, and how many such points at most
LEANING = np.radians((15.0, 75.0))  # rad: an item whose axis is tilted this much leans (a plate against a wall)


def press_points(model, T_base_obj: np.ndarray, sink_lo_hi=None) -> list[np.ndarray]:
    """Top surface points (base frame) to press on: where the vertical line through the item's centre meets it,
    then (for a lying cup whose centre is too near a wall for the palm above it) points PRESS_SHIFTS along each of
    its axes that lies about level, on its top as high as the centre's (within PRESS_LEVEL), and (for a leaning
    item, tilted within LEANING) points PRESS_SHIFTS down its slope, lower than the centre: above its centre the
    palm meets what leans on the wall behind it (the plate it leans on); with `sink_lo_hi`,
    only those PRESS_FARTHER or more farther from the basin's walls than the centre, farthest first, at most
    PRESS_EXTRA. [] when the centre's line misses the item."""
    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.geometry.TriangleMesh(model.mesh)
    T = np.asarray(T_base_obj, float)
    mesh.transform(T)
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    c = T[:3, 3]
    xy = [c[:2]]
    for k in range(3):
        a = T[:3, k].copy()
        a[2] = 0.0
        if np.linalg.norm(a) < 0.7:  # not level enough: off the centre, the top drops away along it
            continue
        a /= np.linalg.norm(a)
        xy += [c[:2] + sgn * r * a[:2] for r in PRESS_SHIFTS for sgn in (1.0, -1.0)]
    n_up = T[:3, 2] if T[2, 2] >= 0.0 else -T[:3, 2]
    down = np.array([n_up[0], n_up[1]])  # level, down the slope of its top
    leaning = LEANING[0] <= np.arccos(np.clip(n_up[2], -1.0, 1.0)) <= LEANING[1]
    if leaning:
        xy += [c[:2] + r * down / np.linalg.norm(down) for r in PRESS_SHIFTS]
    n_slope = len(PRESS_SHIFTS) if leaning else 0
    rays = np.array([[x, y, c[2] + 0.3, 0.0, 0.0, -1.0] for x, y in xy], np.float32)
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    if not np.isfinite(t[0]):
        return []
    hits = [(k >= len(xy) - n_slope, np.array([x, y, c[2] + 0.3 - ti]))
            for k, ((x, y), ti) in enumerate(zip(xy, t)) if np.isfinite(ti)]
    out = [hits[0][1]]
    rest = [p for slope, p in hits[1:] if slope or p[2] >= out[0][2] - PRESS_LEVEL]
    if sink_lo_hi is None:
        return out + rest

    def room(p):
        return float(np.min(_wall_rooms(p[None, :], *sink_lo_hi)))
    # only points that take the palm farther from the walls than the centre does (by PRESS_FARTHER or more)
    rest = sorted((p for p in rest if room(p) >= room(out[0]) + PRESS_FARTHER), key=lambda p: -room(p))
    return out + rest[:PRESS_EXTRA]


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
    d = coal.distance(planner.world.bvh(planner.inventory[a.obj_id]), coal_transform(a.T_base_obj),
                      planner.world.bvh(planner.inventory[b.obj_id]), coal_transform(b.T_base_obj),
                      coal.DistanceRequest(), coal.DistanceResult())
    return d < gap


def _cell_touching(planner, a: ObjectPose, gap: float = 0.003) -> list:
    """The cell's boxes (the sink floor, a basin wall) within `gap` of item `a`."""
    if a.obj_id not in planner.inventory.models:
        return []
    bvh, T = planner.world.bvh(planner.inventory[a.obj_id]), coal_transform(a.T_base_obj)
    out = []
    for b in planner.cell.boxes:
        d = coal.distance(bvh, T, coal.Box(*np.asarray(b.size, float)), coal_transform(make_T(t=b.centre)),
                          coal.DistanceRequest(), coal.DistanceResult())
        if d < gap:
            out.append(b)
    return out


WALL_ROOM = 0.005  # m a slid item keeps from the basin's walls ...
ALONG_WALL_TOL = 0.0005  # ... or, from a wall it is already nearer than that, at least what it kept at the start


def _wall_rooms(V: np.ndarray, lo, hi) -> np.ndarray:
    """Room (m) between the points V (N, 3) and each of the basin's four walls (-x, -y, +x, +y)."""
    return np.concatenate([np.min(V[:, :2], axis=0) - np.asarray(lo, float)[:2],
                           np.asarray(hi, float)[:2] - np.max(V[:, :2], axis=0)])


NESTED_AXES = np.radians(30.0)  # rad: an item lying on another with axes this close lies nested on it


def _nested(T_base_a: np.ndarray, T_base_b: np.ndarray) -> bool:
    """Whether the items at these poses are the same way up, their axes within NESTED_AXES (a stack's plates)."""
    return float(T_base_a[:3, 2] @ T_base_b[:3, 2]) >= np.cos(NESTED_AXES)


def _leaning(T_base_obj: np.ndarray) -> bool:
    """Whether the item's axis is tilted within LEANING (either way up)."""
    return bool(LEANING[0] <= np.arccos(min(abs(float(T_base_obj[2, 2])), 1.0)) <= LEANING[1])


def slide_directions(planner, target: ObjectPose, others: list, distance: float) -> list[tuple[np.ndarray, float]]:
    """(unit direction, clearance) of each of 8 horizontal directions the item can slide `distance` along:
    it stays inside the sink (WALL_ROOM from each wall; from a wall it already lies nearer than that, no nearer than
    it starts: a slide along that wall, the only way out for an item wedged between the wall and a neighbour),
    touches nothing it does not already touch and ends farther from the centre of each item it lies on (a leaning
    item: each it lies nested on). Most room first."""
    model = planner.inventory[target.obj_id]
    T0 = np.asarray(target.T_base_obj, float)
    V = np.asarray(model.mesh.vertices) @ T0[:3, :3].T + T0[:3, 3]
    lo, hi = planner.cell.sink_interior
    bvh = planner.world.bvh(model)
    req = coal.CollisionRequest()
    touching = set()
    for k, o in enumerate(others):
        if coal.collide(bvh, coal_transform(T0), planner.world.bvh(planner.inventory[o.obj_id]),
                        coal_transform(o.T_base_obj), req, coal.CollisionResult()):
            touching.add(k)
        elif planner._lies_on(target, o):
            # further down the stack the item rests on (the plate under the one under it): the item climbs over
            # it as it slides (the path follows its resting height), which this level shift does not model
            touching.add(k)
    # A slide takes the item off what it rests on: it must end farther (horizontally) from the centre of each item
    # it lies on than it starts. Those items are passed over by the contact test above, so without this a slide
    # back towards the middle of the plate below passed as "free" (a second slide undid the first and left the
    # plate squarely nested again).
    # A LEANING item (tilted within LEANING) keeps this only for the items it lies NESTED on (the same way up, axes
    # within NESTED_AXES): a plate leaning on the rim of a flat one is not nested on it, and the slide that frees it
    # (along its lean, level) may pass nearer that one's centre (before, such a plate had no direction left: every
    # way out went nearer the centre of one item or another it touched). Every other item keeps it for all it lies
    # on: a cup lying across a plate's rim slid towards that plate's centre climbs its rim.
    under = [np.asarray(o.T_base_obj, float)[:2, 3] for o in others
             if planner._lies_on(target, o) and not (_leaning(T0) and not _nested(T0, np.asarray(o.T_base_obj, float)))]
    sides0 = _wall_rooms(V, lo, hi)
    out = []
    for a in np.radians(np.arange(0, 360, 45)):
        d = np.array([np.cos(a), np.sin(a), 0.0])
        c1 = T0[:2, 3] + distance * d[:2]
        if any(np.linalg.norm(c1 - c) <= np.linalg.norm(T0[:2, 3] - c) for c in under):
            continue
        W = V + distance * d
        sides = _wall_rooms(W, lo, hi)
        if np.any((sides < WALL_ROOM) & (sides < sides0 - ALONG_WALL_TOL)):
            continue
        room = float(np.min(sides))
        T1 = trans(*(distance * d)) @ T0
        hit = False
        for k, o in enumerate(others):
            if k in touching:
                continue
            dreq = coal.DistanceRequest()
            dres = coal.DistanceResult()
            dist = coal.distance(bvh, coal_transform(T1), planner.world.bvh(planner.inventory[o.obj_id]),
                                 coal_transform(o.T_base_obj), dreq, dres)
            if dist < 0.005:
                hit = True
                break
            room = min(room, dist)
        if not hit:
            out.append((d, room))
    out.sort(key=lambda x: -x[1])
    return out


class NearItems:
    """The slid item's gaps (coal, exact meshes) to the other items, to keep the slide off every item that may
    not carry it. Pressed from above, the item rides on what it touches at the start; a new contact on the way is
    a collision (the simulated arm stops on it, as a real one pushing into a neighbour would). Which of two items
    a few tenths of a millimetre apart carries it is below what the fitted poses resolve (a lying mug on a plate
    0.4 mm from a bowl's flank; on a bowl 45 micrometres above a plate), so a step of the slide is safe only if it
    is safe whichever of the items within NEAR_GAP at the start carries the item:
    - it comes within NEAR_GAP of no item it started farther from, and nearer to none it started near;
    - while it leaves one of them and the path follows another one's surface (the planner's meshes touch there,
      so its gap reads 0 and how the true one changes is not measured), its height changes by at most NEAR_SLACK
      in all: a drop would set it down on that one if it truly hovers over it (a slide off a bowl onto a plate 45
      micrometres below), a rise would push it into that one's flank if the other one carries it. Leaving them all
      (every gap grows), riding on all of them, or following one once clear of the others is safe.
    A direction that fails is not refused outright: plan_slide tries the next (the candidates go round the item),
    so the slide goes the way that takes the item away from the neighbours that may not carry it; it is refused
    only where no direction is safe."""

    def __init__(self, planner, target: ObjectPose, others: list[ObjectPose]):
        self.bvh = planner.world.bvh(planner.inventory[target.obj_id])
        self.others = [(planner.world.bvh(planner.inventory[o.obj_id]), coal_transform(o.T_base_obj)) for o in others
                       if o.obj_id in planner.inventory.models]
        self.start = self.gaps(target.T_base_obj)
        self.reset()

    def gaps(self, T_base_obj: np.ndarray) -> np.ndarray:
        T = coal_transform(np.asarray(T_base_obj, float))
        return np.array([max(0.0, coal.distance(self.bvh, T, b, To, coal.DistanceRequest(), coal.DistanceResult()))
                         for b, To in self.others])

    def reset(self) -> None:
        """A new slide path starts (from the item's start pose)."""
        self.moved_while_ambiguous = 0.0

    def unsafe(self, T_prev: np.ndarray, T_next: np.ndarray, parts: int = 5) -> str:
        """Why the step from T_prev to T_next (the item's poses, moved by a translation; checked at `parts` points
        along it) is not safe ("" when it is). Height changes while it leaves one start-near item and touches
        another add up over the path (at most NEAR_SLACK in all)."""
        near0 = self.start < NEAR_GAP
        dz = float(T_next[2, 3] - T_prev[2, 3]) / parts
        g0 = self.gaps(T_prev)
        for i in range(1, parts + 1):
            T = np.array(T_prev, float)
            T[:3, 3] += (np.asarray(T_next, float)[:3, 3] - T[:3, 3]) * i / parts
            g = self.gaps(T)
            if np.any((g < NEAR_GAP) & ~near0):
                return "slide: the item would come onto an item it does not start on"
            if np.any(near0 & (g < self.start - NEAR_SLACK)):
                return "slide: the item would come nearer to an item that may not carry it"
            amb = near0 & (np.minimum(g0, g) < NEAR_GAP)
            # it leaves one of them while the path follows another one's surface (touching it at both ends of the
            # part: how the true gap to that one changes is below what the gaps measure)
            if np.any(amb & (g > g0 + LEAVE_TOL)) and np.any(amb & (g0 <= 0.0) & (g <= 0.0)):
                self.moved_while_ambiguous += abs(dz)
                if self.moved_while_ambiguous > NEAR_SLACK:
                    return "slide: the item would go up or down while two items may carry it"
            g0 = g
        return ""


def _slide_path(planner, scene, q_press, T_press, target, d, distance, support: SupportHeight,
                step: float = 0.01, near: NearItems | None = None):
    """The slide as straight pieces every `step` metres whose heights follow the item's resting height (it
    climbs out of the one it is nested in): (trajectory, q_end, T_base_tcp_end, T_base_obj_end) or a failure.
    The item may not need to rise faster than 1:1 over a step (the fingers would push it into its support), nor
    more than CLIMB_START + CLIMB_SLOPE x the way slid so far (pressed from above, it is pushed along, not up
    over a neighbour: the friction of the pads on it does not lift it over a steep rise). The same holds going down:
    where it would drop away faster (off what it rested on) the pressing fingers lose it. It may come down onto
    the basin's floor (it rests there, at its resting height, and slides on along it: that contact is not
    checked)."""
    T_obj = np.asarray(target.T_base_obj, float)
    z0 = support.drop(T_obj)  # ~0: it rests where it is
    Q = [np.asarray(q_press, float)]
    T_end, T1 = T_press, T_obj
    prev_rise = 0.0
    T1_prev = T_obj
    if near is not None:
        near.reset()
    n = int(np.ceil(distance / step))
    for k in range(1, n + 1):
        shift = distance * k / n * d
        T1 = trans(*shift) @ T_obj
        rise = -(support.drop(T1) - z0)
        if rise - prev_rise > distance / n or rise > CLIMB_START + CLIMB_SLOPE * distance * k / n:
            return CartesianPathFailed("slide: the item would have to climb too steeply", {"segment": "slide"})
        if rise < -(CLIMB_START + CLIMB_SLOPE * distance * k / n):
            return CartesianPathFailed("slide: the item would fall off the fingers", {"segment": "slide"})
        prev_rise = rise
        T_prev, T1 = T1_prev, trans(0.0, 0.0, rise) @ T1
        T1_prev = T1
        why = near.unsafe(T_prev, T1) if near is not None else ""
        if why:
            return CartesianPathFailed(why, {"segment": "slide"})
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


def _leaning_over(planner, target: ObjectPose, others: list[ObjectPose]) -> list[ObjectPose]:
    """The leaning items (tilted within LEANING) touching `target` (within NEAR_GAP) whose base stands higher."""
    z = float(np.asarray(target.T_base_obj, float)[2, 3])
    out = []
    for o in others:
        T = np.asarray(o.T_base_obj, float)
        if o.obj_id not in planner.inventory.models or T[2, 3] <= z:
            continue
        if not _leaning(T):
            continue
        if _gap(planner, target, o) <= NEAR_GAP:
            out.append(o)
    return out


def _gap(planner, a: ObjectPose, b: ObjectPose) -> float:
    return float(coal.distance(planner.world.bvh(planner.inventory[a.obj_id]), coal_transform(a.T_base_obj),
                               planner.world.bvh(planner.inventory[b.obj_id]), coal_transform(b.T_base_obj),
                               coal.DistanceRequest(), coal.DistanceResult()))


def plan_slide(planner, q_start: np.ndarray, objects: list[ObjectPose], target: ObjectPose, *,
               map_points: np.ndarray | None = None, distance: float = 0.06,
               then_pickable: bool = True, off=(), avoid=()) -> SlidePlan | PlanningFailure:
    """Plan sliding `target` sideways by `distance` (or 3/4, 1/2 of it where there is no room; see the module
    docstring); with `then_pickable`, only a slide after which `planner.select_grasps` finds a grasp of the moved
    item is used; with `off` (perceived items), only one after which the item no longer lies on any of them;
    `avoid`: slides of it that stopped ((T_base_press, direction) pairs), not planned again (`repeats`): the same
    belief plans the same slide, and the arm stops the same way."""
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
    leaned = _leaning_over(planner, target, others)
    if leaned:
        # two leaning items that touch: which one carries the other is not resolved by their fitted poses (the
        # higher one may rest on this one), and a loaded item is not pushed
        f = CartesianPathFailed(f"slide: the {leaned[0].cls} leaning on it may rest on it", {"segment": "slide"})
        planner._report_blocking(f, target, objects, leaned)
        return f
    presses = press_points(model, target.T_base_obj, planner.cell.sink_interior)
    surface = TopSurface(model, target.T_base_obj)
    if not presses:
        return NoIK("slide: no top surface above the item's centre", {})
    # the longest slide that has room first (most overhang afterwards), shorter ones where the sink is full
    cands = [(dist, d) for dist in (distance, 0.75 * distance, 0.5 * distance)
             for d, _room in slide_directions(planner, target, others, dist)]
    if not cands:
        return CartesianPathFailed("slide: no direction with room to slide the item", {"segment": "slide"})
    support = SupportHeight(planner, target, others)
    near = NearItems(planner, target, others)
    voxels = planner._voxels(map_points, [o for o in objects if o.obj_id in planner.inventory.models])
    base_scene = planner.scene(objects, map_points)
    base_scene.set_opening(0.0)
    # the fingers press on the item, towards what it rests on (never reaching it: the item is between; the
    # planner's fingers are 2 mm longer than the simulator's, so they may seem to); what it rests on may be the
    # cell itself (a plate lying on the sink floor whose well is one thin wall: its fingers seem to reach the floor)
    touching = [(f"obj:{names[k]}", o) for k, o in enumerate(objects) if o is not target and _touching(planner, target, o)]
    under = [u for u, _ in touching]
    # those it lies on (not beside it) are its supports for the slide too (below), whatever gap within _touching's
    # their fitted poses leave: it cannot float (a plate nested in a plate seen in a small part, fitted 2 mm low)
    supports = [u for u, o in touching if planner._lies_on(target, o)]
    under += [f"cell:{b.name}" for b in _cell_touching(planner, target)]
    press_scene = base_scene.for_grasp(names[k_t])
    if under:
        press_scene = press_scene.allowing([(u, pad) for u in under for pad in ("pad_a", "pad_b")])
    timings: dict = {}
    first: PlanningFailure | None = None
    pickable: dict = {}  # candidate index -> whether the moved item can be picked there
    # the centre first; where the palm above it cannot come down (a wall beside it), points farther from the walls
    for p, (ci, (dist, d)) in ((p, c) for p in presses for c in enumerate(cands)):
        if off:
            if ("off", ci) not in pickable:
                moved = _moved(target, dist * d)
                pickable["off", ci] = not any(planner._lies_on(moved, o) for o in off)
                if not pickable["off", ci]:
                    first = first or CartesianPathFailed("slide: the item would still lie on the one below",
                                                         {"segment": "slide"})
            if not pickable["off", ci]:
                continue
        if then_pickable:
            if ci not in pickable:
                moved = [o if o is not target else _moved(o, dist * d) for o in objects]
                grasps = planner.select_grasps(q0, moved, target=moved[k_t], map_points=None, limit=1)
                pickable[ci] = not isinstance(grasps, PlanningFailure)
                if not pickable[ci]:
                    first = first or CartesianPathFailed("slide: the item would still not be pickable there",
                                                         {"segment": "slide", "after": grasps.kind})
            if not pickable[ci]:
                continue
        # closed fingers pointing down; the closing axis across the slide or along it, or along the top's level line
        a_d = float(np.arctan2(d[1], d[0]))
        yaws = press_yaws(surface, p, [a_d + yaw for yaw in np.radians((0.0, 90.0, 45.0, 135.0))])
        if not yaws:
            first = first or NoIK("slide: at every yaw a finger tip would go too deep into the item's top", {})
        for a, z_tcp in yaws:
            T_press = make_T(rot_z(a)[:3, :3] @ np.diag([1.0, -1.0, -1.0]), (p[0], p[1], z_tcp))
            if repeats(T_press, d, avoid):
                first = first or CartesianPathFailed("slide: only slides that stopped before", {"segment": "slide"})
                continue
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
            # ... and what it lies on (`supports`, within _touching's gap: the press took them as what it rests on):
            # pressed onto them, it rides on them, whatever gap the two fitted poses leave
            resting += [("held", u) for u in supports if not any(u in pr for pr in resting)]
            under = {b if a == "held" else a for a, b in resting}
            shielded = [(f, u) for f in ("pad_a", "pad_b") for u in under]
            r = _slide_path(planner, slide_scene.allowing(resting + shielded + [("held", FLOOR)]), q_press, T_press,
                            target, d, dist, support, near=near)
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
            return SlidePlan(target, T1, d, dist, approach, press, slide, release, timings, T_base_press=T_press)
    return first or CartesianPathFailed("slide: no plannable slide", {"segment": "slide"})
