"""`kitchenbot bench backends`: time each learned backend through its real adapter on 640 x 480 views.

Backends whose weights are in `weights_dir` are timed as they are. For the others, `--random-init` (the default
when weights are missing) builds the *same architecture* from the `transformers` config defaults (Swin-T +
BERT-base GroundingDINO / MM-GroundingDINO, SAM2 Hiera-tiny, ViT-S/14 DINOv2, ViT-B/16 BEiT and CLIP) with
random weights, saves it to a temporary folder and loads it through the same adapter: the latency is the
architecture's, the outputs are meaningless. Prints milliseconds per scan (3 views) and per crop.

`--scan DATASET` runs each learned backend end to end instead: the whole pipeline (Perceiver) with that
backend on the first scan of a BOP dataset (e.g. 3 views of 640 x 480 from `kitchenbot scenes generate`),
timing model loading, the CAD database build, and every stage per scan and per image.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

VOCAB = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", ".", "dish", "##ware"]


def register(bs: argparse._SubParsersAction) -> None:
    p = bs.add_parser("backends", help="time the learned detectors, SAM2 and image encoders per scan / crop")
    p.add_argument("--only", nargs="+", choices=["llmdet", "grounding-dino", "sam2", "dinov2", "beit", "clip"],
                   help="time only these backends")
    p.add_argument("--weights-dir", help="checkpoints folder (default: the config's perception.weights_dir)")
    p.add_argument("--no-random-init", action="store_true",
                   help="skip backends without weights instead of timing a randomly initialised copy")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--device", help="cpu or cuda (default: cuda when available)")
    p.add_argument("--cores", type=int, help="pin the process to this many CPU cores")
    p.add_argument("--config", help="cell config YAML (default: shipped)")
    p.add_argument("--report", type=Path, help="write the numbers as JSON here")
    p.add_argument("--scan", type=Path, metavar="DATASET",
                   help="end to end: run the pipeline with each learned backend on the first scan of this BOP "
                        "dataset and print ms per stage, per scan and per image")
    p.add_argument("--scene", type=int, help="with --scan: this scene id (default: the first)")
    p.set_defaults(func=bench_backends)


# End to end: (detector, segmenter, image encoder) per learned backend; the others at their defaults.
COMBOS = {
    "llmdet": ("llmdet", "geometric", "colour"),
    "grounding-dino": ("grounding-dino", "geometric", "colour"),
    "sam2": ("grounding-dino", "sam2", "colour"),
    "dinov2": ("geometric", "geometric", "dinov2"),
    "beit": ("geometric", "geometric", "beit"),
    "clip": ("geometric", "geometric", "clip"),
}


def _random_checkpoint(backend: str, folder: Path) -> None:
    """The released architecture with random weights (and a toy tokenizer), saved like a checkpoint."""
    import torch
    import transformers as tf

    torch.manual_seed(0)
    if backend in ("llmdet", "grounding-dino"):
        cfg_cls, model_cls = ((tf.MMGroundingDinoConfig, tf.MMGroundingDinoForObjectDetection) if backend == "llmdet"
                              else (tf.GroundingDinoConfig, tf.GroundingDinoForObjectDetection))
        model = model_cls(cfg_cls())
        (folder.parent / "vocab.txt").write_text("\n".join(VOCAB) + "\n")
        tf.BertTokenizer(str(folder.parent / "vocab.txt")).save_pretrained(folder)
    elif backend == "sam2":
        model = tf.Sam2Model(tf.Sam2Config())
    elif backend == "dinov2":
        model = tf.Dinov2Model(tf.Dinov2Config(hidden_size=384, num_attention_heads=6, intermediate_size=1536,
                                               patch_size=14))
    elif backend == "beit":
        model = tf.BeitModel(tf.BeitConfig())
    else:
        model = tf.CLIPVisionModel(tf.CLIPVisionConfig(patch_size=16))
    model.save_pretrained(folder)


def _views(n: int = 3):
    import numpy as np

    from kitchenbot.perception.types import View

    rng = np.random.default_rng(0)
    K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
    return [View((rng.random((480, 640, 3)) * 255).astype(np.uint8), np.full((480, 640), 0.6, np.float32), K,
                 np.eye(4)) for _ in range(n)]


def _time(fn, repeats: int) -> float:
    return _time_both(fn, repeats)[0]


def _time_both(fn, repeats: int) -> tuple[float, float]:
    """Median wall and process-CPU milliseconds of `fn` (after one warm-up call). CPU time counts every
    thread's work and does not grow when other processes compete for the cores; wall time does."""
    fn()  # warm-up (allocations, kernel selection)
    ts, cs = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        ts.append(1000 * (time.perf_counter() - t0))
        cs.append(1000 * (time.process_time() - c0))
    return statistics.median(ts), statistics.median(cs)


