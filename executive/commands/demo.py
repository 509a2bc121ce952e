"""`kitchenbot demo [--out DIR] [--seed N]`: what `make demo` runs.

Builds the simulated cell, scans the sink from the configured waypoints with the fake arm and camera, writes
the views as PNGs (RGB | depth | ground-truth instances) and then runs the sink-to-dishwasher job, printing
its summary; everything lands in DIR with a JSON report.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulated demo: scan the sink, save the views, run sink-to-dishwasher")
    p.add_argument("--out", type=Path, default=Path("out/demo"))
    p.add_argument("--seed", type=int, default=12, help="scene seed (default 12)")
    p.add_argument("--objects", type=int, default=4,
                   help="items in the sink (default 4; `kitchenbot bench tasks` measures 3-10 over many seeds)")
    p.add_argument("--config", help="cell config YAML (default: the shipped simulation config)")
    p.add_argument("--scan-only", action="store_true", help="stop after the scan")
    p.set_defaults(func=run)


def _depth_png(depth):
    import numpy as np

    d = np.nan_to_num(depth)
    valid = d > 0
    out = np.zeros(d.shape + (3,), np.uint8)
    if valid.any():
        lo, hi = np.percentile(d[valid], [1, 99])
        t = np.clip((d - lo) / max(hi - lo, 1e-6), 0, 1)
        out[..., 0] = (255 * (1 - t)).astype(np.uint8)
        out[..., 1] = (255 * (1 - np.abs(2 * t - 1))).astype(np.uint8)
        out[..., 2] = (255 * t).astype(np.uint8)
    out[~valid] = 0
    return out


def _labels_png(labels):
    import numpy as np

    rng = np.random.default_rng(3)
    palette = rng.integers(40, 255, (int(labels.max()) + 1, 3)).astype(np.uint8)
    palette[0] = 0
    return palette[labels]


def scan_and_save(cell, out: Path) -> list[dict]:
    """Visit the scan waypoints, capture, save PNGs; returns per-view records."""
    import numpy as np
    from PIL import Image

    cfg = cell.config
    views = []
    for i, q in enumerate(cfg.scan_waypoints):
        t0 = time.perf_counter()
        cell.arm.move_joints(np.asarray(q), speed=1.0, accel=2.0)
        frame = cell.camera.capture()
        dt = time.perf_counter() - t0
        T_base_cam = cell.arm.flange_pose() @ cell.T_flange_cam
        panels = [frame.rgb, _depth_png(frame.depth)]
        labels = getattr(cell.camera, "last_labels", None)
        if labels is not None:
            panels.append(_labels_png(labels))
        Image.fromarray(np.hstack(panels)).save(out / f"view_{i}.png")
        valid = np.isfinite(frame.depth) & (frame.depth > 0)
        views.append({"view": i, "png": f"view_{i}.png", "T_base_cam": np.round(T_base_cam, 5).tolist(),
                      "valid_depth_fraction": float(valid.mean()), "sim_time_s": frame.stamp,
                      "compute_ms": dt * 1000})
    return views


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from kitchenbot.executive.assembly import assemble
    from kitchenbot.executive.config import load_config

    console = Console()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    cfg = load_config(args.config)
    if args.objects is not None:
        if not 0 <= args.objects <= 30:
            raise ValueError(f"--objects: expected 0..30, got {args.objects}")
        cfg.sim = cfg.sim.model_copy(update={"min_objects": args.objects, "max_objects": args.objects})
    cell = assemble(cfg, seed=args.seed)
    cell.connect()
    world = cell.world
    console.print(f"[bold]kitchenbot demo[/] seed {args.seed}: {cfg.robot.model}, "
                  f"{world.cell.spec.sink.style} sink with {len(world.objects)} items: "
                  + ", ".join(o.model.name for o in world.objects.values()))
    views = scan_and_save(cell, out)
    console.print(f"scanned {len(views)} views -> {out}/view_*.png")
    report = {"seed": args.seed, "style": world.cell.spec.sink.style,
              "objects": [o.model.name for o in world.objects.values()], "views": views}
    status = 0
    if not args.scan_only:
        from kitchenbot.executive.runner import run_task

        cell.disconnect()
        console.print("running [bold]sink-to-dishwasher[/] on the same scene")
        task_report = run_task(cfg, "sink-to-dishwasher", args.seed, report_path=out / "run_report.json",
                               journal_path=out / "journal.sqlite")
        report["task"] = task_report.to_dict()
        from kitchenbot.executive.progress import print_summary

        print_summary(task_report, console)
        status = 0 if report["task"].get("status") == "succeeded" else 1
    (out / "report.json").write_text(json.dumps(report, indent=1))
    console.print(f"report: {out / 'report.json'}")
    return status
