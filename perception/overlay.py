"""PNG overlays: model contours at the estimated poses (coloured, with the object id) and at the ground
truth (thin white), drawn over each image of chosen scenes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import open3d as o3d

from kitchenbot.perception import bop
from kitchenbot.world.inventory import Inventory
from kitchenbot.world.raycast import pinhole_rays


def silhouette(mesh: o3d.geometry.TriangleMesh, T_cam_obj: np.ndarray, K: np.ndarray, w: int, h: int) -> np.ndarray:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    # The extrinsic is world->camera; the mesh's "world" is the object frame.
    rays = pinhole_rays(K, T_cam_obj, w, h)
    return np.isfinite(scene.cast_rays(rays)["t_hit"].numpy())


def _colour(obj_id: int) -> tuple[int, int, int]:
    rng = np.random.default_rng(obj_id * 7919)
    c = rng.integers(80, 256, 3)
    return int(c[0]), int(c[1]), int(c[2])


def draw(rgb: np.ndarray, K: np.ndarray, inventory: Inventory, est: list[tuple[int, np.ndarray, float]],
         gt: list[tuple[int, np.ndarray]]) -> np.ndarray:
    """BGR image with GT contours (white, thin) and estimate contours (coloured, labelled)."""
    h, w = rgb.shape[:2]
    img = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    img = (img * 0.7).astype(np.uint8)
    for oid, T in gt:
        m = silhouette(inventory[oid].mesh, T, K, w, h).astype(np.uint8)
        cs, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(img, cs, -1, (255, 255, 255), 1)
    for oid, T, score in est:
        m = silhouette(inventory[oid].mesh, T, K, w, h).astype(np.uint8)
        cs, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        col = _colour(oid)
        cv2.drawContours(img, cs, -1, col, 2)
        if cs:
            x, y, _, _ = cv2.boundingRect(max(cs, key=cv2.contourArea))
            cv2.putText(img, f"{inventory[oid].name} {score:.2f}", (x, max(12, y - 4)), cv2.FONT_HERSHEY_SIMPLEX,
                        0.45, col, 1, cv2.LINE_AA)
    return img


def write_overlays(dataset: str | Path, estimates, out_dir: str | Path, scenes: list[int] | None = None,
                   split: str | None = None, max_scenes: int = 3, inventory: Inventory | None = None) -> int:
    """Draw the estimates (perception.evaluate.Estimate) of the chosen scenes; returns the number of PNGs."""
    root = Path(dataset)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if inventory is None:
        md = bop.models_dir(root)
        inventory = Inventory.load(md, md / "grasps.json" if (md / "grasps.json").is_file() else None)
    by_im: dict[tuple[int, int], list] = {}
    for e in estimates:
        by_im.setdefault((e.scene_id, e.im_id), []).append((e.obj_id, e.T_cam_obj, e.score))
    dirs = bop.scene_dirs(root, split)
    if scenes:
        dirs = [d for d in dirs if d.name.isdigit() and int(d.name) in scenes]
    else:
        dirs = [d for d in dirs if d.name.isdigit() and any(k[0] == int(d.name) for k in by_im)][:max_scenes]
    n = 0
    for sd in dirs:
        for im in bop.read_scene(sd):
            est = by_im.get((im.scene_id, im.im_id), [])
            gt = [(g.obj_id, g.T_cam_obj) for g in im.gt if g.obj_id in inventory.models]
            img = draw(im.view.rgb, im.view.K, inventory, est, gt)
            cv2.imwrite(str(out / f"{im.scene_id:06d}_{im.im_id:06d}.png"), img)
            n += 1
    return n