def bench_backends(args: argparse.Namespace) -> int:
    import numpy as np
    import torch

    from kitchenbot.executive.config import load_config
    from kitchenbot.perception.backends import CHECKPOINTS, _weights_problem
    from kitchenbot.perception.detect import Detection
    from kitchenbot.perception.hf_common import device_and_dtype
    from kitchenbot.perception.hf_detectors import GroundedDetector
    from kitchenbot.perception.hf_encoders import HFImageEncoder
    from kitchenbot.perception.hf_sam2 import Sam2Segmenter

    if args.cores:
        os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[: args.cores]))
        torch.set_num_threads(args.cores)
    wdir = args.weights_dir or load_config(args.config).perception.weights_dir
    device, dtype = device_and_dtype(args.device)
    if args.scan is not None:
        return _end_to_end(args, wdir, device, dtype)
    print(f"device {device} ({dtype}), torch threads {torch.get_num_threads()}, 3 views of 640 x 480")
    views = _views()
    boxes = [[Detection(np.array([60.0 + 110 * i, 120, 150 + 110 * i, 260]), 0.9) for i in range(5)] for _ in views]
    rng = np.random.default_rng(1)
    crops = [(rng.random((140, 120, 3)) * 255).astype(np.uint8) for _ in range(5)]
    masks = [np.ones((140, 120), bool) for _ in crops]
    results = {}
    tmp = tempfile.TemporaryDirectory()
    for name in args.only or ["llmdet", "grounding-dino", "sam2", "dinov2", "beit", "clip"]:
        ck = CHECKPOINTS[name]
        folder, source = ck.path(wdir), "weights"
        if _weights_problem(ck, wdir):
            if args.no_random_init:
                print(f"{name:<15} skipped: no weights in {folder}")
                continue
            folder, source = Path(tmp.name) / ck.folder, "random init"
            _random_checkpoint(name, folder)
        t0 = time.perf_counter()
        if ck.role == "detector":
            ad = GroundedDetector(name, folder, device=str(device))
            ms, cpu = _time_both(lambda: ad.detect_batch(views), args.repeats)
            row = {"ms_per_scan": ms, "ms_per_view": ms / len(views), "cpu_ms_per_view": cpu / len(views)}
        elif ck.role == "segmenter":
            ad = Sam2Segmenter(folder, device=str(device))
            ms, cpu = _time_both(lambda: ad.segment_batch(views, boxes), args.repeats)
            row = {"ms_per_scan": ms, "ms_per_view": ms / len(views), "cpu_ms_per_view": cpu / len(views),
                   "boxes_per_view": 5}
        else:
            ad = HFImageEncoder(name, folder, device=str(device))
            ms, cpu = _time_both(lambda: ad.encode_batch(crops, masks), args.repeats)
            row = {"ms_per_5_crops": ms, "ms_per_crop": ms / len(crops), "cpu_ms_per_crop": cpu / len(crops),
                   "dim": ad.dim}
        params = sum(p.numel() for p in ad.model.parameters())
        row.update(source=source, checkpoint=ck.repo_id, params_m=params / 1e6, total_s=time.perf_counter() - t0)
        results[name] = row
        main = ", ".join(f"{k} {v:.0f}" for k, v in row.items() if k.startswith(("ms_", "cpu_ms")))
        print(f"{name:<15} {main}  ({params / 1e6:.0f} M params, {source})")
        del ad
    tmp.cleanup()
    if not str(device).startswith("cuda"):
        print("no CUDA device: CPU timings only")
    if args.report:
        args.report.write_text(json.dumps({"device": str(device), "dtype": str(dtype), "backends": results}, indent=1))
    return 0


