"""The collision world (coal through Pinocchio's GeometryModel): arm capsules, gripper, camera, cell boxes,
perceived objects as CAD meshes, unexplained map points as an occupancy octree, the held object.

Built in two layers: :class:`CollisionWorld` holds what never changes (robot links, tool, cell boxes, cached
mesh BVHs per object model); :meth:`CollisionWorld.scene` adds one planning query's dynamic geometry and returns
a :class:`Scene` with its own GeometryData, collision pairs and per-pair security margins.

Margins: every pair is checked with ``margin`` (conservative, 1 cm by default: the simulator's FakeArm stops on
contact with its own geometry, a real cell has calibration error), except the gripper near the grasp: a scene
variant made with :meth:`Scene.for_grasp` checks the gripper (the camera only against the cell and the arm: it
keeps ``margin`` from items and voxels) with ``grasp_margin`` and lets the finger pads touch
the grasped object (the allowed-contact set of that query) while the TCP is within ``pad_contact_radius`` (2.5 cm)
of that object's surface, i.e. while closing around it; farther out a pad touching it would push or hit it (the
simulator, fakes/collision.py, allows finger contacts within 3 cm: the planner stays the more conservative).

Geometry of the UR links (in Pinocchio joint frames = DH frame i-1 turned by q_i): the real links are offset
from the DH plane along the shoulder/elbow axes (UR5e: upper arm ~0.138 m, forearm ~0.138-0.131 m; scaled by d4
for the other models); radii cover the motor housings, not the thinner tubes, so the capsules are conservative.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
import hashlib

import coal
import numpy as np
import pinocchio as pin

from kitchenbot.planning.robot import RobotModel
from kitchenbot.transforms import inv, make_T
from kitchenbot.world.cell import Box, Cell
from kitchenbot.world.gripper import MAX_OPENING, PAD_ENVELOPE
from kitchenbot.world.inventory import ObjectModel

# ---- shapes ------------------------------------------------------------------------------------------------


def coal_transform(T: np.ndarray) -> coal.Transform3s:
    """A 4x4 pose as coal's transform (a copy)."""
    T = np.asarray(T, float)
    return coal.Transform3s(T[:3, :3].copy(), T[:3, 3].copy())


@dataclass(frozen=True)
class Capsule:
    name: str
    joint: int  # 1..6 (0 = base/universe)
    a: tuple[float, float, float]  # segment ends in the joint frame
    b: tuple[float, float, float]
    radius: float


@dataclass(frozen=True)
class ToolBox:
    """A box fixed to the flange (joint 6) frame: pose T_flange_box, full extents `size`."""

    name: str
    T_flange_box: np.ndarray
    size: tuple[float, float, float]


def link_capsules(robot: RobotModel) -> list[Capsule]:
    """Capsules covering the UR links, in joint frames (see module docstring)."""
    ur = robot.ur
    d1, a2, a3, d4, d5, d6 = ur.d[0], ur.a[1], ur.a[2], ur.d[3], ur.d[4], ur.d[5]
    s = d4 / 0.1333  # scale the UR5e offsets to the other models
    sh = 0.138 * s  # upper-arm axis offset along the shoulder axis
    fo = (0.138 - 0.131) * s  # forearm axis offset
    r = ur.link_radius
    r_sh = max(r[1], 0.065 * s)
    return [
        # shoulder: column from just above the counter to the shoulder axis (rotates with q1 about z)
        Capsule("link1", 1, (0.0, 0.0, r_sh + 0.005), (0.0, 0.0, d1), r_sh),
        # shoulder housing along the shoulder-lift axis, then the upper arm tube at its offset
        Capsule("link2_housing", 2, (0.0, 0.0, -0.03 * s), (0.0, 0.0, sh), r_sh),
        Capsule("link2", 2, (0.0, 0.0, sh), (a2, 0.0, sh), max(r[1], 0.06 * s)),
        # elbow housing (from the upper arm's offset back to the forearm's) and the forearm
        Capsule("link3_housing", 3, (0.0, 0.0, fo), (0.0, 0.0, sh), max(r[2], 0.055 * s)),
        # forearm: real tube ~0.04 m radius at offset fo; widened to also cover drivers.ur_kinematics'
        # link_segments model (offset 0.3*d4, the simulator's) so the planner is never less conservative; it
        # stops short of the wrist-1 housing, which link4 covers
        Capsule("link3", 3, (0.0, 0.0, 0.027 * s), (a3 + 0.045 * s, 0.0, 0.027 * s), max(r[2], 0.062 * s)),
        # wrist 1 housing: from the forearm end towards the wrist-2 axis (the wrist-2 capsule covers the rest)
        Capsule("link4", 4, (0.0, 0.0, fo - 0.02), (0.0, 0.0, d4 - 0.045 * s), max(r[3], 0.047 * s)),
        # wrist 2: along its axis to the wrist-3 axis (d5)
        Capsule("link5", 5, (0.0, 0.0, -0.045 * s), (0.0, 0.0, d5), max(r[4], 0.047 * s)),
        # wrist 3: to the flange (d6)
        Capsule("link6", 6, (0.0, 0.0, -0.045 * s), (0.0, 0.0, d6 - 0.01), max(r[5], 0.047 * s)),
    ]


@dataclass(frozen=True)
class GripperGeometry:
    """The Fin-Ray gripper in the TCP frame (z = approach, y = closing axis), metres.

    Palm/body from the flange to the pad roots; two fingers whose inner faces (pads) are at +-opening/2 and
    whose tips end ``pad_tip`` past the TCP: the pad envelope of world.gripper (2 mm past the physical tips).
    """

    palm_size_xy: tuple[float, float] = (0.075, 0.14)
    pad_root: float = PAD_ENVELOPE.root  # z of the pad roots (= palm bottom) in the TCP frame
    pad_tip: float = PAD_ENVELOPE.tip
    pad_width: float = PAD_ENVELOPE.width  # along x
    pad_thickness: float = PAD_ENVELOPE.thickness  # along y
    camera_size: tuple[float, float, float] = (0.11, 0.035, 0.04)  # OAK-D-like housing, cam frame x, y, z

    def palm(self, T_flange_tcp: np.ndarray) -> ToolBox:
        z_flange = float((inv(T_flange_tcp) @ np.array([0, 0, 0, 1.0]))[2])  # flange origin in TCP z
        lo, hi = min(z_flange, self.pad_root), self.pad_root
        T = T_flange_tcp @ make_T(t=(0.0, 0.0, (lo + hi) / 2))
        return ToolBox("palm", T, (self.palm_size_xy[0], self.palm_size_xy[1], max(hi - lo, 1e-3)))

    def pads(self, T_flange_tcp: np.ndarray, opening: float) -> list[ToolBox]:
        o = float(np.clip(opening, 0.0, MAX_OPENING))
        zc = (self.pad_root + self.pad_tip) / 2
        size = (self.pad_width, self.pad_thickness, self.pad_tip - self.pad_root)
        out = []
        for name, sgn in (("pad_a", 1.0), ("pad_b", -1.0)):
            T = T_flange_tcp @ make_T(t=(0.0, sgn * (o / 2 + self.pad_thickness / 2), zc))
            out.append(ToolBox(name, T, size))
        return out

    def camera(self, T_flange_cam: np.ndarray) -> ToolBox:
        T = T_flange_cam @ make_T(t=(0.0, 0.0, -self.camera_size[2] / 2))  # housing behind the optical centre
        return ToolBox("camera", T, self.camera_size)

    def tool_boxes(self, T_flange_tcp: np.ndarray, T_flange_cam: np.ndarray | None, opening: float) -> list[ToolBox]:
        boxes = [self.palm(T_flange_tcp), *self.pads(T_flange_tcp, opening)]
        if T_flange_cam is not None:
            boxes.append(self.camera(T_flange_cam))
        return boxes


