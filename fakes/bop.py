"""Write simulated scans as a BOP dataset with ground truth.

Layout (one folder per scene under ``test/``)::

    DIR/camera.json                     the camera (BOP)
    DIR/models/                         models_info.json + obj_XXXXXX.ply (mm), grasps.json
    DIR/test/000000/rgb/000000.png      one image per scan waypoint
    DIR/test/000000/depth/000000.png    uint16, depth_mm = value * depth_scale
    DIR/test/000000/mask_visib/000000_000001.png
    DIR/test/000000/scene_camera.json   cam_K, depth_scale, cam_R_w2c, cam_t_w2c (world = robot base, mm)
    DIR/test/000000/scene_gt.json       cam_R_m2c, cam_t_m2c (mm), obj_id
    DIR/test/000000/scene_gt_info.json  bbox_obj, bbox_visib, px_count_*, visib_fract
    DIR/test_targets_bop19.json         targets: objects at least 10 % visible
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import open3d as o3d
from PIL import Image

from kitchenbot.fakes.cameras import CameraModel, camera_model
from kitchenbot.fakes.render import Lighting, render, rgb_noise, stereo_noise
from kitchenbot.transforms import inv
from kitchenbot.world.raycast import pinhole_rays

TABLE_CAMERA_LIFT = 0.25  # m: the scan poses raised over a table (generate_dataset(surface="table"))
DEPTH_SCALE = 0.1  # BOP depth_scale: stored value x 0.1 = mm (sub-millimetre storage, as many BOP sets do)


@dataclass
class SceneSensor:
    """How one scene is seen: the camera model (intrinsics, depth error model), the light, and scales of the
    depth noise and dropout (the wide variety draws these per scene)."""

    camera: CameraModel
    lighting: Lighting
    noise_scale: float = 1.0
    dropout: float = 0.003

    def to_json(self) -> dict:
        return {"camera": self.camera.name, "lighting": asdict(self.lighting), "noise_scale": self.noise_scale,
                "dropout": self.dropout}


def random_sensor(camera: CameraModel, rng: np.random.Generator) -> SceneSensor:
    """Light from a random direction above, dimmer or brighter, warm or cool; depth noise x0.7-2, more dropouts."""
    az, el = rng.uniform(0, 2 * np.pi), rng.uniform(np.radians(35), np.radians(85))
    d = (float(np.cos(el) * np.cos(az)), float(np.cos(el) * np.sin(az)), float(np.sin(el)))
    warm = rng.uniform(-0.08, 0.08)
    light = Lighting(direction=d, ambient=float(rng.uniform(0.3, 0.6)), diffuse=float(rng.uniform(0.35, 0.7)),
                     tint=(1.0 + warm, 1.0, 1.0 - warm), exposure=float(rng.uniform(0.75, 1.2)))
    return SceneSensor(camera, light, float(rng.uniform(0.7, 2.0)), float(rng.uniform(0.002, 0.01)))


def _bbox(mask: np.ndarray) -> list[int]:
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]


def _alone_mask(world, uid: int, K: np.ndarray, T_base_cam: np.ndarray, w: int, h: int) -> np.ndarray:
    """Pixels the object would cover with nothing in front of it (for visib_fract)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(world.object_mesh(uid)))
    rays = pinhole_rays(K, inv(T_base_cam), w, h)
    return np.isfinite(scene.cast_rays(rays)["t_hit"].numpy())