def _end_to_end(args: argparse.Namespace, wdir: str, device, dtype) -> int:
    """The pipeline with each learned backend on one scan (random-init copies where weights are missing)."""
    import torch

    from kitchenbot.executive.config import load_config
    from kitchenbot.perception import bop
    from kitchenbot.perception.backends import CHECKPOINTS, _weights_problem
    from kitchenbot.world.cell import Cell
    from kitchenbot.world.inventory import Inventory
    from kitchenbot.perception.pipeline import Perceiver

    if not args.scan.is_dir():
        raise FileNotFoundError(f"--scan {args.scan}: dataset folder not found")
    dirs = bop.scene_dirs(args.scan)
    if args.scene is not None:
        dirs = [d for d in dirs if d.name.isdigit() and int(d.name) == args.scene]
        if not dirs:
            raise ValueError(f"--scene {args.scene}: no such scene in {args.scan}")
    group = bop.view_groups(bop.read_scene(dirs[0]))[0]
    views = [im.view for im in group]
    md = bop.models_dir(args.scan)
    inventory = Inventory.load(md, md / "grasps.json" if (md / "grasps.json").is_file() else None)
    cfg = load_config(args.config)
    w, h = views[0].size
    print(f"device {device} ({dtype}), torch threads {torch.get_num_threads()}; end to end on {dirs[0]}: "
          f"{len(views)} views of {w} x {h}, {len(inventory)} inventory models")
    tmp = tempfile.TemporaryDirectory()
    wtmp = Path(tmp.name) / "weights"
    wtmp.mkdir()
    results = {}
    for name in args.only or list(COMBOS):
        det, seg, enc = COMBOS[name]
        sources = {}
        for b in {det, seg, enc} & set(CHECKPOINTS):
            ck = CHECKPOINTS[b]
            if (wtmp / ck.folder).exists():
                continue
            if _weights_problem(ck, wdir):
                if args.no_random_init:
                    break
                _random_checkpoint(b, wtmp / ck.folder)
                sources[b] = "random init"
            else:
                (wtmp / ck.folder).symlink_to(ck.path(wdir))
                sources[b] = "weights"
        else:
            settings = cfg.perception.model_copy(update={"detector": det, "segmenter": seg, "image_encoder": enc,
                                                         "weights_dir": str(wtmp),
                                                         "cache_dir": str(Path(tmp.name) / "cad")})
            with_cell = group[0].has_world_pose
            t0 = time.perf_counter()
            perc = Perceiver(settings, inventory, Cell(cfg.cell) if with_cell else None, use_cell=with_cell)
            t_load = time.perf_counter() - t0
            t0, c0 = time.perf_counter(), time.process_time()
            _ = perc.database
            t_db, t_db_cpu = time.perf_counter() - t0, time.process_time() - c0
            runs = []
            for _k in range(max(1, args.repeats)):
                t0, c0 = time.perf_counter(), time.process_time()
                res = perc.perceive(views)
                runs.append((1000 * (time.perf_counter() - t0), 1000 * (time.process_time() - c0), res))
            total, cpu, res = sorted(runs, key=lambda r: r[0])[len(runs) // 2]
            row = {"detector": det, "segmenter": seg, "image_encoder": enc, "sources": sources,
                   "load_s": t_load, "database_s": t_db, "database_cpu_s": t_db_cpu, "ms_per_scan": total,
                   "ms_per_image": total / len(views), "cpu_ms_per_scan": cpu, "cpu_ms_per_image": cpu / len(views),
                   "stages_ms": res.timings_ms, "stages_cpu_ms": res.timings_cpu_ms, "instances": len(res.pose_ms), "poses": len(res.poses),
                   "pose_ms_per_object_median": statistics.median(res.pose_ms) if res.pose_ms else 0.0}
            results[name] = row
            stages = ", ".join(f"{k} {v:.0f}/{res.timings_cpu_ms.get(k, 0):.0f}" for k, v in res.timings_ms.items())
            print(f"{name:<15} {det}+{seg}+{enc}: wall/CPU ms per scan {total:.0f}/{cpu:.0f}, per image "
                  f"{total / len(views):.0f}/{cpu / len(views):.0f} (stages wall/CPU: {stages}); load {t_load:.1f} s, "
                  f"CAD database {t_db:.1f} s ({t_db_cpu:.1f} s CPU); {len(res.poses)} poses  "
                  f"[{', '.join(f'{k}: {v}' for k, v in sources.items())}]")
            del perc
            continue
        print(f"{name:<15} skipped: no weights in {wdir}")
    tmp.cleanup()
    if not str(device).startswith("cuda"):
        print("CPU timings; with random weights the detectors' boxes (and so the later stages' work) are not a "
              "trained model's")
    if args.report:
        args.report.write_text(json.dumps({"device": str(device), "dtype": str(dtype), "scan": str(dirs[0]),
                                           "views": len(views), "end_to_end": results}, indent=1, default=str))
    return 0