def capsule_geometry(c: Capsule) -> tuple[coal.Capsule, np.ndarray]:
    """coal capsule (axis z, half length) and its placement in the joint frame."""
    a, b = np.asarray(c.a, float), np.asarray(c.b, float)
    L = float(np.linalg.norm(b - a))
    z = (b - a) / L if L > 1e-9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(z, [1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=1)
    return coal.Capsule(c.radius, max(L, 1e-6)), make_T(R, (a + b) / 2)


def mesh_bvh(vertices: np.ndarray, triangles: np.ndarray) -> coal.BVHModelOBBRSS:
    bvh = coal.BVHModelOBBRSS()
    bvh.beginModel(len(triangles), len(vertices))
    bvh.addVertices(np.asarray(vertices, float))
    bvh.addTriangles(np.asarray(triangles, np.int64))
    bvh.endModel()
    return bvh



_MODEL_BVH: dict[int, tuple] = {}  # id(mesh) -> (mesh, BVH): every collision world and planning.resting share them


def model_bvh(model: ObjectModel) -> coal.BVHModelOBBRSS:
    """The model's mesh as a coal BVH, built once per mesh."""
    key = id(model.mesh)
    hit = _MODEL_BVH.get(key)
    if hit is None or hit[0] is not model.mesh:  # the entry keeps the mesh alive: its id stays unique
        hit = _MODEL_BVH[key] = (model.mesh, mesh_bvh(np.asarray(model.mesh.vertices), np.asarray(model.mesh.triangles)))
    return hit[1]

def tcp_positions(robot: RobotModel, Q: np.ndarray) -> np.ndarray:
    """TCP positions (N, 3) for joint rows Q (N, 6): the DH chain, vectorised over the rows."""
    ur = robot.ur
    n = len(Q)
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for i in range(6):
        th = Q[:, i]
        ct, st = np.cos(th), np.sin(th)
        ca, sa = np.cos(ur.alpha[i]), np.sin(ur.alpha[i])
        A = np.zeros((n, 4, 4))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st * ca, st * sa, ur.a[i] * ct
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st, ct * ca, -ct * sa, ur.a[i] * st
        A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa, ca, ur.d[i]
        A[:, 3, 3] = 1.0
        T = T @ A
    return (T @ robot.T_flange_tcp[:, 3])[:, :3]


# Owners of map points and distances to model surfaces (for CollisionWorld.explained) ---------------------------
_SAME_POINT = 1e-4  # m: a map point and an instance's point this close are the same measurement


def _owners(P: np.ndarray, instance_points: Sequence[np.ndarray | None], n: int) -> np.ndarray:
    """Index of the instance (among the first `n`) whose points include each of `P`, -1 for none."""
    owner = np.full(len(P), -1, np.int64)
    parts, ids = [], []
    for k in range(min(n, len(instance_points))):
        ip = instance_points[k]
        if ip is not None and len(ip):
            ip = np.asarray(ip, float).reshape(-1, 3)
            parts.append(ip)
            ids.append(np.full(len(ip), k, np.int64))
    if not parts or len(P) == 0:
        return owner
    from scipy.spatial import cKDTree

    d, j = cKDTree(np.vstack(parts)).query(P, distance_upper_bound=_SAME_POINT)
    ok = np.isfinite(d)
    owner[ok] = np.concatenate(ids)[j[ok]]
    return owner


# m from its own fitted model's surface within which the grasp target's (the held item's) observed points are its
# own: as far as a pose perception gives may be off (1.6 cm and turned 100 deg about the vertical, a lying mug:
# its real surface lies up to 3.5 cm from the fitted one); farther out they are something else the instance took in
OWN_REACH = 0.04
_SURFACES: dict[int, tuple] = {}  # id(mesh) -> (mesh, open3d RaycastingScene)
# How far from the grasp target's (the held item's) fitted surface map points are its own, from how closely its model
# fits its own points: FIT_SPREAD x the 90th percentile of their distances to it, kept within [FIT_RADIUS_MIN,
# explain radius] (and [FIT_RADIUS_MIN, OWN_REACH] for its own points), in FIT_RADIUS_STEP steps (the memo's grids
# are per radius). A model that fits its points to a couple of millimetres is not 1.5 or 4 cm off: points farther
# out are something else (a bowl nested under it, covered by it), or a part of it where its fit put none (a mug's
# handle turned about its axis); the pads and the lift must keep clear of them.
FIT_SPREAD = 3.0
FIT_RADIUS_MIN = 0.005
FIT_RADIUS_STEP = 0.001


def _surface_distance(model: ObjectModel, P_obj: np.ndarray) -> np.ndarray:
    """Distance (m) from points in the object frame to the model's mesh surface (Open3D's ray-casting scene,
    built once per mesh)."""
    import open3d as o3d

    hit = _SURFACES.get(id(model.mesh))
    if hit is None or hit[0] is not model.mesh:
        rs = o3d.t.geometry.RaycastingScene()
        rs.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(model.mesh))
        hit = _SURFACES[id(model.mesh)] = (model.mesh, rs)
    q = o3d.core.Tensor(np.asarray(P_obj, np.float32).reshape(-1, 3))
    return hit[1].compute_distance(q).numpy().astype(float)


_NEAR_CELL = 0.005  # m: cells of the grid that settles most "within r of the surface" questions without a query
# m: the grid covers the model's box grown by this much (the farthest any query asks: OWN_REACH), so one grid per
# model answers every radius (the fit radii of the grasp target and the held item vary by the millimetre); a point
# outside it is left to the exact distance
_NEAR_GRID_REACH = OWN_REACH
# m: kept off the bounds both ways, for the float32 distances (the grid's and the exact query's)
_NEAR_SLACK = 1e-5
_NEAR_GRIDS: dict[int, tuple] = {}  # id(mesh) -> (mesh, origin, cell centres' distances to the surface, NaN: not yet)


def _near_grid(model: ObjectModel) -> tuple[np.ndarray, np.ndarray]:
    """Per model, once: the object-frame grid over its box grown by _NEAR_GRID_REACH, as (origin, each cell
    centre's distance to the surface), the distances NaN until a point in the cell is first asked about
    (_near_by_grid fills them: a query touches a few thousand of its ~10^5 cells)."""
    hit = _NEAR_GRIDS.get(id(model.mesh))
    if hit is None or hit[0] is not model.mesh:
        bb = model.mesh.get_axis_aligned_bounding_box()
        lo = np.asarray(bb.get_min_bound()) - _NEAR_GRID_REACH
        shape = np.ceil((np.asarray(bb.get_max_bound()) + _NEAR_GRID_REACH - lo) / _NEAR_CELL).astype(int) + 1
        hit = _NEAR_GRIDS[id(model.mesh)] = (model.mesh, lo, np.full(tuple(shape), np.nan))
    return hit[1], hit[2]


