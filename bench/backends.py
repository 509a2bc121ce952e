"""`kitchenbot bench backends`: time each learned backend through its real adapter on 640 x 480 views.

Backends whose weights are in `weights_dir` are timed as they are. For the others, `--random-init` (the default
when weights are missing) builds the *same architecture* from the `transformers` config defaults (Swin-T +
BERT-base GroundingDINO / MM-GroundingDINO, SAM2 Hiera-tiny, ViT-S/14 DINOv2, ViT-B/16 BEiT and CLIP) with
random weights, saves it to a temporary folder and loads it through the same adapter: the latency is the
architecture's, the outputs are meaningless. Prints milliseconds per scan (3 views) and per crop.
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
    p.set_defaults(func=bench_backends)


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
    fn()  # warm-up (allocations, kernel selection)
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(1000 * (time.perf_counter() - t0))
    return statistics.median(ts)


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
            ms = _time(lambda: ad.detect_batch(views), args.repeats)
            row = {"ms_per_scan": ms, "ms_per_view": ms / len(views)}
        elif ck.role == "segmenter":
            ad = Sam2Segmenter(folder, device=str(device))
            ms = _time(lambda: ad.segment_batch(views, boxes), args.repeats)
            row = {"ms_per_scan": ms, "ms_per_view": ms / len(views), "boxes_per_view": 5}
        else:
            ad = HFImageEncoder(name, folder, device=str(device))
            ms = _time(lambda: ad.encode_batch(crops, masks), args.repeats)
            row = {"ms_per_5_crops": ms, "ms_per_crop": ms / len(crops), "dim": ad.dim}
        params = sum(p.numel() for p in ad.model.parameters())
        row.update(source=source, checkpoint=ck.repo_id, params_m=params / 1e6, total_s=time.perf_counter() - t0)
        results[name] = row
        main = ", ".join(f"{k} {v:.0f}" for k, v in row.items() if k.startswith("ms_"))
        print(f"{name:<15} {main}  ({params / 1e6:.0f} M params, {source})")
        del ad
    tmp.cleanup()
    if not str(device).startswith("cuda"):
        print("no CUDA device: CPU timings only")
    if args.report:
        args.report.write_text(json.dumps({"device": str(device), "dtype": str(dtype), "backends": results}, indent=1))
    return 0
