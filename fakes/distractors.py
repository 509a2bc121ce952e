"""Things in a sink that are not dishware: boxes, cans, bottles, sponges, cutlery (simple primitives).

They are rendered and collide like the dishware but are not in the inventory: the dataset writer gives them
no ground truth, so any pose perception reports on one is a false positive. Their obj_ids start at
DISTRACTOR_ID0, outside every inventory.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.fakes.placement import settle
from kitchenbot.perception.inventory import ObjectModel
from kitchenbot.transforms import make_T, rot_x, rot_y, rot_z

DISTRACTOR_ID0 = 900


def _box(sx: float, sy: float, sz: float) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_box(sx, sy, sz)
    m.translate((-sx / 2, -sy / 2, 0.0))
    return m


def _cylinder(r: float, h: float) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_cylinder(r, h, resolution=40)
    m.translate((0.0, 0.0, h / 2))
    return m


def _bottle() -> o3d.geometry.TriangleMesh:
    body = _cylinder(0.034, 0.15)
    shoulder = o3d.geometry.TriangleMesh.create_cone(0.034, 0.04, resolution=40)
    shoulder.translate((0.0, 0.0, 0.15))
    neck = _cylinder(0.013, 0.04)
    neck.translate((0.0, 0.0, 0.175))
    return body + shoulder + neck


def distractor_models() -> list[ObjectModel]:
    """A food box, a tea box, a drink can, a bottle, a sponge, a knife and a fork-sized bar."""
    specs = [
        ("food_box", _box(0.16, 0.06, 0.22), (0.85, 0.35, 0.15)),
        ("tea_box", _box(0.12, 0.07, 0.07), (0.20, 0.45, 0.75)),
        ("can", _cylinder(0.033, 0.122), (0.75, 0.10, 0.12)),
        ("bottle", _bottle(), (0.25, 0.55, 0.30)),
        ("sponge", _box(0.10, 0.07, 0.03), (0.95, 0.85, 0.20)),
        ("knife", _box(0.21, 0.018, 0.006), (0.70, 0.70, 0.72)),
        ("fork", _box(0.19, 0.025, 0.008), (0.65, 0.66, 0.68)),
    ]
    out = []
    for k, (name, mesh, colour) in enumerate(specs):
        mesh = mesh.remove_duplicated_vertices()
        mesh.compute_vertex_normals()
        V = np.asarray(mesh.vertices)
        diam = float(np.max(np.linalg.norm(V[:, None] - V[None], axis=2))) if len(V) < 3000 else 0.0
        out.append(ObjectModel(DISTRACTOR_ID0 + k, name, "distractor", mesh, diam, colour=colour))
    return out


def add_distractors(world, n: int, rng: np.random.Generator, max_top_z: float = 0.08) -> list[int]:
    """Drop `n` random distractors into the world's sink (lying on a random side, settled onto what is there).
    Returns their uids; a distractor that finds no place inside the basin in 8 tries is left out."""
    models = distractor_models()
    lo, hi = world.cell.sink_interior
    uids = []
    for _ in range(n):
        model = models[int(rng.integers(len(models)))]
        for _attempt in range(8):
            lying = [np.eye(4), rot_x(np.pi / 2), rot_y(np.pi / 2)][int(rng.integers(3))]
            R = rot_z(rng.uniform(0, 2 * np.pi)) @ lying
            V = np.asarray(model.mesh.vertices) @ R[:3, :3].T
            r = float(np.max(np.linalg.norm(V[:, :2] - V[:, :2].mean(axis=0), axis=1)))
            lo_xy, hi_xy = lo[:2] + r + 0.003, hi[:2] - r - 0.003
            if np.any(lo_xy > hi_xy):
                continue
            xy = rng.uniform(lo_xy, hi_xy)
            T = make_T(R[:3, :3], (xy[0], xy[1], 0.3))
            uid = world.add_object(model, T)
            T_rest = settle(world, uid, T, keep_inside=world.cell.sink_interior)
            V = np.asarray(model.mesh.vertices) @ T_rest[:3, :3].T + T_rest[:3, 3]
            inside = np.all(V[:, :2] >= lo[:2] - 1e-3) and np.all(V[:, :2] <= hi[:2] + 1e-3)
            if V[:, 2].max() > max_top_z or not inside or V[:, 2].min() < lo[2] - 0.002:
                world.remove_object(uid)
                continue
            world.set_pose(uid, T_rest)
            uids.append(uid)
            break
    return uids