def _near_by_grid(model: ObjectModel, P_obj: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(surely within `radius` of the model's surface, surely farther than it) for points in the object frame, by
    their grid cells (both False: not known, the exact distance decides). A point lies within its cell centre's
    distance to the surface -/+ the cell's half-diagonal; the cells' distances are computed when first needed."""
    lo, dist = _near_grid(model)
    ijk = np.floor((P_obj - lo) / _NEAR_CELL).astype(np.int64)
    ok = np.all((ijk >= 0) & (ijk < np.array(dist.shape)), axis=1)
    flat = np.ravel_multi_index(tuple(ijk[ok].T), dist.shape)
    d = np.full(len(P_obj), np.nan)
    d[ok] = dist.reshape(-1)[flat]
    todo = np.unique(flat[np.isnan(d[ok])])
    if len(todo):
        centres = lo + (np.column_stack(np.unravel_index(todo, dist.shape)) + 0.5) * _NEAR_CELL
        dist.reshape(-1)[todo] = _surface_distance(model, centres)
        d[ok] = dist.reshape(-1)[flat]
    half = np.sqrt(3) / 2 * _NEAR_CELL
    with np.errstate(invalid="ignore"):
        return d <= radius - half - _NEAR_SLACK, d > radius + half + _NEAR_SLACK


def _digest(a: np.ndarray) -> bytes:
    a = np.ascontiguousarray(a)
    return hashlib.blake2b(a.view(np.uint8).reshape(-1), digest_size=16).digest() + repr((a.dtype.str, a.shape)).encode()


class _ObjectPoints:
    """One object (model, pose) against one point set: the points in the object frame, which lie in its mesh box
    grown by a radius, and their distances to its surface, each computed once, when first asked for."""

    def __init__(self, P: np.ndarray, o: SceneObject, radius: float):
        bb = o.model.mesh.get_axis_aligned_bounding_box()
        self.model = o.model  # kept alive: the memo's key holds id(mesh)
        self.lo, self.hi = np.asarray(bb.get_min_bound()), np.asarray(bb.get_max_bound())
        self.Pl = (P - o.T_base_obj[:3, 3]) @ o.T_base_obj[:3, :3]
        self.in_box = np.all((self.Pl >= self.lo - radius) & (self.Pl <= self.hi + radius), axis=1)
        self._d = np.full(len(P), np.nan)

    def near(self, idx: np.ndarray, radius: float) -> np.ndarray:
        """Whether points `idx` (indices) lie within `radius` of the model's surface: a grid cell surely that near
        settles it (most map points lie on some surface; the exact query is the costly part), as does a cell surely
        farther out; the exact distance the rest. The same answer as the distance alone."""
        out, far = _near_by_grid(self.model, self.Pl[idx], radius)
        ask = ~(out | far)
        if ask.any():
            out[ask] = self.distance(idx[ask]) <= radius
        return out

    def distance(self, idx: np.ndarray) -> np.ndarray:
        """Distances of points `idx` (indices) to the model's surface (each point's own query: computing a point
        alone or with others gives the same number)."""
        d = self._d[idx]
        todo = idx[np.isnan(d)]
        if len(todo):
            self._d[todo] = _surface_distance(self.model, self.Pl[todo])
            d = self._d[idx]
        return d


class _PointsMemo:
    """What `CollisionWorld.explained` computes for one point set (by content) that does not depend on which
    objects explain their own points: the owners per instance-point list, per object its `_ObjectPoints`, and per
    instance (by its points' content) which of the set's points are its own (`same_points`)."""

    def __init__(self, P: np.ndarray):
        self.P = P
        self._owners: dict[tuple, np.ndarray] = {}
        self._objects: dict[tuple, _ObjectPoints] = {}
        self._same: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    def same_points(self, ip: np.ndarray, key: bytes) -> tuple[np.ndarray, np.ndarray]:
        """(indices, distances): the set's points within _SAME_POINT of one of the instance points `ip` (N, 3)
        and the distance to the nearest of them, as `_owners`' query measures it (only the points in their box,
        grown: farther in one coordinate is farther)."""
        hit = self._same.get(key)
        if hit is None:
            from scipy.spatial import cKDTree

            lo, hi = ip.min(axis=0) - 2 * _SAME_POINT, ip.max(axis=0) + 2 * _SAME_POINT
            cand = np.flatnonzero(np.all((self.P >= lo) & (self.P <= hi), axis=1))
            d = cKDTree(ip).query(self.P[cand], distance_upper_bound=_SAME_POINT)[0] if len(cand) else np.zeros(0)
            ok = np.isfinite(d)
            hit = self._same[key] = (cand[ok], d[ok])
        return hit

    def owners(self, instance_points: Sequence[np.ndarray | None], n: int) -> np.ndarray:
        """`_owners(P, instance_points, n)`, from each instance's own points (`same_points`, kept per instance: the
        asks of one pick and place differ by one or two instances, the held or the placed item). A point that two
        instances hold at the same distance (where `_owners`' one tree picks either) is left to `_owners`."""
        ips = [None if ip is None else np.asarray(ip, float).reshape(-1, 3) for ip in instance_points[:n]]
        digests = tuple(None if ip is None else _digest(ip) for ip in ips)
        key = (n, digests)
        hit = self._owners.get(key)
        if hit is None:
            owner = np.full(len(self.P), -1, np.int64)
            best = np.full(len(self.P), np.inf)
            for k, (ip, dg) in enumerate(zip(ips, digests)):
                if ip is None or not len(ip) or not len(self.P):
                    continue
                idx, d = self.same_points(ip, dg)
                if np.any(d == best[idx]):
                    owner = _owners(self.P, instance_points, n)  # a tie: the one tree's answer
                    break
                closer = d < best[idx]
                best[idx[closer]] = d[closer]
                owner[idx[closer]] = k
            hit = self._owners[key] = owner
        return hit

    def object(self, o: SceneObject, radius: float) -> _ObjectPoints:
        T = np.asarray(o.T_base_obj, float)
        key = (id(o.model.mesh), T.tobytes(), float(radius))
        hit = self._objects.get(key)
        if hit is None or hit.model.mesh is not o.model.mesh:
            hit = self._objects[key] = _ObjectPoints(self.P, o, radius)
        return hit


class _ExplainMemo:
    """Memo of `CollisionWorld.explained`'s per-object work, by the points' content (a few point sets kept: the
    map of this pick and place and its variants without one object's points); plus the instance points that lie
    near their own model per (object, points)."""

    KEEP = 6

    def __init__(self):
        self._sets: dict[bytes, _PointsMemo] = {}
        self._near: dict[tuple, tuple] = {}
        self._cell: dict[tuple, tuple] = {}

    def points(self, P: np.ndarray) -> _PointsMemo:
        key = _digest(P)
        hit = self._sets.pop(key, None)
        if hit is None:
            hit = _PointsMemo(P.copy())
            while len(self._sets) >= self.KEEP:
                self._sets.pop(next(iter(self._sets)))
        self._sets[key] = hit  # most recent last
        return hit

    def outside_cell(self, cell: Cell, points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """The finite rows of `points` and the mask of those outside every cell box grown by `radius` (the last
        few point sets kept by content: the map of one pick and place is asked about several times)."""
        P = np.asarray(points, float).reshape(-1, 3)
        key = (_digest(P), id(cell), tuple(b.lower.tobytes() + b.upper.tobytes() for b in cell.boxes), float(radius))
        hit = self._cell.get(key)
        if hit is None or hit[0] is not cell:
            P = P[np.all(np.isfinite(P), axis=1)]
            keep = np.ones(len(P), bool)
            for b in cell.boxes:
                keep &= ~np.all((P >= b.lower - radius) & (P <= b.upper + radius), axis=1)
            while len(self._cell) >= self.KEEP:
                self._cell.pop(next(iter(self._cell)))
            hit = self._cell[key] = (cell, P, keep)
        return hit[1], hit[2]

    def fit_radii(self, o: SceneObject, ip, explain_radius: float, reach: float) -> tuple[float, float]:
        """(explain radius, own reach) of an object whose observed points are `ip`: FIT_SPREAD x the 90th percentile
        of their distances to its fitted surface, within [FIT_RADIUS_MIN, `explain_radius`] and [FIT_RADIUS_MIN,
        `reach`], rounded up to FIT_RADIUS_STEP (see FIT_SPREAD)."""
        d = self._own_distances(o, ip)[1]
        spread = max(FIT_RADIUS_MIN, np.ceil(FIT_SPREAD * float(np.percentile(d, 90)) / FIT_RADIUS_STEP - 1e-9)
                     * FIT_RADIUS_STEP)
        return min(explain_radius, spread), min(reach, spread)

    def _own_distances(self, o: SceneObject, ip) -> tuple[np.ndarray, np.ndarray]:
        """(points in the object frame, distances to its model surface) of an instance's points `ip` (base frame),
        kept per (points, model, pose): the fit radii and the own points near the model at every reach read the
        same distances (each point's own query: the same number as computed alone or with others)."""
        ip = np.asarray(ip, float).reshape(-1, 3)
        T = np.asarray(o.T_base_obj, float)
        key = ("dist", _digest(ip), id(o.model.mesh), T.tobytes())
        hit = self._near.get(key)
        if hit is None or hit[0] is not o.model.mesh:
            il = (ip - T[:3, 3]) @ T[:3, :3]
            if len(self._near) > 64:
                self._near.clear()
            hit = self._near[key] = (o.model.mesh, il, _surface_distance(o.model, il) if len(il) else np.zeros(0))
        return hit[1], hit[2]

    def own_points_near(self, o: SceneObject, ip, lo: np.ndarray, hi: np.ndarray, reach: float) -> np.ndarray:
        """The instance's points `ip` (base frame) within `reach` of the object's model surface."""
        ip = np.asarray(ip, float).reshape(-1, 3)
        il, d = self._own_distances(o, ip)
        inb = np.all((il >= lo - reach) & (il <= hi + reach), axis=1)  # farther than `reach` from the surface
        return ip[inb & (d <= reach)]


_EXPLAIN_MEMO = _ExplainMemo()


# ---- the world ---------------------------------------------------------------------------------------------

ROBOT_GROUP = "robot"
TOOL_PARTS = ("palm", "pad_a", "pad_b", "camera")
PADS = ("pad_a", "pad_b")


def _tool_meets_item(a: str, b: str) -> bool:
    """A (tool part, perceived object or the map's voxels) pair."""
    return (a in TOOL_PARTS and b.startswith(("obj:", "voxels"))) or (b in TOOL_PARTS and a.startswith(("obj:", "voxels")))


def _has_pad(a: str, b: str) -> bool:
    """A pair with an open pad in it."""
    return a in PADS or b in PADS


def _camera_near_item(a: str, b: str) -> bool:
    """A (camera, item or voxels) pair: it keeps the full margin in the grasp and release scenes too."""
    return (a == "camera" and b.startswith(("obj:", "voxels"))) or (b == "camera" and a.startswith(("obj:", "voxels")))


@dataclass
class SceneObject:
    """A perceived object for the collision world: its model, pose and a name used in allowed-contact sets."""

    name: str
    model: ObjectModel
    T_base_obj: np.ndarray


@dataclass
class Held:
    """The object in the gripper: its model and its pose in the TCP frame."""

    model: ObjectModel
    T_tcp_obj: np.ndarray
    width: float  # pad distance while holding it


def _collision_pairs(layout: tuple) -> list[tuple[int, int]]:
    """The pairs a scene checks, from its layout ((group, joint index, name or None for the environment) per
    geometry). Self: links two or more joints apart; the tool and the held object vs links 1..4. The environment
    against everything on the robot side but the shoulder column and housing."""
    out = []
    n = len(layout)
    for i in range(n):
        gi, ji, ni = layout[i]
        for j in range(i + 1, n):
            gj, jj, nj = layout[j]
            if gi == "env" and gj == "env":
                continue
            if "env" in (gi, gj):
                name = ni if gi != "env" else nj
                if name == "link1" or name == "link2_housing":
                    continue  # fixed above the base on the counter; never reaches the cell geometry
                out.append((i, j))
                continue
            # both on the robot side
            if {gi, gj} <= {"tool", "held"}:
                continue
            if abs(ji - jj) < 2:
                continue
            if gi == gj == "robot" and {ji, jj} in ({3, 5}, {4, 6}):
                # structurally apart: the wrist-2 motor turns in a plane beyond the wrist-1 housing (never meets
                # the forearm); wrist 1 and wrist 3 sit side by side d5 apart at most (their capsules come
                # within the margin at q5 = 0 without touching)
                continue
            if "tool" in (gi, gj) or "held" in (gi, gj):
                other = jj if gi in ("tool", "held") else ji
                if other > 4:
                    continue
            out.append((i, j))
    return out


class CollisionWorld:
    """Static collision geometry of one cell + robot + tool; makes per-query :class:`Scene` objects."""

    def __init__(
        self,
        robot: RobotModel,
        cell: Cell,
        T_flange_cam: np.ndarray | None = None,
        *,
        margin: float = 0.01,
        grasp_margin: float = 0.002,
        pad_contact_radius: float = 0.025,
        gripper: GripperGeometry | None = None,
        voxel_size: float = 0.02,
    ):
        self.robot = robot
        self.cell = cell
        self.T_flange_cam = None if T_flange_cam is None else np.asarray(T_flange_cam, float)
        self.margin = float(margin)
        self.grasp_margin = float(grasp_margin)
        self.pad_contact_radius = float(pad_contact_radius)
        self.gripper = gripper or GripperGeometry()
        self.voxel_size = float(voxel_size)
        self.capsules = link_capsules(robot)
        # the capsules' coal geometry and placements, built once: every scene shares them (as the meshes' BVHs)
        self.capsule_geoms = [capsule_geometry(c) for c in self.capsules]
        self._pair_cache: dict[tuple, list[tuple[int, int]]] = {}  # scene layout -> its collision pairs
        self._proxy_cache: dict[int, coal.Box] = {}

    def bvh(self, model: ObjectModel) -> coal.BVHModelOBBRSS:
        return model_bvh(model)

    # ---- unexplained map points -> occupied voxels -----------------------------------------------------------
    def unexplained_voxels(
        self,
        points: np.ndarray | None,
        objects: Sequence[SceneObject],
        explain_radius: float = 0.015,
        min_points: int = 3,
        instance_points: Sequence[np.ndarray | None] = (),
        instance_reach: float = OWN_REACH,
        self_explaining: Sequence[bool] | None = None,
    ) -> np.ndarray:
        """Centres of voxels holding >= `min_points` map points that nothing explains: not a cell box, not a
        perceived object (see :meth:`explained`)."""
        if points is None or len(points) == 0:
            return np.zeros((0, 3))
        P, keep = _EXPLAIN_MEMO.outside_cell(self.cell, points, explain_radius)
        keep = keep.copy()
        keep[keep] = ~self.explained(P[keep], objects, explain_radius, instance_points, instance_reach,
                                     self_explaining)
        return self.occupied_voxels(P[keep], min_points)

    def occupied_voxels(self, points: np.ndarray | None, min_points: int = 1) -> np.ndarray:
        """Centres of the voxels holding >= `min_points` of `points` (N, 3)."""
        if points is None or len(points) == 0:
            return np.zeros((0, 3))
        P = np.asarray(points, float).reshape(-1, 3)
        idx = np.floor(P / self.voxel_size).astype(np.int64)
        uniq, counts = np.unique(idx, axis=0, return_counts=True)
        return (uniq[counts >= min_points] + 0.5) * self.voxel_size

    @staticmethod
    def explained(
        points: np.ndarray,
        objects: Sequence[SceneObject],
        explain_radius: float = 0.015,
        instance_points: Sequence[np.ndarray | None] = (),
        instance_reach: float = OWN_REACH,
        self_explaining: Sequence[bool] | None = None,
    ) -> np.ndarray:
        """Mask of the (N, 3) `points` that perceived objects explain.

        A point is explained where some object's model surface lies within `explain_radius` of it (depth noise
        and a pose a little off), not merely inside its bounding box: a hollow item's box is mostly air, and the
        points of an item nobody perceived nested in it (a bowl in a bowl) are an obstacle the lift must clear.
        A point of instance ``objects[i]`` (``instance_points[i]`` holds them) likewise: where the fitted model
        does not cover its own points, the real item is there and the model is not, so they stay obstacles. Only
        the objects marked in `self_explaining` (None: all) may explain their own points anyway, where those lie
        within `instance_reach` of the object's own fitted model surface (the grasp target and the held item, so
        a pose a little off leaves no phantom obstacle beside the item the pads close on); and points of no
        instance within `explain_radius` of such points. Own points farther from the model stay obstacles: the
        instance took in something beside it (a mug next to a bowl segmented into the bowl's instance) that no
        model stands for, and the grasp, the lift and the transport must keep clear of it.

        The per-object work (the points in the object frame, its box, distances to its surface) and the owners
        are memoised by content (:class:`_ExplainMemo`): one pick or place asks this of the same map and the
        same poses several times (the target, the held item or the staged one explaining its own points
        differ between the asks, the rest does not). The answers are those computed afresh."""
        P = np.ascontiguousarray(np.asarray(points, float).reshape(-1, 3))
        hit = np.zeros(len(P), bool)
        n = len(objects)
        own_ok = [True] * n if self_explaining is None else [bool(x) for x in self_explaining] + [True] * n
        memo = _EXPLAIN_MEMO.points(P)
        owner = memo.owners(instance_points, n)
        inst = []
        for k, o in enumerate(objects):
            ob = memo.object(o, explain_radius)
            ip = instance_points[k] if k < len(instance_points) else None
            radius, reach = explain_radius, instance_reach
            if self_explaining is not None and own_ok[k] and ip is not None and len(ip):
                # the grasp target / held item named by the query: only as far out as its fit may be off
                radius, reach = _EXPLAIN_MEMO.fit_radii(o, ip, explain_radius, instance_reach)
            # any point on (near) this model's surface; the box only bounds the search (a hollow's box is mostly
            # air: an unperceived item nested in it is there, not explained)
            cand = np.flatnonzero(ob.in_box & ~hit)
            if len(cand):
                hit[cand[ob.near(cand, radius)]] = True
            if own_ok[k]:
                # its own points near its own fitted model (within instance_reach of the surface)
                mine = np.flatnonzero((owner == k) & ~hit)
                if len(mine):
                    hit[mine[ob.near(mine, reach)]] = True
                if ip is not None and len(ip):
                    near = _EXPLAIN_MEMO.own_points_near(o, ip, ob.lo, ob.hi, reach)
                    if len(near):
                        inst.append((near, radius))
        if inst and not hit.all():
            from scipy.spatial import cKDTree

            # an instance's points near its model explain points of no instance beside them
            may = ~hit & (owner < 0)
            if may.any():
                idx = np.flatnonzero(may)
                for r in sorted({r for _, r in inst}):
                    pts = np.vstack([near for near, rr in inst if rr == r])
                    d, _ = cKDTree(pts).query(P[idx], distance_upper_bound=r)
                    hit[idx[np.isfinite(d)]] = True
        return hit

    # ---- per-query scene -------------------------------------------------------------------------------------
    def scene(
        self,
        objects: Sequence[SceneObject] = (),
        voxels: np.ndarray | None = None,
        held: Held | None = None,
        opening: float = MAX_OPENING,
        boxes: Sequence[Box] = (),
    ) -> "Scene":
        """`boxes`: extra fixed obstacles (axis-aligned, base frame) beyond the cell's."""
        return Scene(self, list(objects), voxels if voxels is not None else np.zeros((0, 3)), held, opening, list(boxes))


class Scene:
    """One query's collision model. ``valid(q)`` / ``valid_batch(Q)`` are what the planners call."""

    def __init__(self, world: CollisionWorld, objects: list[SceneObject], voxels: np.ndarray, held: Held | None,
                 opening: float, boxes: list[Box] | None = None):
        self.world = world
        self.objects = objects
        self.voxels = np.asarray(voxels, float).reshape(-1, 3)
        self.held = held
        self._shared = {"opening": float(held.width if held is not None else opening)}
        robot = world.robot
        self.model = robot.model
        self.data = robot.model.createData()
        gm = pin.GeometryModel()
        self.gm = gm
        self.group: dict[int, str] = {}  # geometry id -> robot | tool | held | env
        self.link_index: dict[int, int] = {}  # geometry id -> joint index (robot/tool)
        self.names: list[str] = []

        def add(name: str, joint: int, T: np.ndarray, geom, group: str) -> int:
            go = pin.GeometryObject(name, joint, pin.SE3(np.asarray(T, float)), geom)
            gid = gm.addGeometryObject(go)
            self.group[gid] = group
            self.link_index[gid] = joint
            self.names.append(name)
            return gid

        for c, (geom, T) in zip(world.capsules, world.capsule_geoms):
            add(c.name, c.joint, T, geom, "robot")
        T_j6_flange = robot.model.frames[robot.flange_id].placement.homogeneous  # joint-6 frame -> flange
        self._T_j6_flange = T_j6_flange
        for tb in world.gripper.tool_boxes(robot.T_flange_tcp, world.T_flange_cam, self.opening):
            add(tb.name, 6, T_j6_flange @ tb.T_flange_box, coal.Box(*tb.size), "tool")
        if held is not None:
            add("held", 6, T_j6_flange @ robot.T_flange_tcp @ held.T_tcp_obj, world.bvh(held.model), "held")
        for b in [*world.cell.boxes, *(boxes or [])]:
            add(f"cell:{b.name}", 0, make_T(t=b.centre), coal.Box(*b.size), "env")
        for o in objects:
            add(f"obj:{o.name}", 0, o.T_base_obj, world.bvh(o.model), "env")
        if len(self.voxels):
            tree = coal.makeOctree(self.voxels, world.voxel_size)
            add("voxels", 0, np.eye(4), tree, "env")

        # Pairs: they depend on the layout only (each geometry's group, joint and, off the environment, name), the
        # same for every scene with the same held item (or none) and number of obstacles: computed once per layout
        layout = tuple((self.group[i], self.link_index[i], None if self.group[i] == "env" else self.names[i])
                       for i in range(len(self.names)))
        pairs = world._pair_cache.get(layout)
        if pairs is None:
            pairs = world._pair_cache[layout] = _collision_pairs(layout)
            if len(world._pair_cache) > 256:
                world._pair_cache.clear()
                world._pair_cache[layout] = pairs
        for i, j in pairs:
            gm.addCollisionPair(pin.CollisionPair(i, j))
        self.gd = pin.GeometryData(gm)
        self._bp = None
        self._pools: dict[float, object] = {}  # the batch checker's pools, one per pads' opening (_pool)
        self._tcp_in_j6 = robot.model.frames[robot.tcp_id].placement.translation.copy()
        self._ws_lo = np.asarray(robot.limits.workspace.lower, float)
        self._ws_hi = np.asarray(robot.limits.workspace.upper, float)
        self._q_lo, self._q_hi = robot.lower - 1e-9, robot.upper + 1e-9  # the joint limits as valid() allows them
        # the same bounds as Python floats, per coordinate: valid() compares one configuration at a time (RRT-Connect
        # asks it ~20k times per query), where numpy's per-call overhead on 6 values was most of the bounds' cost
        self._q_box = tuple(zip(self._q_lo.tolist(), self._q_hi.tolist()))
        self._ws_box = tuple(zip(self._ws_lo.tolist(), self._ws_hi.tolist()))
        self.pair_names = [(self.names[i], self.names[j]) for i, j in pairs]
        # pairs with the gripper or the held item (their margin is the grasp margin in for_grasp's variants); not
        # the camera against items and voxels: it never has to come close to them, and what they stand for is
        # known only to a few millimetres (a record of an item put down, to half its height search's step)
        self._gripper_pair = [(a in TOOL_PARTS or b in TOOL_PARTS or a == "held" or b == "held")
                              and not _camera_near_item(a, b) for a, b in self.pair_names]
        self._zone: tuple[Scene, int, float] | None = None  # (strict variant, target geometry, radius): for_grasp
        self._zone_at: dict[bytes, bool] = {}  # q -> whether its TCP is within the contact zone (_tcp_in_zone)
        # only_tool_touches' / only_pads_touch's variants (the pairs asked about, all the others), made when first asked
        self._splits: dict[str, tuple[Scene, Scene]] = {}
        self._set_margins({}, world.margin)

    @property
    def opening(self) -> float:
        return self._shared["opening"]

    def set_opening(self, opening: float) -> None:
        """Move the finger pads to `opening` (the geometry model is shared by this scene's grasp/release
        variants, so it moves for all of them)."""
        if abs(opening - self._shared["opening"]) < 1e-9:
            return
        self._shared["opening"] = float(opening)
        robot = self.world.robot
        for tb in self.world.gripper.pads(robot.T_flange_tcp, float(opening)):
            gid = self.names.index(tb.name)
            self.gm.geometryObjects[gid].placement = pin.SE3(self._T_j6_flange @ tb.T_flange_box)

    # ---- margins and allowed contacts --------------------------------------------------------------------
    def _set_margins(self, allowed: dict[tuple[str, str], bool], default_margin: float, gripper_margin: float | None = None) -> None:
        gd = self.gd
        reqs = gd.collisionRequests  # a view on the requests: one Python proxy for all pairs (~1 us a pair less)
        active = list(gd.activeCollisionPairs)
        for k, (a, b) in enumerate(self.pair_names):
            m = default_margin
            if gripper_margin is not None and self._gripper_pair[k]:
                m = gripper_margin
            reqs[k].security_margin = m
            on = not (allowed and allowed.get((a, b), False))
            if on != active[k]:  # (de)activating is needed only where the state changes
                gd.activateCollisionPair(k) if on else gd.deactivateCollisionPair(k)

    def allowing(self, pairs: Iterable[tuple[str, str]]) -> "Scene":
        """A copy of this scene (same margins) in which the given (name, name) pairs are not checked."""
        want = {tuple(p) for p in pairs} | {(b, a) for a, b in pairs}
        other = self._variant()
        for k, (a, b) in enumerate(self.pair_names):
            other.gd.collisionRequests[k].security_margin = self.gd.collisionRequests[k].security_margin
            if self.gd.activeCollisionPairs[k] and (a, b) not in want:
                other.gd.activateCollisionPair(k)
            else:
                other.gd.deactivateCollisionPair(k)
        return other

    def allowing_keep_zone(self, pairs: Iterable[tuple[str, str]]) -> "Scene":
        """As allowing(pairs), keeping for_grasp's contact zone for the target (its strict variant allows the
        pairs too): a grasp whose pads may also brush a neighbour (planning/pad_give.py)."""
        pairs = list(pairs)
        other = self.allowing(pairs)
        if self._zone is not None:
            strict, gid, radius = self._zone
            other._zone = (strict.allowing(pairs), gid, radius)
        return other

    def touching_only(self, pairs: Iterable[tuple[str, str]]) -> "Scene":
        """A copy of this scene in which the given (name, name) pairs keep no margin: they may come closer than
        the collision margin but must not touch (escaping from a stop within the margin of a rack wall)."""
        want = {tuple(p) for p in pairs} | {(b, a) for a, b in pairs}
        other = self._variant()
        for k, (a, b) in enumerate(self.pair_names):
            m = self.gd.collisionRequests[k].security_margin
            other.gd.collisionRequests[k].security_margin = 0.0 if (a, b) in want else m
            other.gd.activateCollisionPair(k) if self.gd.activeCollisionPairs[k] else other.gd.deactivateCollisionPair(k)
        return other

    def with_pair_margins(self, margins: dict[tuple[str, str], float]) -> "Scene":
        """A copy of this scene in which the given (name, name) pairs are checked with their own margin (m; a
        negative one lets them overlap by that much: a start contact that may last but not get deeper)."""
        want = {tuple(p): float(m) for p, m in margins.items()}
        want |= {(b, a): m for (a, b), m in list(want.items())}
        other = self._variant()
        for k, (a, b) in enumerate(self.pair_names):
            other.gd.collisionRequests[k].security_margin = want.get((a, b), self.gd.collisionRequests[k].security_margin)
            other.gd.activateCollisionPair(k) if self.gd.activeCollisionPairs[k] else other.gd.deactivateCollisionPair(k)
        return other

    def _pair_index(self, pair: tuple[str, str]) -> int | None:
        """Index of the collision pair of these two geometry names (either order); None where the scene has none."""
        names = {tuple(p): k for k, p in enumerate(self.pair_names)}
        return names.get(tuple(pair), names.get((pair[1], pair[0])))

    def _within(self, q: np.ndarray, pair: tuple[str, str]):
        """For the pair's geometries at q: a function margin (m) -> whether they come within it (a negative margin:
        whether they overlap by more than its size); None where the scene has no such pair."""
        k = self._pair_index(pair)
        if k is None:
            return None
        other = self._variant()
        pin.updateGeometryPlacements(self.model, other.data, self.gm, other.gd, np.asarray(q, float))
        req = other.gd.collisionRequests[k]

        def within(m: float) -> bool:
            req.security_margin = m
            return bool(pin.computeCollision(self.gm, other.gd, k))

        return within

    @staticmethod
    def _switch(holds, lo: float, hi: float, tol: float) -> tuple[float, float]:
        """Bisection on [lo, hi] where holds(lo) and not holds(hi): the bracket (within `tol`) where it switches."""
        while hi - lo > tol:
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if holds(mid) else (lo, mid)
        return lo, hi

    def penetration(self, q: np.ndarray, pair: tuple[str, str], limit: float = 0.03, tol: float = 1e-4) -> float:
        """How deep (m, within `tol`) the pair's geometries overlap at q: 0 where they do not touch, `limit` where
        they overlap by that much or more (bisection on a negative security margin)."""
        within = self._within(q, pair)
        if within is None or not within(0.0):
            return 0.0
        if within(-limit):
            return float(limit)
        return self._switch(lambda d: within(-d), 0.0, float(limit), tol)[1]

    def clearance(self, q: np.ndarray, pair: tuple[str, str], limit: float, tol: float = 2.5e-4) -> float:
        """How far apart (m, within `tol`) the pair's geometries are at q, up to `limit` (bisection on the pair's
        security margin); 0 where they touch or the scene has no such pair."""
        within = self._within(q, pair)
        if within is None:
            return 0.0
        if not within(limit):
            return float(limit)
        if within(0.0):
            return 0.0
        return self._switch(lambda m: not within(m), 0.0, float(limit), tol)[0]

    def signed_gaps(self, Q: np.ndarray, pair: tuple[str, str], span: float, tol: float = 2e-5) -> np.ndarray:
        """Per configuration of `Q` (N, 6): the pair's signed gap (m; negative: overlap depth) within `tol`, clipped
        to [-span, span] (bisection on the pair's security margin, as `clearance` and `penetration`), whether or
        not this scene checks the pair. All `span` for a pair the scene does not have.

        Where the two are apart, the bisection's last bracket is first predicted from their distance (one distance
        query, `_switch_at`) and checked at its two ends (two collision checks at those margins): where the gap is
        more than its lower end and at most its upper end, the bisection (monotone in the margin) ends in that
        bracket, and its ~10 checks are not run. Where the check disagrees (the distance query and the margin check
        differ by a few micrometres at a bracket's end) or the two overlap, the bisection runs as before: the same
        answer either way."""
        Q = np.asarray(Q, float).reshape(-1, 6)
        out = np.full(len(Q), float(span))
        k = self._pair_index(pair)
        if k is None:
            return out
        other = self._variant()
        req = other.gd.collisionRequests[k]

        def within(m: float) -> bool:  # the gap is at most m
            req.security_margin = m
            return bool(pin.computeCollision(self.gm, other.gd, k))

        lo0, hi0 = -float(span), float(span)
        for i, q in enumerate(Q):
            pin.updateGeometryPlacements(self.model, other.data, self.gm, other.gd, q)
            if not within(span):
                continue
            d = float(pin.computeDistance(self.gm, other.gd, k).min_distance)
            if d > 0.0:  # apart: the bracket the bisection would end in, if the distance query agrees
                lo, hi = self._switch_at(d, lo0, hi0, tol)
                if not within(lo) and (hi == hi0 or within(hi)):  # gap in (lo, hi]; within(span) is known
                    out[i] = (lo + hi) / 2
                    continue
            if within(-span):
                out[i] = -float(span)
                continue
            lo, hi = self._switch(lambda m: not within(m), lo0, hi0, tol)
            out[i] = (lo + hi) / 2
        return out

    @staticmethod
    def _switch_at(x: float, lo: float, hi: float, tol: float) -> tuple[float, float]:
        """The bracket `_switch` ends in on [lo, hi] for a predicate that holds below `x` and not from `x` on: the
        same midpoints, computed the same way."""
        while hi - lo > tol:
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if x > mid else (lo, mid)
        return lo, hi

    def touching(self, Q: np.ndarray, pair: tuple[str, str], margin: float = 0.0) -> np.ndarray:
        """Per configuration of `Q` (N, 6): whether the pair's geometries come within `margin` (m; 0: they touch
        or overlap), whether or not this scene checks the pair. All False for a pair the scene does not have."""
        k = self._pair_index(pair)
        Q = np.asarray(Q, float).reshape(-1, 6)
        if k is None:
            return np.zeros(len(Q), bool)
        other = self._variant()
        other.gd.collisionRequests[k].security_margin = float(margin)
        out = np.zeros(len(Q), bool)
        for i, q in enumerate(Q):
            pin.updateGeometryPlacements(self.model, other.data, self.gm, other.gd, q)
            out[i] = bool(pin.computeCollision(self.gm, other.gd, k))
        return out

    def content_key(self) -> tuple:
        """What this scene's answers depend on, as a hashable value: the world, the held item, the obstacles
        (names, models, poses), the voxels, the extra boxes, every pair's margin and activation and the contact
        zone. Two scenes with equal keys answer every query alike (the pads' opening is left out: it is moved per
        query, set_opening). For results kept across queries (grasps.select_grasps' `memo`)."""
        held = None if self.held is None else (id(self.held.model), np.asarray(self.held.T_tcp_obj, float).tobytes(),
                                               float(self.held.width))
        objs = tuple((o.name, id(o.model), np.asarray(o.T_base_obj, float).tobytes()) for o in self.objects)
        boxes = tuple(n for n in self.names if n.startswith("cell:"))
        placements = tuple(self.gm.geometryObjects[i].placement.homogeneous.tobytes()
                           for i in range(len(self.names)) if self.group.get(i) == "env")
        margins = tuple(float(r.security_margin) for r in self.gd.collisionRequests)
        active = tuple(bool(a) for a in self.gd.activeCollisionPairs)
        zone = None if self._zone is None else (self._zone[0].content_key(), self._zone[1], self._zone[2])
        return (id(self.world), held, objs, hashlib.sha1(self.voxels.tobytes()).hexdigest(), boxes,
                placements, margins, active, zone)

    def _variant(self) -> "Scene":
        other = object.__new__(Scene)
        other.__dict__.update(self.__dict__)
        other.data = self.model.createData()
        other.gd = pin.GeometryData(self.gm)
        other._bp = None
        other._pools = {}  # its own pair activations and margins
        other._zone = None
        other._zone_at = {}
        other._splits = {}
        return other

    def for_grasp(self, target_name: str | None, *, pads_only: bool = True) -> "Scene":
        """A copy of this scene for the last centimetres of a grasp/place: gripper margins shrink to
        ``grasp_margin`` and the pads may touch ``obj:<target_name>`` (and the palm too when not pads_only)."""
        other = self._variant()
        allowed: dict[tuple[str, str], bool] = {}
        if target_name is not None:
            tgt = f"obj:{target_name}"
            parts = PADS if pads_only else TOOL_PARTS
            for a, b in self.pair_names:
                if (a == tgt and b in parts) or (b == tgt and a in parts):
                    allowed[(a, b)] = True
        other._set_margins(allowed, self.world.margin, self.world.grasp_margin)
        if allowed and self.world.pad_contact_radius >= 0:
            # The pads may touch the target only while closing around it: while the TCP is within
            # `pad_contact_radius` of the target's surface. Farther out a pad touching it (e.g. a finger through a
            # mug's handle while it slides in) pushes or hits it; there the strict variant decides.
            strict = self._variant()
            strict._set_margins({}, self.world.margin, self.world.grasp_margin)
            gid = self.names.index(f"obj:{target_name}")
            other._zone = (strict, gid, self.world.pad_contact_radius)
        return other

    def for_release(self, target_name: str | None = None) -> "Scene":
        """Scene for placing: the held object and gripper use ``grasp_margin`` (it must touch its support)."""
        return self.for_grasp(target_name, pads_only=False)

    # ---- queries -------------------------------------------------------------------------------------------
    def _broadphase(self):
        """coal's dynamic AABB tree over this scene (3x fewer narrow-phase tests than all pairs; it uses the
        pairs' activation and security margins from the GeometryData, cross-checked in the tests)."""
        if self._bp is None:
            self._bp = pin.BroadPhaseManager_DynamicAABBTreeCollisionManager(self.model, self.gm, self.gd)
        return self._bp

    def in_collision_exhaustive(self, q: np.ndarray) -> bool:
        """All-pairs check without the broad phase (reference for tests)."""
        return bool(pin.computeCollisions(self.model, self.data, self.gm, self.gd, np.asarray(q, float), True))

    def valid(self, q: np.ndarray) -> bool:
        """True when q is within the joint limits and nothing collides (within the margins)."""
        q = np.asarray(q, float)
        if q.shape == (6,):  # the same comparisons as the arrays' below, on Python floats (a NaN fails none)
            for a, (lo, hi) in zip(q.tolist(), self._q_box):
                if a < lo or a > hi:
                    return False
        elif (q < self._q_lo).any() or (q > self._q_hi).any():
            return False
        if pin.computeCollisions(self.model, self.data, self._broadphase(), q, True):
            return False
        # the TCP must stay inside the safety workspace (the Arm refuses trajectories that leave it)
        p = self.data.oMi[6].act(self._tcp_in_j6)
        for a, (lo, hi) in zip(p.tolist(), self._ws_box):
            if a < lo or a > hi:
                return False
        if self._zone is not None and not self._zone[0].valid(q):
            return bool(self._in_contact_zone(p[None])[0])
        return True

    def _in_contact_zone(self, P: np.ndarray) -> np.ndarray:
        """Whether each TCP position (N, 3) is within the pad-contact radius of the grasp target's surface."""
        _, gid, radius = self._zone
        go = self.gm.geometryObjects[gid]
        T_obj = coal.Transform3s(go.placement.rotation, go.placement.translation)  # env objects hang off the base
        probe = coal.Sphere(1e-4)
        req = coal.DistanceRequest()
        out = np.zeros(len(P), bool)
        for i, p in enumerate(P):
            d = coal.distance(probe, coal.Transform3s(np.eye(3), np.asarray(p, float)), go.geometry, T_obj, req,
                              coal.DistanceResult())
            out[i] = d <= radius
        return out

    # pools kept per scene (distinct pads' openings): a grasp search asks a few openings, alternately
    MAX_POOLS = 8

    def _pool(self):
        """Pinocchio's batch checker (C++ loop over configurations, same broad phase, this scene's pair
        activation and margins). The pool holds its own copy of the geometry, so it is built for the pads'
        opening at the time: one per opening, kept (grasp selection alternates between a few openings, since
        its candidates are ordered by height, not by opening; it rebuilt the pool at every change). A scene's
        margins and activations are set when it is made and not changed after, the pads are the only geometry
        that moves (set_opening): a kept pool answers as a new one would."""
        key = self._shared["opening"]
        pool = self._pools.get(key)
        if pool is None:
            pool = pin.BroadPhaseManagerPool_DynamicAABBTreeCollisionManager(self.model, self.gm, 1)
            gd = pool.getGeometryDatas()[0]
            reqs, mine = gd.collisionRequests, self.gd.collisionRequests  # views: one Python proxy each
            want, now = list(self.gd.activeCollisionPairs), list(gd.activeCollisionPairs)
            for k in range(len(self.pair_names)):
                reqs[k].security_margin = mine[k].security_margin
                if want[k] != now[k]:
                    gd.activateCollisionPair(k) if want[k] else gd.deactivateCollisionPair(k)
            if len(self._pools) >= self.MAX_POOLS:
                self._pools.clear()
            self._pools[key] = pool
        return pool

    def valid_batch(self, Q: np.ndarray, *, up_to_first: bool = False) -> np.ndarray:
        """Validity of each row of Q (N, 6): limits, workspace (vectorised DH FK) and collisions (batch).
        `up_to_first`: the batch checker stops at the first colliding row, so only the rows up to the first
        invalid one are answered (those after it are undetermined): what :meth:`first_invalid` needs."""
        Q = np.asarray(Q, float).reshape(-1, 6)
        robot = self.world.robot
        ok = np.all((Q >= robot.lower - 1e-9) & (Q <= robot.upper + 1e-9), axis=1)
        p = tcp_positions(robot, Q)
        ok &= np.all((p >= self._ws_lo) & (p <= self._ws_hi), axis=1)
        if ok.any():
            idx = np.flatnonzero(ok)
            hit = np.asarray(pin.computeCollisionsInParallel(1, self._pool(), np.ascontiguousarray(Q[idx].T), True,
                                                             up_to_first), bool)
            ok[idx[hit]] = False
        if self._zone is not None and ok.any():
            idx = np.flatnonzero(ok)
            touching = idx[~self._zone[0].valid_batch(Q[idx])]  # valid only thanks to the allowed pad contacts
            if len(touching):
                ok[touching] = self._in_contact_zone(p[touching])
        return ok

    def all_valid(self, Q: np.ndarray) -> bool:
        """Whether every row of Q (N, 6) is valid: ``valid_batch(Q).all()``, but the batch checker stops at the
        first colliding row (order Q with the likeliest collisions first). A motion check of RRT-Connect."""
        Q = np.asarray(Q, float).reshape(-1, 6)
        if self._zone is not None:
            return bool(self.valid_batch(Q).all())
        robot = self.world.robot
        if not np.all((Q >= robot.lower - 1e-9) & (Q <= robot.upper + 1e-9)):
            return False
        p = tcp_positions(robot, Q)
        if not np.all((p >= self._ws_lo) & (p <= self._ws_hi)):
            return False
        hit = pin.computeCollisionsInParallel(1, self._pool(), np.ascontiguousarray(Q.T), True, True)
        return not bool(np.any(hit))

    def first_invalid(self, Q: np.ndarray, chunk: int = 128) -> int:
        """Index of the first invalid row of Q, or -1 when all are valid (checked in chunks, stops early)."""
        Q = np.asarray(Q, float).reshape(-1, 6)
        for s in range(0, len(Q), chunk):
            v = self.valid_batch(Q[s : s + chunk], up_to_first=True)
            if not v.all():
                return s + int(np.argmin(v))
        return -1

    def only_tool_touches(self, q: np.ndarray) -> bool:
        """Whether all that collides at q is the tool meeting perceived objects or the map's voxels (at least one
        such pair, no other pair): what ``colliding_pairs(q)`` says read that way (a grasp's near miss), from two
        broad-phase checks, one over those pairs and one over all the others, instead of a check of every pair."""
        return self._only_pairs_touch(q, "tool", _tool_meets_item)

    def only_pads_touch(self, q: np.ndarray) -> bool:
        """Whether all that collides at q has an open pad in it (at least one such pair, no pair without a pad):
        ``colliding_pairs(q)`` read that way (a grasp rejected only for its open pads), from two broad-phase
        checks as :meth:`only_tool_touches`."""
        return self._only_pairs_touch(q, "pads", _has_pad)

    def _only_pairs_touch(self, q: np.ndarray, name: str, which: Callable[[str, str], bool]) -> bool:
        """At least one active pair for which `which(a, b)` holds collides at q and no other active pair does (what
        ``colliding_pairs(q)`` says, read so): a broad-phase check over the scene's variant with only those pairs
        active, then one over the variant without them (both made once per scene and kept under `name`). Where the
        grasp's contact zone applies, as colliding_pairs: outside it, the strict variant answers."""
        if self._zone is not None and not self._tcp_in_zone(q):
            return self._zone[0]._only_pairs_touch(q, name, which)
        split = self._splits.get(name)
        if split is None:
            mine = {p for p in self.pair_names if which(*p)}
            these = self._variant()
            for k, pr in enumerate(self.pair_names):
                these.gd.collisionRequests[k].security_margin = self.gd.collisionRequests[k].security_margin
                if self.gd.activeCollisionPairs[k] and pr in mine:
                    these.gd.activateCollisionPair(k)
                else:
                    these.gd.deactivateCollisionPair(k)
            split = self._splits[name] = (these, self.allowing(mine))
        these, others = split
        q = np.asarray(q, float)
        if not pin.computeCollisions(self.model, these.data, these._broadphase(), q, True):
            return False
        return not pin.computeCollisions(self.model, others.data, others._broadphase(), q, True)

    def _tcp_in_zone(self, q: np.ndarray) -> bool:
        """Whether the TCP at q is within the grasp target's contact zone (where this scene's pad contacts apply;
        outside it the strict variant answers the pair queries). Kept per configuration: a rejected grasp's
        configurations are asked about again and again (its near miss, its pads alone in the way, what crowds it)."""
        q = np.asarray(q, float).reshape(6)
        key = q.tobytes()
        hit = self._zone_at.get(key)
        if hit is None:
            hit = bool(self._in_contact_zone(tcp_positions(self.world.robot, q.reshape(1, 6)))[0])
            if len(self._zone_at) >= 4096:
                self._zone_at.clear()
            self._zone_at[key] = hit
        return hit

    def colliding_pairs(self, q: np.ndarray) -> list[tuple[str, str]]:
        if self._zone is not None and not self._tcp_in_zone(q):
            return self._zone[0].colliding_pairs(q)
        pin.computeCollisions(self.model, self.data, self.gm, self.gd, np.asarray(q, float), False)
        out = []
        for k, r in enumerate(self.gd.collisionResults):
            if self.gd.activeCollisionPairs[k] and r.isCollision():
                out.append(self.pair_names[k])
        return out

    def min_distance(self, q: np.ndarray, parts: Iterable[str], exclude: Iterable[str] = ()) -> float:
        """Smallest distance (m) from geometries named in `parts` to environment geometries not in `exclude`."""
        parts, exclude = set(parts), set(exclude)
        pin.updateGeometryPlacements(self.model, self.data, self.gm, self.gd, np.asarray(q, float))
        best = np.inf
        req = coal.DistanceRequest()
        for k, (a, b) in enumerate(self.pair_names):
            if not ((a in parts and b.startswith(("cell:", "obj:", "voxels"))) or (b in parts and a.startswith(("cell:", "obj:", "voxels")))):
                continue
            if a in exclude or b in exclude:
                continue
            p = self.gm.collisionPairs[k]
            res = coal.DistanceResult()
            d = coal.distance(
                self._proxy(p.first), self.gd.oMg[p.first], self._proxy(p.second), self.gd.oMg[p.second], req, res,
            )
            best = min(best, d)
        return float(best)

    def _proxy(self, gid: int):
        """Geometry for clearance queries: meshes are replaced by their bounding boxes (fast, never larger
        clearance than the mesh; the box is centred on the mesh frame origin = BOP bounding-box centre)."""
        g = self.gm.geometryObjects[gid].geometry
        if isinstance(g, coal.BVHModelBase):
            key = id(g)
            box = self.world._proxy_cache.get(key)
            if box is None:
                g.computeLocalAABB()
                a = g.aabb_local
                box = coal.Box(*(np.maximum(np.abs(np.asarray(a.min_)), np.abs(np.asarray(a.max_))) * 2))
                self.world._proxy_cache[key] = box
            return box
        return g

    def voxels_at_robot(self, q: np.ndarray, centres: np.ndarray) -> np.ndarray:
        """Which voxels (centres (N, 3), cubes of the world's voxel size, base frame) lie within the collision
        margin of the arm, the tool or the held item at `q`: the ones that make `q` collide."""
        C = np.asarray(centres, float).reshape(-1, 3)
        out = np.zeros(len(C), bool)
        if not len(C):
            return out
        pin.updateGeometryPlacements(self.model, self.data, self.gm, self.gd, np.asarray(q, float))
        vs = self.world.voxel_size
        box = coal.Box(vs, vs, vs)
        req = coal.CollisionRequest()
        req.security_margin = self.world.margin
        eye = np.eye(3)
        for gid, group in self.group.items():
            if group == "env":
                continue
            g = self.gm.geometryObjects[gid].geometry
            M = self.gd.oMg[gid]
            Tg = coal.Transform3s(np.asarray(M.rotation), np.asarray(M.translation))
            for k in np.flatnonzero(~out):
                if coal.collide(g, Tg, box, coal.Transform3s(eye, C[k]), req, coal.CollisionResult()):
                    out[k] = True
        return out

    def placements(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """T_base_geometry of every geometry at q (used by the independent checker)."""
        pin.updateGeometryPlacements(self.model, self.data, self.gm, self.gd, np.asarray(q, float))
        return {self.names[i]: self.gd.oMg[i].homogeneous.copy() for i in range(len(self.names))}


__all__ = [
    "Capsule",
    "CollisionWorld",
    "GripperGeometry",
    "Held",
    "Scene",
    "SceneObject",
    "ToolBox",
    "link_capsules",
]
