"""Reading BOP datasets (https://bop.felk.cvut.cz/datasets/): scenes, images as Views, ground truth.

Layout: DATASET/models/ (or models_eval/) and scene folders DATASET/<split>/<scene_id>/ holding
scene_camera.json, scene_gt.json, scene_gt_info.json, rgb/ (or gray/), depth/. Units: mm; depth PNG values
x depth_scale = mm. When scene_camera.json gives cam_R_w2c/cam_t_w2c for every image, the scene's images
are views of one world (the robot base) and are fused; otherwise each image is a view on its own.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from kitchenbot.perception.types import View
from kitchenbot.transforms import inv, make_T


class BopError(ValueError):
    """A BOP dataset file is missing or malformed."""


@dataclass
class GtObject:
    obj_id: int
    T_cam_obj: np.ndarray  # metres
    visib_fract: float


@dataclass
class BopImage:
    scene_id: int
    im_id: int
    view: View  # T_base_cam = world pose when known, else identity
    gt: list[GtObject]
    has_world_pose: bool


def _json(path: Path) -> dict | list:
    try:
        return json.loads(path.read_text())
    except OSError:
        raise BopError(f"{path}: missing (a BOP scene folder needs it)") from None
    except json.JSONDecodeError as e:
        raise BopError(f"{path}: not valid JSON ({e})") from None


def models_dir(root: Path) -> Path:
    for name in ("models", "models_eval"):
        if (root / name / "models_info.json").is_file():
            return root / name
    raise BopError(f"{root}: no models/models_info.json (or models_eval/) - is this a BOP dataset folder?")


def scene_dirs(root: Path, split: str | None = None) -> list[Path]:
    """Scene folders (containing scene_camera.json) of the split, or of every split found."""
    base = root / split if split else root
    if not base.is_dir():
        raise BopError(f"{base}: no such folder")
    found = sorted({p.parent for p in base.glob("*/scene_camera.json")} | {p.parent for p in base.glob("*/*/scene_camera.json")})
    if not found:
        raise BopError(f"{base}: no scene folders (*/scene_camera.json) found")
    return found


def _find_image(scene: Path, sub: tuple[str, ...], im_id: int) -> Path:
    for s in sub:
        for ext in (".png", ".jpg", ".tif"):
            p = scene / s / f"{im_id:06d}{ext}"
            if p.is_file():
                return p
    raise BopError(f"{scene}: no {'/'.join(sub)} image for im_id {im_id}")


def read_scene(scene: Path, im_ids: list[int] | None = None) -> list[BopImage]:
    cams = _json(scene / "scene_camera.json")
    gts = _json(scene / "scene_gt.json") if (scene / "scene_gt.json").is_file() else {}
    infos = _json(scene / "scene_gt_info.json") if (scene / "scene_gt_info.json").is_file() else {}
    scene_id = int(scene.name) if scene.name.isdigit() else 0
    out = []
    for key in sorted(cams, key=int):
        im_id = int(key)
        if im_ids is not None and im_id not in im_ids:
            continue
        cam = cams[key]
        try:
            K = np.asarray(cam["cam_K"], float).reshape(3, 3)
            scale = float(cam.get("depth_scale", 1.0))
        except (KeyError, ValueError) as e:
            raise BopError(f"{scene / 'scene_camera.json'}: image {key}: bad or missing cam_K ({e})") from None
        world = "cam_R_w2c" in cam and "cam_t_w2c" in cam
        T_base_cam = np.eye(4)
        if world:
            T_w2c = make_T(np.asarray(cam["cam_R_w2c"], float).reshape(3, 3), np.asarray(cam["cam_t_w2c"], float) / 1000)
            T_base_cam = inv(T_w2c)
        rgb = np.asarray(Image.open(_find_image(scene, ("rgb", "gray"), im_id)).convert("RGB"))
        depth = np.asarray(Image.open(_find_image(scene, ("depth",), im_id)), np.float32) * scale / 1000.0
        if depth.shape != rgb.shape[:2]:
            raise BopError(f"{scene}: image {im_id}: depth {depth.shape} and rgb {rgb.shape[:2]} differ in size")
        gt = []
        for k, rec in enumerate(gts.get(key, [])):
            T = make_T(np.asarray(rec["cam_R_m2c"], float).reshape(3, 3), np.asarray(rec["cam_t_m2c"], float) / 1000)
            vf = infos.get(key, [{}] * (k + 1))[k].get("visib_fract", 1.0) if key in infos else 1.0
            gt.append(GtObject(int(rec["obj_id"]), T, float(vf)))
        out.append(BopImage(scene_id, im_id, View(rgb, depth, K, T_base_cam, float(im_id)), gt, world))
    return out


def view_groups(images: list[BopImage], fuse: bool = True) -> list[list[BopImage]]:
    """Images perceived together: a whole scene when all its images have world poses, else one by one."""
    if fuse and images and all(im.has_world_pose for im in images):
        return [images]
    return [[im] for im in images]
