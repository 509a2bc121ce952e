"""Physics-free resting poses: put an object down so it touches what is below it without sinking in.

Contact is found on a height field: on a grid over the object's footprint, the object's underside b(x, y)
(rays cast up into the object) and the top of everything else h(x, y) (rays cast down from the underside)
give the largest drop that keeps b >= h everywhere. That handles plates on plates, cups nested in cups and
items resting on rims. No toppling, no friction: an object rests where it first touches.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.fakes.geometry import build_scene, cast_vertical

GRID = 0.003  # m


def _underside(mesh: o3d.geometry.TriangleMesh, grid: float) -> tuple[np.ndarray, np.ndarray]:
    """(xy, z) of the lowest surface of `mesh` on a grid over its footprint."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    bb = mesh.get_axis_aligned_bounding_box()
    lo, hi = bb.get_min_bound(), bb.get_max_bound()
    xs = np.arange(lo[0] + grid / 2, hi[0], grid)
    ys = np.arange(lo[1] + grid / 2, hi[1], grid)
    X, Y = np.meshgrid(xs, ys)
    xy = np.column_stack([X.ravel(), Y.ravel()])
    z = cast_vertical(scene, xy, lo[2] - 0.01, down=False)
    ok = np.isfinite(z)
    return xy[ok], z[ok]


def drop_onto(world, uid: int, T_base_obj: np.ndarray, floor_z: float = -1.0) -> np.ndarray:
    """T_base_obj moved straight down (or up, if it intersects) until it rests on the rest of the world."""
    obj = world.objects[uid]
    mesh = o3d.geometry.TriangleMesh(obj.model.mesh)
    mesh.transform(T_base_obj)
    xy, b = _underside(mesh, GRID)
    if len(xy) == 0:
        return T_base_obj
    scene, _ = build_scene(world, exclude=(uid,))
    top = float(mesh.get_axis_aligned_bounding_box().get_max_bound()[2])
    # Cast from the object's top so that anything it already intersects counts as "below".
    h = cast_vertical(scene, xy, top + 0.001, down=True)
    h = np.where(np.isfinite(h), h, floor_z)
    dz = float(np.max(h - b))
    T = np.array(T_base_obj, float)
    T[2, 3] += dz
    return T
