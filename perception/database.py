"""CAD feature database (paper III-C "Database preparation").

Each model is rendered from viewpoints around it (Open3D RaycastingScene: colour from the mesh's vertex
colours or the model colour, Lambert shading with a head light). Per rendered view we keep the image class
token and the mean point feature of the visible surface (used for candidate proposal); per model the
reference cloud P_ref (voxel centres of the whole surface, outward normals) with fused features F_ref
(image features back-projected from the renders, point features on P_ref).

Built once per inventory + backends + voxel size and cached on disk (npz) under a key hashing all three.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from kitchenbot.perception.features import FusedCloud, ImageEncoder, PointEncoder, l2n, oriented_normals, voxel_pool
from kitchenbot.transforms import inv
from kitchenbot.world.inventory import Inventory, ObjectModel
from kitchenbot.world.raycast import pinhole_rays

DB_VERSION = 3
# Metres per unit of normal difference in `ModelEntry.oriented_tree`: the far side of a 4-5 mm plate or cup
# wall (opposite normal, difference 2) is 30 mm away there; a 15 deg normal error costs ~4 mm.
NORMAL_WEIGHT = 0.015


@dataclass
class ModelEntry:
    obj_id: int
    ref: FusedCloud  # object frame
    view_cls: np.ndarray  # (V, Di) image class tokens of the rendered views
    view_geo: np.ndarray  # (V, Dp) mean point features of the rendered views
    dense_points: np.ndarray  # (Nd, 3) object frame, for scoring (finer than the voxel grid)
    dense_normals: np.ndarray  # (Nd, 3)

    @cached_property
    def ref_tree(self) -> cKDTree:
        """KD-tree over the voxel-level reference points (object frame)."""
        return cKDTree(self.ref.points)

    @cached_property
    def tree(self) -> cKDTree:
        """KD-tree over the dense surface points (object frame)."""
        return cKDTree(self.dense_points)

    @cached_property
    def reach(self) -> float:
        """Farthest dense surface point from the object origin (metres): nothing farther is near the surface."""
        return float(np.sqrt((self.dense_points.astype(np.float64) ** 2).sum(axis=1).max())) \
            if len(self.dense_points) else 0.0

    @cached_property
    def fused_features(self) -> np.ndarray:
        """The reference points' fused features, float64, one row per point (perception.register.feature_matches)."""
        return np.ascontiguousarray(self.ref.fused, dtype=np.float64)

    @cached_property
    def oriented_tree(self) -> cKDTree:
        """KD-tree over (point, NORMAL_WEIGHT x outward normal) of the dense surface: a nearest neighbour here
        is a near point whose surface faces the same way (a thin wall's far side is not one)."""
        return cKDTree(np.hstack([self.dense_points, NORMAL_WEIGHT * self.dense_normals]))


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_cam of an OpenCV camera (z forward, y down) at `eye` looking at `target`."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    up = np.asarray(up, float)
    if abs(z @ up) > 0.99:
        up = np.array([0.0, 1.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def render_model(model: ObjectModel, T_obj_cam: np.ndarray, K: np.ndarray, size=(160, 160)):
    """(rgb uint8, mask, points in the object frame per pixel) of the model alone."""
    scene = o3d.t.geometry.RaycastingScene()
    tm = o3d.t.geometry.TriangleMesh.from_legacy(model.mesh)
    scene.add_triangles(tm)
    w, h = size
    rays = pinhole_rays(K, inv(T_obj_cam), w, h)
    ans = scene.cast_rays(rays)
    t = ans["t_hit"].numpy()
    mask = np.isfinite(t)
    r = rays.numpy()
    pts = r[..., :3] + r[..., 3:] * np.where(mask, t, 0)[..., None]
    n = ans["primitive_normals"].numpy()
    d = r[..., 3:] / np.linalg.norm(r[..., 3:], axis=-1, keepdims=True)
    shade = 0.35 + 0.65 * np.abs(np.sum(n * d, axis=-1))
    if model.mesh.has_vertex_colors():
        tri = np.asarray(model.mesh.triangles)
        vc = np.asarray(model.mesh.vertex_colors)
        pid = np.where(mask, ans["primitive_ids"].numpy(), 0).astype(np.int64)
        uv = ans["primitive_uvs"].numpy()
        bary = np.stack([1 - uv[..., 0] - uv[..., 1], uv[..., 0], uv[..., 1]], -1)
        col = np.einsum("hwk,hwkc->hwc", bary, vc[tri[pid]])
    else:
        col = np.broadcast_to(np.asarray(model.colour, float), mask.shape + (3,))
    rgb = np.clip(col * shade[..., None] * 255, 0, 255).astype(np.uint8)
    rgb[~mask] = 0
    return rgb, mask, pts


def _view_dirs() -> list[np.ndarray]:
    out = []
    for el in (65, 30, -10, -45):
        for az in range(0, 360, 90 if abs(el) > 40 else 60):
            e, a = np.radians(el), np.radians(az + (45 if el < 0 else 0))
            out.append(np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]))
    out += [np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])]
    return out


