"""`kitchenbot eval DATASET [--config FILE] [--results FILE.csv] [--report FILE.json] [--scenes ...]
[--sweep voxel|topk|iou] [--overlays DIR]`: the perception pipeline on any BOP dataset."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="evaluate perception on a BOP dataset (ADI recall, AUC ADD-S, timings)")
    p.add_argument("dataset", type=Path, help="BOP dataset folder (models/ + scene folders)")
    p.add_argument("--config", help="cell config YAML: perception settings and cell geometry (default: shipped)")
    p.add_argument("--split", help="split folder inside the dataset (default: every scene folder found)")
    p.add_argument("--results", type=Path, help="write BOP results CSV here")
    p.add_argument("--report", type=Path, help="write the metrics report JSON here")
    p.add_argument("--scenes", type=int, nargs="+", help="only these scene ids")
    p.add_argument("--sweep", choices=["voxel", "topk", "iou"], help="evaluate over a hyperparameter; plot ADI")
    p.add_argument("--sweep-plot", type=Path, help="PNG for --sweep (default: sweep_<what>.png)")
    from kitchenbot.perception.sweep import add_arguments as add_model_sweep_arguments  # issue 4

    add_model_sweep_arguments(p)  # --sweep-models, --sweep-table, --point-encoders
    p.add_argument("--overlays", type=Path, help="write PNG overlays of model contours at the estimated poses")
    p.add_argument("--overlay-scenes", type=int, nargs="+", help="scenes to draw (default: the first three)")
    p.add_argument("--cell", choices=["auto", "always", "never", "dataset"], default="auto",
                   help="the config's cell geometry: always use it; never (find supports and walls in each "
                        "scan); auto (default: use it where it fits what the cameras see, else the surfaces "
                        "found); dataset (each generated scene's own cell from its scene_sim.json)")
    p.add_argument("--inventory", type=Path,
                   help="BOP models folder of the dishware to find (default: the dataset's models/)")
    p.add_argument("--objects", type=int, nargs="+",
                   help="only these model ids are dishware to find; every other object in the ground truth "
                        "is a distractor that must get no pose (e.g. YCB-Video: 13 14, the bowl and the mug)")
    p.add_argument("--min-visib", type=float, default=0.1, help="evaluate GT objects at least this visible")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kitchenbot.executive.config import load_config
    from kitchenbot.perception.evaluate import evaluate, sweep, write_bop_csv
    from kitchenbot.world.cell import Cell

    if not args.dataset.is_dir():
        raise FileNotFoundError(f"{args.dataset}: dataset folder not found")
    cfg = load_config(args.config)
    if args.inventory is not None and not args.inventory.is_dir():
        raise FileNotFoundError(f"--inventory {args.inventory}: models folder not found")
    kw = dict(cell=Cell(cfg.cell), use_cell=args.cell, split=args.split, scenes=args.scenes,
              min_visib=args.min_visib, progress=not args.no_progress, inventory=args.inventory,
              object_ids=args.objects)
    if getattr(args, "sweep_models", False):  # every backend combination with weights (perception/sweep.py)
        from kitchenbot.perception.sweep import run_cli

        return run_cli(args, cfg.perception, kw)
    if args.sweep:
        png = args.sweep_plot or Path(f"sweep_{args.sweep}.png")
        rows = sweep(args.dataset, args.sweep, cfg.perception, png, **kw)
        for r in rows:
            print(f"{args.sweep}={r['value']}: ADI recall {r['adi']:.3f}, AUC {r['auc']:.3f}, {r['pose_ms']:.0f} ms/object")
        print(f"plot: {png}")
        if args.report:
            args.report.write_text(json.dumps({"sweep": args.sweep, "rows": rows}, indent=1))
        return 0
    res = evaluate(args.dataset, cfg.perception, **kw)
    r = res.report
    if args.results:
        write_bop_csv(res.estimates, args.results)
    if args.report:
        args.report.write_text(json.dumps(r, indent=1))
    if args.overlays:
        from kitchenbot.perception.overlay import write_overlays

        n = write_overlays(args.dataset, res.estimates, args.overlays, args.overlay_scenes, split=args.split)
        print(f"overlays: {n} images in {args.overlays}")
    print(f"ADI recall@0.1d {r['adi_recall_0.1d']:.3f}  AUC ADD-S(10cm) {r['auc_adds_10cm']:.3f}  "
          f"objects {r['objects']}  false positives {r['false_positives']}  scenes {r['scenes']}  images {r['images']}")
    print(f"rejected instances (no inventory model explains them; obstacles) {r['rejected']}  surfaces from "
          + ", ".join(f"{k} {v}" for k, v in r["surfaces_from"].items()) + " (scans)")
    for mf in r["cell_misfits"]:
        print(f"  scene {mf['scene_id']}: {mf['message']}")
    for oid, o in r["per_object"].items():
        print(f"  {oid:>3} {o['name']:<16} recall {o['recall']:.3f}  (n={o['n']})")
    print(f"false positives per image {r['false_positives_per_image']:.2f}; on distractors (objects outside the "
          f"inventory, {r['distractors']} seen): {r['false_positives_on_distractors']}"
          + "".join(f"  {k} {v}" for k, v in r["false_positives_on_distractors_by_name"].items()))
    if r.get("grasp_errors"):
        print("per scan, base frame: position / axis error of matched objects (median, p90), missed, extra "
              "(duplicates, phantoms), share within 1 cm and 5 deg")
        for name, g in r["grasp_errors"].items():
            fmt = lambda x: "   -" if x is None else f"{x:4.1f}"  # noqa: E731
            print(f"  {name:<16} n {g['n']:3d}  pos mm {fmt(g['translation_mm_median'])} / "
                  f"{fmt(g['translation_mm_p90'])}  tilt deg {fmt(g['tilt_deg_median'])} / {fmt(g['tilt_deg_p90'])}  "
                  f"missed {g['missed']:2d}  extra {g['extra']:2d}  within {g['within']:.2f}")
    tc = r["timing_cpu_median_ms"]
    print("median CPU ms per scan: " + ", ".join(f"{k} {v:.0f}" for k, v in tc.items()) +
          f"; map + segmentation {r['map_seg_cpu_ms_per_scan_median']:.0f}; slowest scan {r['scan_cpu_ms_max']:.0f}; pose per object "
          f"{r['pose_cpu_ms_per_object_median']:.0f}")
    t = r["timing_median_ms"]
    print("median ms per scan: " + ", ".join(f"{k} {v:.0f}" for k, v in t.items())
          + f"; pose per object {r['pose_ms_per_object_median']:.0f}")
    return 0
