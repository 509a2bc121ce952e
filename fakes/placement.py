"""Physics-free resting poses: put an object down so it touches what is below it without sinking in, and
let it tip over its support until it is statically stable.

Contact is found on a height field: on a grid over the object's footprint, the object's underside b(x, y)
(rays cast up into the object) and the top of everything else h(x, y) (rays cast down from above the object)
give the largest drop that keeps b >= h everywhere. That handles plates on plates, cups nested in cups and
items resting on rims. `settle` then rotates the object about its support (a point or an edge) in small
steps, dropping it again after each, until its centre of mass lies over the support polygon: a quasi-static
stand-in for toppling, with no friction and no sliding. Written by hand because no library here does
quasi-static rigid-body settling on triangle meshes; all geometry queries go through Open3D raycasting.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation

from kitchenbot.fakes.geometry import build_scene, cast_vertical
from kitchenbot.transforms import make_T

GRID = 0.003  # m
CONTACT_TOL = 0.0015  # m: grid cells this close to the deepest contact count as touching
RELEASE_PROBE = 0.0005  # m: a released object's supports are found from this far above its underside


@dataclass
class _Body:
    """An object's mesh in its own frame, ready for repeated underside queries."""

    scene: o3d.t.geometry.RaycastingScene
    vertices: np.ndarray
    com: np.ndarray  # centre of mass (uniform solid), object frame

    @classmethod
    def of(cls, mesh: o3d.geometry.TriangleMesh) -> "_Body":
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        V = np.asarray(mesh.vertices)
        F = np.asarray(mesh.triangles)
        a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0  # signed tetrahedra with the origin
        com = (vol[:, None] * (a + b + c) / 4.0).sum(0) / vol.sum() if abs(vol.sum()) > 1e-12 else V.mean(0)
        return cls(scene, V, com)

    def underside(self, T: np.ndarray, grid: float = GRID) -> tuple[np.ndarray, np.ndarray]:
        """(xy, z) of the lowest surface of the posed object on a base-frame grid over its footprint."""
        Vw = self.vertices @ T[:3, :3].T + T[:3, 3]
        lo, hi = Vw.min(0), Vw.max(0)
        xs = np.arange(lo[0] + grid / 2, hi[0], grid)
        ys = np.arange(lo[1] + grid / 2, hi[1], grid)
        X, Y = np.meshgrid(xs, ys)
        xy = np.column_stack([X.ravel(), Y.ravel()])
        origins = np.column_stack([xy, np.full(len(xy), lo[2] - 0.01)])
        R = T[:3, :3]
        o_obj = (origins - T[:3, 3]) @ R  # into the object frame
        d_obj = np.broadcast_to(R.T @ np.array([0.0, 0.0, 1.0]), o_obj.shape)
        rays = np.hstack([o_obj, d_obj]).astype(np.float32)
        t = self.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        ok = np.isfinite(t)
        return xy[ok], origins[ok, 2] + t[ok]

    def topside(self, T: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """z of the highest surface of the posed object above each base-frame point xy (NaN where none)."""
        Vw = self.vertices @ T[:3, :3].T + T[:3, 3]
        origins = np.column_stack([xy, np.full(len(xy), Vw[:, 2].max() + 0.01)])
        R = T[:3, :3]
        o_obj = (origins - T[:3, 3]) @ R
        d_obj = np.broadcast_to(R.T @ np.array([0.0, 0.0, -1.0]), o_obj.shape)
        t = self.scene.cast_rays(o3d.core.Tensor(np.hstack([o_obj, d_obj]).astype(np.float32)))["t_hit"].numpy()
        return origins[:, 2] - t


def _drop(body: _Body, T: np.ndarray, scene, floor_z: float) -> tuple[np.ndarray, np.ndarray]:
    """(T moved vertically to touch the scene, contact points (N, 3) in the base frame)."""
    xy, b = body.underside(T)
    if len(xy) == 0:
        return T, np.zeros((0, 3))
    top = float((body.vertices @ T[:3, :3].T + T[:3, 3])[:, 2].max())
    # Cast from the object's top so that anything it already intersects counts as "below".
    h = cast_vertical(scene, xy, top + 0.001, down=True)
    h = np.where(np.isfinite(h), h, floor_z)
    gap = h - b
    dz = float(gap.max())
    T = np.array(T, float)
    T[2, 3] += dz
    touching = gap >= dz - CONTACT_TOL
    return T, np.column_stack([xy[touching], h[touching]])


def drop_released(world, uid: int, T_base_obj: np.ndarray, floor_z: float = -1.0) -> np.ndarray:
    """T_base_obj of an object let go where it is: it stays, falls onto what is below it, or (if its bottom is
    sunk into something) rises onto that; never onto an item lying on it.

    Unlike `_drop` (scene generation: anything the object intersects counts as below it), a column's support is
    found from just above the object's underside: the first surface below the probe point, or, when the probe
    point is inside a closed mesh (the first surface below it faces down), the top of that mesh above it.
    """
    body = _Body.of(world.objects[uid].model.mesh)
    scene, labels = build_scene(world, exclude=(uid,))
    xy, b = body.underside(T_base_obj)
    if len(xy) == 0:
        return T_base_obj
    t = body.topside(T_base_obj, xy)
    t = np.where(np.isfinite(t), t, b)
    # The probe point is inside the object (below the middle of its column), so an item resting on the object's
    # top is above it; a support touching or sunk into the underside is below it or contains it.
    s = b + np.minimum(RELEASE_PROBE, np.maximum(t - b, 0.0) / 2)
    down = _cast(scene, xy, s, down=True)
    h = down["z"].copy()
    closed = np.array([k[0] in ("obj", "cell") for k in labels.kinds] + [False])  # open planes/fixtures: surfaces
    gid = np.where(np.isfinite(h), down["gid"], len(labels.kinds))
    inside = closed[gid] & (down["nz"] < 0)  # the ray leaves a solid through its bottom: it started inside
    if inside.any():
        up = _cast(scene, xy[inside], s[inside], down=False)
        h[inside] = np.where(np.isfinite(up["z"]), up["z"], h[inside])
    h = np.where(np.isfinite(h), h, floor_z)
    T = np.array(T_base_obj, float)
    T[2, 3] += float((h - b).max())
    return T


def _cast(scene, xy: np.ndarray, z0: np.ndarray, down: bool) -> dict[str, np.ndarray]:
    """First hits of vertical rays from (xy, z0): z (NaN where none), geometry id, normal's z."""
    d = np.zeros((len(xy), 3), np.float32)
    d[:, 2] = -1.0 if down else 1.0
    origins = np.column_stack([xy, z0]).astype(np.float32)
    r = scene.cast_rays(o3d.core.Tensor(np.hstack([origins, d])))
    t = r["t_hit"].numpy()
    z = np.where(np.isfinite(t), origins[:, 2] + d[:, 2] * t, np.nan)
    return {"z": z, "gid": r["geometry_ids"].numpy().astype(np.int64), "nz": r["primitive_normals"].numpy()[:, 2]}


def drop_onto(world, uid: int, T_base_obj: np.ndarray, floor_z: float = -1.0) -> np.ndarray:
    """T_base_obj moved straight down (or up, if it intersects) until it rests on the rest of the world."""
    body = _Body.of(world.objects[uid].model.mesh)
    scene, _ = build_scene(world, exclude=(uid,))
    return _drop(body, T_base_obj, scene, floor_z)[0]


def _support_pivot(contacts: np.ndarray, com_xy: np.ndarray, margin: float) -> np.ndarray | None:
    """None when the centre of mass is over the support polygon; else the support point nearest to it."""
    pts = contacts[:, :2]
    if len(pts) > 400:  # the contact patch is a dense grid; a strided subset has the same hull to ~a cell
        pts = pts[:: len(pts) // 400 + 1]
        contacts = contacts[:: len(contacts) // 400 + 1]
    if len(pts) >= 3:
        try:
            hull = ConvexHull(pts)
            # Inside when every facet's signed distance is <= -margin.
            if np.all(hull.equations[:, :2] @ com_xy + hull.equations[:, 2] <= -margin):
                return None
        except QhullError:
            pass  # collinear contacts: an edge, handled below
    # Nearest point of the support set to the centre of mass (the contacts are dense on a grid, so the
    # nearest contact approximates the nearest point of the hull boundary).
    k = int(np.argmin(np.linalg.norm(pts - com_xy, axis=1)))
    return contacts[k]


def settle(world, uid: int, T_base_obj: np.ndarray, step_deg: float = 4.0, max_deg: float = 80.0,
           floor_z: float = -1.0, keep_inside: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Drop the object and tip it over its support until its centre of mass is supported.

    `keep_inside` (lower, upper corners): stop tipping before any vertex leaves this box in x/y (the object
    then leans on whatever bounds it, e.g. a basin wall).
    """
    body = _Body.of(world.objects[uid].model.mesh)
    scene, _ = build_scene(world, exclude=(uid,))
    T, contacts = _drop(body, T_base_obj, scene, floor_z)
    turned = 0.0
    while turned < max_deg and len(contacts):
        com = T[:3, :3] @ body.com + T[:3, 3]
        pivot = _support_pivot(contacts, com[:2], margin=0.002)
        if pivot is None:
            break
        d = com[:2] - pivot[:2]
        if np.linalg.norm(d) < 1e-6:
            break
        axis = np.cross([0.0, 0.0, 1.0], [d[0], d[1], 0.0])
        axis /= np.linalg.norm(axis)
        R = Rotation.from_rotvec(axis * np.radians(step_deg)).as_matrix()
        T_new = make_T(R, pivot - R @ pivot) @ T
        T_new, c_new = _drop(body, T_new, scene, floor_z)
        if keep_inside is not None:
            Vw = body.vertices @ T_new[:3, :3].T + T_new[:3, 3]
            lo, hi = keep_inside
            if np.any(Vw[:, :2] < lo[:2]) or np.any(Vw[:, :2] > hi[:2]):
                break
        T, contacts = T_new, c_new
        turned += step_deg
    return T
