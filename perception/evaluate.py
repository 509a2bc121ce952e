"""Evaluate the pipeline on a BOP dataset: BOP results CSV, a metrics report, overlays, hyperparameter sweeps.

The dataset's own models/ become the inventory. Scenes whose images carry world camera poses (cam_R_w2c,
cam_t_w2c; world = robot base) are perceived as one multi-view scan; other images one by one. Each
estimate is written once per image of its scan, in that image's camera frame (BOP convention).
"""

from __future__ import annotations

import csv
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kitchenbot.perception import bop
from kitchenbot.perception.metrics import adi, auc_adds, grasp_error_summary, match_image, match_scan
from kitchenbot.perception.pipeline import Perceiver, map_seg_ms, scan_total_ms
from kitchenbot.perception.rgbd import project_pixels
from kitchenbot.perception.settings import PerceptionSettings
from kitchenbot.transforms import inv
from kitchenbot.world.cell import Cell, CellSpec
from kitchenbot.world.inventory import Inventory, ObjectModel


@dataclass
class Estimate:
    scene_id: int
    im_id: int
    obj_id: int
    score: float
    T_cam_obj: np.ndarray
    time_s: float


@dataclass
class EvalResult:
    estimates: list[Estimate]
    report: dict
    per_scan: list[dict] = field(default_factory=list)


