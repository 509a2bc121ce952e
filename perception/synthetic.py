"""Synthetic RGB-D views with a known answer (perception tests and benchmarks): inventory meshes placed in the cell's
sink at known poses, rendered with an Open3D RaycastingScene (depth, RGB with Lambert shading, instance labels)."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.perception.database import look_at
from kitchenbot.perception.types import View
from kitchenbot.transforms import inv, make_T
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory

K_VGA = np.array([[460.0, 0, 320.0], [0, 460.0, 240.0], [0, 0, 1.0]])


def resting_pose(inv_: Inventory, obj_id: int, x: float, y: float, yaw: float = 0.0, cell: Cell | None = None,
                 upside_down: bool = False) -> np.ndarray:
    """Pose of a model standing on the sink floor at (x, y)."""
    cell = cell or Cell()
    floor = cell.sink_interior[0][2]
    m = inv_[obj_id]
    lo = np.asarray(m.mesh.get_axis_aligned_bounding_box().get_min_bound())
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
    if upside_down:
        R = R @ np.diag([1.0, -1.0, -1.0])
    return make_T(R, [x, y, floor - lo[2]])


def scan_poses(cell: Cell | None = None, n: int = 3, height: float = 0.45) -> list[np.ndarray]:
    cell = cell or Cell()
    lo, hi = cell.sink_interior
    c = (lo + hi) / 2
    c[2] = lo[2] + 0.05
    out = []
    for k in range(n):
        a = np.pi + (k - (n - 1) / 2) * 0.45
        eye = c + np.array([0.18 * np.cos(a), 0.18 * np.sin(a), height])
        out.append(look_at(eye, c, up=(1.0, 0.0, 0.0)))
    return out


def render(inv_: Inventory, placed: list[tuple[int, np.ndarray]], T_base_cams: list[np.ndarray],
           cell: Cell | None = None, K: np.ndarray = K_VGA, size=(640, 480), noise: float = 0.0,
           rng: np.random.Generator | None = None,
           extra: list[tuple[o3d.geometry.TriangleMesh, tuple[float, float, float]]] = ()) -> tuple[list[View], list[np.ndarray]]:
    """Views and per-pixel labels (-1 cell/background, k = index into `placed`, then the `extra` meshes:
    things that are not in the inventory, already in the base frame)."""
    cell = cell or Cell()
    scene = o3d.t.geometry.RaycastingScene()
    colours, labels = [], []
    for b in cell.boxes:
        m = o3d.geometry.TriangleMesh.create_box(*b.size)
        m.translate(b.lower)
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
        colours.append(b.colour)
        labels.append(-1)
    for k, (oid, T) in enumerate(placed):
        m = o3d.geometry.TriangleMesh(inv_[oid].mesh)
        m.transform(T)
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
        colours.append(inv_[oid].colour)
        labels.append(k)
    for k, (mesh, colour) in enumerate(extra):
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        colours.append(colour)
        labels.append(len(placed) + k)
    colours, labels = np.array(colours), np.array(labels)
    rng = rng or np.random.default_rng(0)
    views, labs = [], []
    w, h = size
    for T in T_base_cams:
        rays = scene.create_rays_pinhole(o3d.core.Tensor(K), o3d.core.Tensor(inv(T)), w, h)
        ans = scene.cast_rays(rays)
        t = ans["t_hit"].numpy()
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t)
        r = rays.numpy()[..., 3:]
        z = np.where(hit, t * (r @ T[:3, 2]), 0.0)  # t_hit is along the (unnormalised) ray: z = t * dir.z_cam
        n = ans["primitive_normals"].numpy()
        shade = 0.35 + 0.65 * np.abs(np.sum(n * r / np.linalg.norm(r, axis=-1, keepdims=True), axis=-1))
        g = np.where(hit, gid, 0)
        rgb = np.clip(colours[g] * shade[..., None] * 255, 0, 255).astype(np.uint8)
        rgb[~hit] = 0
        if noise > 0:
            z = np.where(hit, z + rng.normal(0, noise, z.shape) * z**2, 0.0)
        views.append(View(rgb, z.astype(np.float32), K.copy(), T.copy()))
        labs.append(np.where(hit, labels[g], -1))
    return views, labs
