"""`kitchenbot bench perception [DATASET]`: time the pipeline stages on generated sink scans.

Prints, per 3-view scan, the map + segmentation time (align + segment + associate + map) and, per object,
the pose time (features + candidates + registration), as wall-clock and as process CPU time. On a shared
machine the wall clock includes waiting for the CPU; `--cores 2` pins the process to two cores so that a
bigger machine measures the target configuration.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path


def register(bs: argparse._SubParsersAction) -> None:
    p = bs.add_parser("perception", help="time map + segmentation per scan and pose estimation per object")
    p.add_argument("dataset", nargs="?", type=Path, help="BOP dataset with world camera poses (default: generate)")
    p.add_argument("--scenes", type=int, default=5, help="scenes to generate / use (default 5)")
    p.add_argument("--cores", type=int, help="pin the process to this many CPU cores (e.g. 2)")
    p.add_argument("--config", help="cell config YAML (default: the shipped simulation config)")
    p.add_argument("--report", type=Path)
    p.set_defaults(func=bench_perception)


def bench_perception(args: argparse.Namespace) -> int:
    import numpy as np

    from kitchenbot.executive.config import load_config
    from kitchenbot.perception import bop
    from kitchenbot.perception.pipeline import Perceiver, map_seg_ms
    from kitchenbot.world.cell import Cell
    from kitchenbot.world.inventory import Inventory

    if args.cores:
        os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[: args.cores]))
    cfg = load_config(args.config)
    tmp = None
    root = args.dataset
    if root is None:
        from kitchenbot.fakes.bop import generate_dataset

        tmp = tempfile.TemporaryDirectory()
        root = Path(tmp.name)
        kw = {"T_flange_tcp": cfg.robot.tool.T_flange_tcp.matrix(), "T_flange_cam": cfg.T_flange_cam()}
        generate_dataset(root, args.scenes, 500, [np.asarray(q) for q in cfg.scan_waypoints], kw)
    md = bop.models_dir(root)
    inv = Inventory.load(md, md / "grasps.json" if (md / "grasps.json").is_file() else None)
    p = Perceiver(cfg.perception, inv, Cell(cfg.cell))
    t0 = time.perf_counter()
    p.database
    db_s = time.perf_counter() - t0
    seg_wall, seg_cpu, pose_wall, pose_cpu, n_views = [], [], [], [], []
    stage_cpu: dict[str, list[float]] = {}
    scan_cpu: list[float] = []
    for sd in bop.scene_dirs(root)[: args.scenes]:
        images = bop.read_scene(sd)
        r = p.perceive([im.view for im in images])
        n_views.append(len(images))
        # Everything before the poses: cell check, alignment, surfaces, segmentation, association, fusion.
        seg_wall.append(map_seg_ms(r.timings_ms))
        seg_cpu.append(map_seg_ms(r.timings_cpu_ms))
        pose_wall += r.pose_ms
        pose_cpu += r.pose_cpu_ms
        for k, v in r.timings_cpu_ms.items():
            stage_cpu.setdefault(k, []).append(v)
        scan_cpu.append(sum(r.timings_cpu_ms.values()))
    med = statistics.median

    def p90(x: list[float]) -> float:
        return float(np.percentile(x, 90)) if x else float("nan")

    data = {
        "scans": len(seg_wall), "views_per_scan": med(n_views), "objects_estimated": len(pose_wall),
        "cores": len(os.sched_getaffinity(0)), "load_avg_1min": os.getloadavg()[0],
        "cad_database_s": db_s,
        "map_segmentation_ms_median": med(seg_wall), "map_segmentation_cpu_ms_median": med(seg_cpu),
        "pose_ms_per_object_median": med(pose_wall), "pose_cpu_ms_per_object_median": med(pose_cpu),
        "map_segmentation_cpu_ms_p90": p90(seg_cpu), "pose_cpu_ms_per_object_p90": p90(pose_cpu),
        "stage_cpu_ms_per_scan": {k: {"median": med(v), "p90": p90(v)} for k, v in stage_cpu.items()},
        "scan_cpu_ms_max": max(scan_cpu), "scan_cpu_ms_per_image_max": max(c / n for c, n in zip(scan_cpu, n_views)),
    }
    print(f"{data['scans']} scans x {data['views_per_scan']} views on {data['cores']} cores "
          f"(load {data['load_avg_1min']:.1f}): map + segmentation {data['map_segmentation_ms_median']:.0f} ms "
          f"(CPU {data['map_segmentation_cpu_ms_median']:.0f} ms) per scan; pose {data['pose_ms_per_object_median']:.0f} ms "
          f"(CPU {data['pose_cpu_ms_per_object_median']:.0f} ms) per object over {len(pose_wall)} objects")
    print("CPU ms per scan, median / p90: " + ", ".join(
        f"{k} {v['median']:.0f} / {v['p90']:.0f}" for k, v in data["stage_cpu_ms_per_scan"].items()) +
        f"; map + segmentation {data['map_segmentation_cpu_ms_median']:.0f} / {data['map_segmentation_cpu_ms_p90']:.0f}"
        f"; pose per object {data['pose_cpu_ms_per_object_median']:.0f} / {data['pose_cpu_ms_per_object_p90']:.0f}"
        f"; slowest scan {data['scan_cpu_ms_max']:.0f} ({data['scan_cpu_ms_per_image_max']:.0f} per image)")
    if args.report:
        args.report.write_text(json.dumps(data, indent=1))
    if tmp is not None:
        tmp.cleanup()
    return 0