def _visible_in(view, T_base_obj: np.ndarray, pts_obj: np.ndarray) -> bool:
    """Whether the posed model lands (partly) inside the image in front of the camera."""
    P = pts_obj[:: max(1, len(pts_obj) // 200)] @ T_base_obj[:3, :3].T + T_base_obj[:3, 3]
    _, _, inside = project_pixels(view, P)
    return bool(inside.mean() > 0.1)


def _load_models(md: Path) -> Inventory:
    return Inventory.load(md, md / "grasps.json" if (md / "grasps.json").is_file() else None)


def load_inventory(root: Path, inventory: Inventory | str | Path | None = None,
                   object_ids: list[int] | None = None) -> tuple[Inventory, dict[int, np.ndarray], dict[int, str]]:
    """The inventory to find, and the points (object frame, metres) and names of every other model the
    dataset has (its distractors: anything in its ground truth that is not in the inventory).

    `inventory`: an Inventory, a BOP models folder, or None for the dataset's models/. `object_ids`: keep only
    these ids of it (e.g. the bowl and the mug of YCB-Video; the boxes and cans become distractors)."""
    if inventory is None or isinstance(inventory, (str, Path)):
        inventory = _load_models(Path(inventory) if inventory is not None else bop.models_dir(root))
    others: dict[int, ObjectModel] = {}
    if object_ids:
        missing = sorted(set(object_ids) - set(inventory.models))
        if missing:
            raise ValueError(f"--objects: ids {missing} are not in the inventory ({sorted(inventory.models)})")
        others = {m.obj_id: m for m in inventory if m.obj_id not in object_ids}
        inventory = Inventory([inventory[i] for i in object_ids], f"{inventory.source} ids {sorted(object_ids)}")
    try:
        for m in _load_models(bop.models_dir(root)):
            if m.obj_id not in inventory.models:
                others.setdefault(m.obj_id, m)
    except bop.BopError:
        pass
    if (root / "models_distractors" / "models_info.json").is_file():
        for m in _load_models(root / "models_distractors"):
            others.setdefault(m.obj_id, m)
    return inventory, {o: m.points for o, m in others.items()}, {o: m.name for o, m in others.items()}


def _scene_cell(scene_dir: Path) -> Cell | None:
    """The cell a generated scene was made in (scene_sim.json's "cell"), or None."""
    f = scene_dir / "scene_sim.json"
    if not f.is_file():
        return None
    spec = json.loads(f.read_text()).get("cell")
    return Cell(CellSpec.model_validate(spec)) if spec else None


def _on_distractor(T_cam_est: np.ndarray, est_pts: np.ndarray, distractors: list[tuple[np.ndarray, np.ndarray]],
                   tol: float = 0.015, share: float = 0.2) -> int:
    """Index of the distractor (posed points in the camera frame) that an estimate lies on: at least `share`
    of the estimate's posed model points within `tol` of that distractor's surface; -1 if none."""
    from scipy.spatial import cKDTree

    P = est_pts[:: max(1, len(est_pts) // 256)] @ T_cam_est[:3, :3].T + T_cam_est[:3, 3]
    for k, (_, Q) in enumerate(distractors):
        d, _ = cKDTree(Q).query(P, distance_upper_bound=tol)
        if np.mean(np.isfinite(d)) >= share:
            return k
    return -1


def evaluate(dataset: str | Path, settings: PerceptionSettings | None = None, cell: Cell | None = None,
             use_cell: str = "auto", split: str | None = None, scenes: list[int] | None = None,
             min_visib: float = 0.1, progress: bool = True, inventory: Inventory | str | Path | None = None,
             object_ids: list[int] | None = None) -> EvalResult:
    """`use_cell`: auto (the cell when images have world poses), always, never, or dataset (each generated
    scene's own cell from its scene_sim.json, else `cell`). Objects of the ground truth that are not in the
    inventory are distractors: estimates on them are counted as `false_positives_on_distractors`."""
    root = Path(dataset)
    settings = settings or PerceptionSettings()
    if use_cell not in ("auto", "always", "never", "dataset"):
        raise ValueError(f"--cell: expected auto, always, never or dataset, got {use_cell!r}")
    inventory, distractor_pts, distractor_names = load_inventory(root, inventory, object_ids)
    dirs = bop.scene_dirs(root, split)
    if scenes:
        dirs = [d for d in dirs if d.name.isdigit() and int(d.name) in scenes]
        if not dirs:
            raise ValueError(f"--scenes: none of {scenes} is in {root}")
    perceivers: dict[object, Perceiver] = {}

    def perceiver(mode: str, scene_cell: Cell | None = None) -> Perceiver:
        """One Perceiver per cell mode (auto / always / never) and cell (`scene_cell`: --cell dataset)."""
        c = None if mode == "never" else (scene_cell or cell or Cell())
        key = (mode, c.spec.model_dump_json() if c is not None else None)
        if key not in perceivers:
            db = next(iter(perceivers.values())).database if perceivers else None
            perceivers[key] = Perceiver(settings, inventory, c, database=db, use_cell=mode)
        return perceivers[key]

    estimates: list[Estimate] = []
    errors: list[float] = []
    diam_thr: list[float] = []
    per_obj: dict[int, list[bool]] = {}
    false_pos = 0
    timings: dict[str, list[float]] = {}
    pose_ms: list[float] = []
    pose_cpu_ms: list[float] = []
    timings_cpu: dict[str, list[float]] = {}
    mapseg_cpu: list[float] = []
    scan_cpu: list[float] = []
    scan_ms: list[float] = []
    per_scan = []
    rejected = 0
    sources: dict[str, int] = {}
    cell_misfits: list[dict] = []
    grasp_err: dict[str, list] = {}  # class name -> [translations, tilts, extra count]
    pts = {m.obj_id: m.points for m in inventory}
    n_images = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(dirs), desc="scenes", unit="scene", dynamic_ncols=True)
    dfp: dict[str, int] = {}  # distractor name -> estimates on it
    distractors_seen = 0
    for sd in dirs:
        images = bop.read_scene(sd)
        scene_cell = _scene_cell(sd) if use_cell == "dataset" else None
        for group in bop.view_groups(images):
            # Images without world poses have no gravity: no cell to check, no surfaces to find but their own
            # dominant plane (unless the cell is asked for always). --cell dataset: the scene's own cell, always.
            world = group[0].has_world_pose
            want = "always" if use_cell == "dataset" else use_cell
            mode = want if world else ("always" if use_cell == "always" else "never")
            p = perceiver(mode, scene_cell)
            t0 = time.perf_counter()
            res = p.perceive([im.view for im in group], up=np.array([0.0, 0.0, 1.0]) if world else None)
            dt = time.perf_counter() - t0
            rejected += res.rejected
            sources[res.surfaces_from] = sources.get(res.surfaces_from, 0) + 1
            if res.cell_check is not None and not res.cell_check.fits:
                cell_misfits.append({"scene_id": group[0].scene_id, "im_ids": [im.im_id for im in group],
                                     "behind": round(res.cell_check.behind, 4), "message": res.cell_check.message})
            scan_ms.append(1000 * dt)
            pose_ms += res.pose_ms
            pose_cpu_ms += res.pose_cpu_ms
            for k, v in res.timings_ms.items():
                timings.setdefault(k, []).append(v)
            for k, v in res.timings_cpu_ms.items():
                timings_cpu.setdefault(k, []).append(v)
            mapseg_cpu.append(map_seg_ms(res.timings_cpu_ms))
            scan_cpu.append(scan_total_ms(res.timings_cpu_ms))
            if len(group) > 1 or group[0].has_world_pose:
                _scan_errors(group, res.poses, inventory, min_visib, grasp_err)
            for im, view in zip(group, res.views):
                n_images += 1
                est = []
                for po in res.poses:
                    if len(group) > 1 and not _visible_in(view, po.T_base_obj, pts[po.obj_id]):
                        continue
                    T = inv(view.T_base_cam) @ po.T_base_obj
                    est.append((po.obj_id, T, po.score))
                    estimates.append(Estimate(im.scene_id, im.im_id, po.obj_id, po.score, T, dt))
                gt = [(g.obj_id, g.T_cam_obj) for g in im.gt if g.visib_fract >= min_visib and g.obj_id in pts]
                # An estimate that is right about an object seen too little to be a target in this image (BOP:
                # visib_fract < min_visib; multi-view scans see it from the other views), and right about no target,
                # is ignored: neither matched (it would be paired with another target of its model and count as
                # wrong, a miss there too) nor a false positive.
                low = [(g.obj_id, g.T_cam_obj) for g in im.gt if g.visib_fract < min_visib and g.obj_id in pts]
                est = [e for e in est if not _right_about_only(e, low, gt, pts, inventory)]
                matches, unmatched = match_image(gt, est, pts)
                ok_count = 0
                for mt in matches:
                    d = inventory[gt[mt.gt_index][0]].diameter
                    errors.append(mt.error)
                    diam_thr.append(0.1 * d)
                    ok = mt.error < 0.1 * d
                    ok_count += ok
                    per_obj.setdefault(gt[mt.gt_index][0], []).append(bool(ok))
                    if mt.est_index >= 0 and not ok:
                        false_pos += 1
                wrong = [mt.est_index for mt in matches if mt.est_index >= 0 and not mt.error < 0.1 * inventory[gt[mt.gt_index][0]].diameter]
                for j in unmatched:  # one right about such an object and about a target too (nested plates): ignored
                    oid, T, _ = est[j]
                    if not any(o == oid and adi(T, Tg, pts[oid][::4]) < 0.1 * inventory[oid].diameter for o, Tg in low):
                        false_pos += 1
                        wrong.append(j)
                # False positives that lie on an object outside the inventory (a box, a can, a sponge).
                dis = [(g.obj_id, distractor_pts[g.obj_id] @ g.T_cam_obj[:3, :3].T + g.T_cam_obj[:3, 3])
                       for g in im.gt if g.obj_id in distractor_pts and g.visib_fract > 0]
                distractors_seen += sum(1 for g in im.gt if g.obj_id in distractor_pts and g.visib_fract >= min_visib)
                for j in wrong if dis else []:
                    k = _on_distractor(est[j][1], pts[est[j][0]], dis)
                    if k >= 0:
                        name = distractor_names[dis[k][0]]
                        dfp[name] = dfp.get(name, 0) + 1
                per_scan.append({"scene_id": im.scene_id, "im_id": im.im_id, "gt": len(gt), "estimates": len(est),
                                 "correct": int(ok_count)})
        if bar is not None:
            bar.update(1)
            if errors:
                bar.set_postfix(adi=f"{np.mean(np.array(errors) < np.array(diam_thr)):.3f}")
    if bar is not None:
        bar.close()
    e = np.array(errors)
    report = {
        "dataset": str(root),
        "adi_recall_0.1d": float(np.mean(e < np.array(diam_thr))) if len(e) else 0.0,
        "auc_adds_10cm": auc_adds(e),
        "per_object": {str(o): {"name": inventory[o].name, "recall": float(np.mean(v)), "n": len(v)}
                       for o, v in sorted(per_obj.items())},
        "false_positives": int(false_pos),  # per image: unmatched (and not a low-visibility object) or wrong
        "false_positives_per_image": float(false_pos / n_images) if n_images else 0.0,
        # Of those, the ones on an object outside the inventory (its ground truth is in the dataset), by name.
        "false_positives_on_distractors": int(sum(dfp.values())),
        "false_positives_on_distractors_by_name": dict(sorted(dfp.items())),
        "distractors": int(distractors_seen),  # distractor instances at least min_visib visible, over images
        "inventory": sorted(inventory.models),
        # Instances no inventory model explained (left in the map as obstacles), summed over scans.
        "rejected": int(rejected),
        "cell": use_cell,
        "surfaces_from": sources,  # scans segmented with the cell's surfaces / found in the data / per view plane
        "cell_misfits": cell_misfits,  # --cell auto: scans whose configured cell did not fit (not used there)
        "objects": int(len(e)),
        "estimates": len(estimates),
        "scenes": len(dirs),
        "images": n_images,
        "min_visib_fract": min_visib,
        "timing_median_ms": {k: float(np.median(v)) for k, v in timings.items()},
        "pose_ms_per_object_median": float(np.median(pose_ms)) if pose_ms else 0.0,
        # Process CPU time (what the work costs; wall time on a shared machine includes waiting for a core).
        "timing_cpu_median_ms": {k: float(np.median(v)) for k, v in timings_cpu.items()},
        "pose_cpu_ms_per_object_median": float(np.median(pose_cpu_ms)) if pose_cpu_ms else 0.0,
        # Everything before the poses (cell check, alignment, surfaces, segmentation, association, fusion).
        "map_seg_cpu_ms_per_scan_median": float(np.median(mapseg_cpu)) if mapseg_cpu else 0.0,
        "scan_cpu_ms_max": float(np.max(scan_cpu)) if scan_cpu else 0.0,
        "scan_ms_median": float(np.median(scan_ms)) if scan_ms else 0.0,
        "settings": settings.model_dump(mode="json"),
        # Per scan in the base frame, per model: position and axis errors, missed and extra (duplicate or
        # phantom) objects; `within`: fraction of objects within 1 cm and 5 deg (what a grasp can absorb).
        "grasp_errors": {name: grasp_error_summary(*v) for name, v in sorted(grasp_err.items())},
    }
    if grasp_err:
        report["grasp_errors"]["all"] = grasp_error_summary(
            [t for v in grasp_err.values() for t in v[0]], [a for v in grasp_err.values() for a in v[1]],
            sum(v[2] for v in grasp_err.values()))
    return EvalResult(estimates, report, per_scan)


def _right_about_only(e: tuple, low: list, gt: list, pts: dict, inventory: Inventory) -> bool:
    """Estimate `e` (obj_id, T_cam_obj, score) lies within 0.1 d (ADI) of an object of its model in `low` and of
    none in `gt`."""
    oid, T, _ = e
    thr = 0.1 * inventory[oid].diameter

    def near(items):
        return any(o == oid and adi(T, Tg, pts[oid][::4]) < thr for o, Tg in items)
    return near(low) and not near(gt)


def _scan_errors(group: list, poses: list, inventory: Inventory, min_visib: float, acc: dict) -> None:
    """Add one scan's grasp-relevant errors to `acc` (class name -> [translations, tilts, extra count]): the
    scan's ground truth (objects at least `min_visib` visible in one of its images, base frame) matched to
    its estimates by position (metrics.match_scan)."""
    gt: list[tuple[int, np.ndarray]] = []
    low: list[tuple[int, np.ndarray]] = []  # seen too little in every image to be a target
    for im in group:
        for g in im.gt:
            if g.obj_id not in inventory.models:
                continue
            T = im.view.T_base_cam @ g.T_cam_obj
            if not any(o == g.obj_id and np.linalg.norm(Tg[:3, 3] - T[:3, 3]) < 0.005 for o, Tg in gt + low):
                (gt if g.visib_fract >= min_visib else low).append((g.obj_id, T))
            elif g.visib_fract >= min_visib:  # a target in this image, though too little seen in an earlier one
                low = [(o, Tg) for o, Tg in low if not (o == g.obj_id and np.linalg.norm(Tg[:3, 3] - T[:3, 3]) < 0.005)]
                if not any(o == g.obj_id and np.linalg.norm(Tg[:3, 3] - T[:3, 3]) < 0.005 for o, Tg in gt):
                    gt.append((g.obj_id, T))
    est = [(p.obj_id, p.T_base_obj) for p in poses]
    diam = {m.obj_id: m.diameter for m in inventory}
    matches, extra = match_scan(gt, est, diam)
    # An estimate of an object no image saw enough to make it a target (the lowest plate of a stack) is right,
    # not extra (as for the per-image false positives).
    if low:
        _, still = match_scan(low, [est[j] for j in extra], diam)
        extra = [extra[k] for k in still]
    for mt in matches:
        v = acc.setdefault(inventory[gt[mt.gt_index][0]].name, [[], [], 0])
        v[0].append(mt.translation)
        v[1].append(mt.tilt)
    for j in extra:
        acc.setdefault(inventory[est[j][0]].name, [[], [], 0])[2] += 1


def write_bop_csv(estimates: list[Estimate], path: str | Path) -> None:
    """BOP results: scene_id,im_id,obj_id,score,R (row-major, space separated),t (mm),time (s)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene_id", "im_id", "obj_id", "score", "R", "t", "time"])
        for e in estimates:
            R = " ".join(f"{x:.6f}" for x in e.T_cam_obj[:3, :3].reshape(-1))
            t = " ".join(f"{x:.3f}" for x in e.T_cam_obj[:3, 3] * 1000)
            w.writerow([e.scene_id, e.im_id, e.obj_id, f"{e.score:.4f}", R, t, f"{e.time_s:.4f}"])


SWEEPS = {
    "voxel": ("voxel_size", [0.004, 0.006, 0.008, 0.010, 0.012, 0.015, 0.020]),
    "topk": ("top_k", [1, 2, 3, 4, 5, 6]),
    "iou": ("iou_threshold", [0.1, 0.3, 0.5, 0.6, 0.7, 0.8, 0.9]),
}


def sweep(dataset: str | Path, what: str, settings: PerceptionSettings, png: str | Path, **kw) -> list[dict]:
    """Evaluate for each value of one hyperparameter and plot ADI recall (and time per object) against it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if what not in SWEEPS:
        raise ValueError(f"--sweep: expected one of {sorted(SWEEPS)}, got {what!r}")
    field_, values = SWEEPS[what]
    rows = []
    for v in values:
        s = settings.model_copy(update={field_: v})
        r = evaluate(dataset, s, **kw).report
        rows.append({"value": v, "adi": r["adi_recall_0.1d"], "auc": r["auc_adds_10cm"],
                     "pose_ms": r["pose_ms_per_object_median"]})
    fig, ax = plt.subplots(figsize=(5, 3.6))
    x = [r["value"] * (1000 if what == "voxel" else 1) for r in rows]
    ax.plot(x, [r["adi"] for r in rows], "o-", label="ADI recall @0.1d")
    ax.plot(x, [r["auc"] for r in rows], "s--", label="AUC ADD-S 10 cm")
    ax.set_xlabel({"voxel": "voxel size (mm)", "topk": "top-K candidates", "iou": "IoU threshold"}[what])
    ax.set_ylabel("score")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax2 = ax.twinx()
    ax2.plot(x, [r["pose_ms"] for r in rows], "^:", color="grey", label="ms / object")
    ax2.set_ylabel("median pose time per object (ms)")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return rows
