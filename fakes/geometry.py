"""Triangle meshes of the world and an Open3D RaycastingScene over them (rendering and placement share it)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from kitchenbot.world.cell import Box

o3dt = o3d.t.geometry


def box_mesh(box: Box) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_box(*box.size)
    m.translate(box.lower)
    return m


def plane_mesh(T_base_plane: np.ndarray, width: float, height: float) -> o3d.geometry.TriangleMesh:
    w, h = width / 2, height / 2
    V = np.array([[-w, -h, 0], [w, -h, 0], [w, h, 0], [-w, h, 0]], float)
    V = V @ T_base_plane[:3, :3].T + T_base_plane[:3, 3]
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector([[0, 1, 2], [0, 2, 3]]))


@dataclass
class Labelled:
    """What each geometry id of a RaycastingScene is: ('cell', box index) | ('obj', uid) | ('plane', name)
    | ('fixture', name)."""

    kinds: list[tuple[str, object]]


def build_scene(world, exclude: tuple[int, ...] = (), include_cell: bool = True) -> tuple[o3dt.RaycastingScene, Labelled]:
    """A RaycastingScene of the world (cell boxes, objects, textured planes), minus `exclude` object uids."""
    scene = o3dt.RaycastingScene()
    kinds: list[tuple[str, object]] = []

    def add(mesh: o3d.geometry.TriangleMesh, kind: tuple[str, object]) -> None:
        gid = scene.add_triangles(o3dt.TriangleMesh.from_legacy(mesh))
        assert gid == len(kinds)
        kinds.append(kind)

    if include_cell:
        for i, b in enumerate(world.cell.boxes):
            add(box_mesh(b), ("cell", i))
    for uid, o in world.objects.items():
        if uid in exclude:
            continue
        add(world.object_mesh(uid), ("obj", uid))
    for name, p in world.planes.items():
        add(plane_mesh(p.T_base_plane, p.width, p.height), ("plane", name))
    if include_cell:
        for name, fx in getattr(world, "fixtures", {}).items():
            add(fx.mesh, ("fixture", name))
    return scene, Labelled(kinds)


def cast_vertical(scene: o3dt.RaycastingScene, xy: np.ndarray, z_start: float | np.ndarray, down: bool) -> np.ndarray:
    """z of the first hit of vertical rays from (x, y, z_start); NaN where nothing is hit."""
    n = len(xy)
    origins = np.column_stack([xy, np.broadcast_to(z_start, (n,))]).astype(np.float32)
    d = np.zeros((n, 3), np.float32)
    d[:, 2] = -1.0 if down else 1.0
    t = scene.cast_rays(o3d.core.Tensor(np.hstack([origins, d])))["t_hit"].numpy()
    z = origins[:, 2] + d[:, 2] * t
    z[~np.isfinite(t)] = np.nan
    return z