def write_scene(world, scene_dir: Path, camera_poses: list[np.ndarray], K: np.ndarray, width: int, height: int,
                rng: np.random.Generator, reported_poses: list[np.ndarray] | None = None,
                sensor: SceneSensor | None = None) -> dict:
    """Render the world from each true camera pose and write one BOP scene. Returns counts.

    `sensor`: the camera's depth model, the light and the noise level (default: the OAK-D, the fixed light)."""
    for sub in ("rgb", "depth", "mask_visib"):
        (scene_dir / sub).mkdir(parents=True, exist_ok=True)
    reported_poses = reported_poses or camera_poses
    scene_camera, scene_gt, scene_gt_info = {}, {}, {}
    uids = sorted(world.objects)
    for im_id, (T_true, T_rep) in enumerate(zip(camera_poses, reported_poses)):
        if sensor is None:
            r = render(world, K, T_true, width, height)
            depth = stereo_noise(r.depth, r.cos_incidence, K, rng)
        else:
            r = render(world, K, T_true, width, height, sensor.lighting)
            depth = sensor.camera.depth_noise(r.depth, r.cos_incidence, K, rng, sensor.noise_scale, sensor.dropout)
        Image.fromarray(rgb_noise(r.rgb, rng)).save(scene_dir / "rgb" / f"{im_id:06d}.png")
        d = np.round(np.nan_to_num(depth) * 1000.0 / DEPTH_SCALE).clip(0, 65535).astype(np.uint16)
        Image.fromarray(d).save(scene_dir / "depth" / f"{im_id:06d}.png")
        T_cam_base = inv(T_rep)
        scene_camera[str(im_id)] = {
            "cam_K": K.reshape(-1).tolist(),
            "depth_scale": DEPTH_SCALE,
            "cam_R_w2c": T_cam_base[:3, :3].reshape(-1).tolist(),
            "cam_t_w2c": (T_cam_base[:3, 3] * 1000.0).tolist(),
        }
        gts, infos = [], []
        T_cam_base_true = inv(T_true)
        for k, uid in enumerate(uids):
            o = world.objects[uid]
            T_cam_obj = T_cam_base_true @ o.T_base_obj
            gts.append({
                "cam_R_m2c": T_cam_obj[:3, :3].reshape(-1).tolist(),
                "cam_t_m2c": (T_cam_obj[:3, 3] * 1000.0).tolist(),
                "obj_id": int(o.model.obj_id),
            })
            visib = r.labels == uid
            alone = _alone_mask(world, uid, K, T_true, width, height)
            valid = visib & (depth > 0)
            Image.fromarray((visib * 255).astype(np.uint8)).save(scene_dir / "mask_visib" / f"{im_id:06d}_{k:06d}.png")
            n_all = int(alone.sum())
            infos.append({
                "bbox_obj": _bbox(alone),
                "bbox_visib": _bbox(visib),
                "px_count_all": n_all,
                "px_count_valid": int((alone & (depth > 0)).sum()),
                "px_count_visib": int(visib.sum()),
                "visib_fract": float(visib.sum() / n_all) if n_all else 0.0,
            })
            _ = valid
        scene_gt[str(im_id)] = gts
        scene_gt_info[str(im_id)] = infos
    (scene_dir / "scene_camera.json").write_text(json.dumps(scene_camera))
    (scene_dir / "scene_gt.json").write_text(json.dumps(scene_gt))
    (scene_dir / "scene_gt_info.json").write_text(json.dumps(scene_gt_info))
    return {"images": len(camera_poses), "objects": len(uids)}