def build_entry(model: ObjectModel, voxel: float, img_enc: ImageEncoder | None, pt_enc: PointEncoder) -> ModelEntry:
    # Reference surface: dense Poisson-disk samples with triangle normals (outward), pooled per voxel.
    area = model.mesh.get_surface_area()
    n_dense = int(np.clip(area / (0.004**2), 1500, 20000))
    o3d.utility.random.seed(1)  # deterministic samples, so the cache and the results are reproducible
    pcd = model.mesh.sample_points_poisson_disk(n_dense, use_triangle_normal=True)
    dense, dense_n = np.asarray(pcd.points), np.asarray(pcd.normals)
    P, Nsum, inv_ = voxel_pool(dense, dense_n, voxel)
    N = l2n(Nsum)
    Fp = l2n(pt_enc.encode(P, N, voxel))
    # Renders: class tokens, per-view point-feature means, image features lifted onto P.
    f = 200.0
    K = np.array([[f, 0, 80], [0, f, 80], [0, 0, 1.0]])
    dist = 2.0 * model.diameter  # the model fills ~55 % of the 160 px render
    dim_i = img_enc.dim if img_enc else 0
    acc = np.zeros((len(P), dim_i))
    cnt = np.zeros(len(P))
    tree = cKDTree(P)
    view_cls, view_geo = [], []
    for d in _view_dirs():
        T = look_at(d * dist, np.zeros(3))
        rgb, mask, pts = render_model(model, T, K)
        if mask.sum() < 30:
            continue
        vis = pts[mask]
        vP, _, _ = voxel_pool(vis, None, voxel)
        vN = oriented_normals(vP, T[:3, 3], voxel)
        view_geo.append(l2n(pt_enc.encode(vP, vN, voxel).mean(axis=0)))
        if img_enc is not None:
            cls, patches = img_enc.encode(rgb, mask)
            view_cls.append(cls)
            h, w = patches.shape[:2]
            rows, cols = np.nonzero(mask)
            pf = patches[np.clip(rows * h // mask.shape[0], 0, h - 1), np.clip(cols * w // mask.shape[1], 0, w - 1)]
            dd, ii = tree.query(vis, distance_upper_bound=voxel)
            ok = np.isfinite(dd)
            np.add.at(acc, ii[ok], pf[ok])
            np.add.at(cnt, ii[ok], 1)
    if dim_i:
        seen = cnt > 0
        mean = acc[seen].sum(axis=0) / max(cnt[seen].sum(), 1)
        acc[seen] /= cnt[seen, None]
        acc[~seen] = mean
        Fi = l2n(acc)
        cls_all = l2n(np.mean(view_cls, axis=0))
    else:
        Fi, cls_all = np.zeros((len(P), 0)), np.zeros(0)
    ref = FusedCloud(P, N, Fi, Fp, cls_all, l2n(Fp.mean(axis=0)))
    return ModelEntry(model.obj_id, ref, np.array(view_cls).reshape(len(view_cls), dim_i), np.array(view_geo),
                      dense.astype(np.float32), dense_n.astype(np.float32))


class CadDatabase:
    def __init__(self, entries: dict[int, ModelEntry], key: str):
        self.entries = entries
        self.key = key

    def __getitem__(self, obj_id: int) -> ModelEntry:
        return self.entries[obj_id]

    @staticmethod
    def cache_key(inventory: Inventory, img_enc: ImageEncoder | None, pt_enc: PointEncoder, voxel: float) -> str:
        h = hashlib.sha1(json.dumps([DB_VERSION, inventory.fingerprint(), img_enc.name if img_enc else "none",
                                     pt_enc.name, round(voxel, 6)]).encode())
        return h.hexdigest()[:16]

    @classmethod
    def build(cls, inventory: Inventory, img_enc: ImageEncoder | None, pt_enc: PointEncoder, voxel: float,
              cache_dir: str | Path | None = None) -> "CadDatabase":
        key = cls.cache_key(inventory, img_enc, pt_enc, voxel)
        path = Path(cache_dir).expanduser() / f"cad_{key}.npz" if cache_dir else None
        if path is not None and path.is_file():
            try:
                return cls._load(path, key)
            except (OSError, KeyError, ValueError):
                pass  # a stale or partial cache file: rebuild it
        entries = {m.obj_id: build_entry(m, voxel, img_enc, pt_enc) for m in inventory}
        db = cls(entries, key)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            db._save(path)
        return db

    def _save(self, path: Path) -> None:
        arrs = {}
        for i, e in self.entries.items():
            r = e.ref
            for name, a in (("P", r.points), ("N", r.normals), ("Fi", r.img), ("Fp", r.pts), ("cls", r.cls_token),
                            ("geo", r.geo_token), ("vcls", e.view_cls), ("vgeo", e.view_geo),
                            ("dense", e.dense_points), ("dense_n", e.dense_normals)):
                arrs[f"{i}_{name}"] = a
        # A temporary file of this process's own, then an atomic rename: processes started together on the same
        # inventory (parallel benchmark workers, the three tasks at once) build and save the same entry; with one
        # shared temporary name the first rename took the other's file away (FileNotFoundError).
        tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
        np.savez_compressed(tmp, ids=np.array(sorted(self.entries)), **arrs)
        tmp.replace(path)

    @classmethod
    def _load(cls, path: Path, key: str) -> "CadDatabase":
        z = np.load(path)
        entries = {}
        for i in z["ids"]:
            i = int(i)
            g = lambda n: z[f"{i}_{n}"]  # noqa: E731
            ref = FusedCloud(g("P"), g("N"), g("Fi"), g("Fp"), g("cls"), g("geo"))
            entries[i] = ModelEntry(i, ref, g("vcls"), g("vgeo"), g("dense"), g("dense_n"))
        return cls(entries, key)