def write_camera_and_models(out: Path, inventory, K: np.ndarray, width: int, height: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    inventory.save_bop(out / "models", out / "models" / "grasps.json")
    (out / "camera.json").write_text(json.dumps({
        "cx": K[0, 2], "cy": K[1, 2], "fx": K[0, 0], "fy": K[1, 1],
        "width": width, "height": height, "depth_scale": DEPTH_SCALE,
    }, indent=1))


def write_targets(out: Path, min_visib: float = 0.1, target_ids: set[int] | None = None) -> int:
    """test_targets_bop19.json from every scene's gt and gt_info (objects in `target_ids` only, if given:
    distractors are not targets)."""
    targets = []
    for scene_dir in sorted((out / "test").iterdir()):
        gt = json.loads((scene_dir / "scene_gt.json").read_text())
        info = json.loads((scene_dir / "scene_gt_info.json").read_text())
        for im_id, recs in gt.items():
            counts: dict[int, int] = {}
            for rec, inf in zip(recs, info[im_id]):
                if inf["visib_fract"] >= min_visib and (target_ids is None or rec["obj_id"] in target_ids):
                    counts[rec["obj_id"]] = counts.get(rec["obj_id"], 0) + 1
            targets += [{"scene_id": int(scene_dir.name), "im_id": int(im_id), "obj_id": o, "inst_count": c}
                        for o, c in sorted(counts.items())]
    (out / "test_targets_bop19.json").write_text(json.dumps(targets))
    return len(targets)


VARIETIES = ("default", "wide")


def generate_dataset(
    out: Path,
    n_scenes: int,
    seed: int,
    waypoints: list[np.ndarray],
    world_kwargs: dict,
    width: int = 640,
    height: int = 480,
    pose_noise_m: float = 0.0,
    pose_noise_deg: float = 0.0,
    scene_options=None,
    progress=None,
    variety: str = "default",
    distractors: int = 0,
    camera: str = "oakd",
    surface: str = "sink",
) -> dict:
    """Generate `n_scenes` random sink scenes (seeds seed..seed+n-1) scanned from `waypoints`.

    `world_kwargs` go to SimWorld (robot, T_flange_tcp, T_flange_cam). With pose noise, images are rendered
    from perturbed camera poses while scene_camera.json records the unperturbed (reported) ones.

    `variety="wide"`: the inventory grows by one new member of each dishware family (fakes/dish_families.py,
    drawn from `seed`), each scene gets sink fixtures (rounded corners, drain, faucet, floor grid), its own
    basin size and depth, light and depth-noise level. `distractors`: that many non-inventory objects per
    scene (a set of models drawn from `seed`, written to models_distractors/; their ground truth is in
    scene_gt.json like any object's, and they are not targets). `camera`: fakes/cameras.py's model.
    `surface="table"`: the items stand on a flat board over the basin's opening (fakes/scenes.py), no sink.
    The defaults give the original datasets exactly.
    """
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from kitchenbot.fakes.scenes import SceneOptions, generate_scene
    from kitchenbot.transforms import make_T, trans
    from kitchenbot.world.inventory import Inventory

    if variety not in VARIETIES:
        raise ValueError(f"variety: expected one of {VARIETIES}, got {variety!r}")
    if distractors < 0:
        raise ValueError(f"distractors: expected a count >= 0, got {distractors}")
    out = Path(out)
    cam = camera_model(camera)
    inventory = Inventory.builtin()
    if variety == "wide":
        from kitchenbot.fakes.dish_families import sample_dishware

        models = list(inventory) + sample_dishware(np.random.default_rng([seed, 7]), first_id=len(inventory) + 1)
        inventory = Inventory(models, f"builtin+families(seed {seed})")
    K = cam.intrinsics(width, height)
    write_camera_and_models(out, inventory, K, width, height)
    opts = scene_options or SceneOptions()
    if variety == "wide" or distractors:
        opts = replace(opts, fixtures=variety == "wide", vary_sink=variety == "wide")
    if surface != "sink":
        opts = replace(opts, surface=surface)
    if distractors:
        from kitchenbot.fakes.distractors import sample_distractors

        d_models = sample_distractors(np.random.default_rng([seed, 11]), max(6, 2 * distractors))
        Inventory(d_models, "distractors").save_bop(out / "models_distractors",
                                                    out / "models_distractors" / "grasps.json")
        opts = replace(opts, distractors=distractors, distractor_models=d_models)
    default_sensor = variety == "default" and camera == "oakd"
    total_objects = 0
    for i in range(n_scenes):
        world = generate_scene(seed + i, inventory, options=opts, world_kwargs=world_kwargs)
        rng = np.random.default_rng(10_000 + seed + i)
        reported, true = [], []
        for q in waypoints:
            world.set_joints(np.asarray(q, float))
            T = world.T_base_cam()
            if surface == "table":
                # The scan waypoints look into a 20 cm deep basin; over a table the camera stands higher, as
                # desk frames are taken (YCB-Video, LM-O: 0.5-1 m away), the same view directions.
                T = trans(0.0, 0.0, TABLE_CAMERA_LIFT) @ T
            reported.append(T)
            if pose_noise_m > 0 or pose_noise_deg > 0:
                rv = rng.normal(size=3)
                rv *= np.radians(pose_noise_deg) / np.linalg.norm(rv)
                dt = rng.normal(size=3)
                dt *= pose_noise_m / np.linalg.norm(dt)
                T = T @ make_T(Rotation.from_rotvec(rv).as_matrix(), dt)
            true.append(T)
        sensor = None
        if not default_sensor:
            sensor = (random_sensor(cam, np.random.default_rng([seed + i, 3])) if variety == "wide"
                      else SceneSensor(cam, Lighting()))
        stats = write_scene(world, out / "test" / f"{i:06d}", true, K, width, height, rng, reported, sensor)
        meta = {"seed": seed + i, "style": world.cell.spec.sink.style,
                "objects": [{"obj_id": o.model.obj_id, "name": o.model.name} for o in world.objects.values()]}
        if not default_sensor or distractors or surface != "sink":
            meta.update(variety=variety, cell=world.cell.spec.model_dump(mode="json"),
                        fixtures=sorted(world.fixtures), sensor=sensor.to_json() if sensor else None,
                        distractors=[{"obj_id": o.model.obj_id, "name": o.model.name} for o in world.objects.values()
                                     if o.model.obj_id not in inventory.models])
            if surface != "sink":  # the cell's basin is covered: no cell describes this scene
                meta["surface"] = surface
                del meta["cell"]
        (out / "test" / f"{i:06d}" / "scene_sim.json").write_text(json.dumps(meta, indent=1))
        total_objects += stats["objects"]
        if progress is not None:
            progress(i + 1, n_scenes)
    n_targets = write_targets(out, target_ids=set(inventory.models))
    n_distractors = sum(len(json.loads((out / "test" / f"{i:06d}" / "scene_sim.json").read_text()).get("distractors", []))
                        for i in range(n_scenes))
    return {"scenes": n_scenes, "objects": total_objects, "targets": n_targets, "images": n_scenes * len(waypoints),
            "distractors": n_distractors, "inventory": len(inventory)}
