"""Benchmarks of the simulator: render time per frame, scene generation throughput."""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def register(bs: argparse._SubParsersAction) -> None:
    r = bs.add_parser("render", help="time FakeCamera captures (render + noise) at 640x480")
    r.add_argument("--frames", type=int, default=30)
    r.add_argument("--report", type=Path)
    r.set_defaults(func=bench_render)
    s = bs.add_parser("scenes", help="time `scenes generate` for N scenes")
    s.add_argument("--scenes", type=int, default=20)
    s.add_argument("--report", type=Path)
    s.set_defaults(func=bench_scenes)


def _write(report: Path | None, data: dict) -> None:
    if report:
        report.write_text(json.dumps(data, indent=1))


def bench_render(args: argparse.Namespace) -> int:
    from kitchenbot.executive.assembly import make_sim_world
    from kitchenbot.executive.config import load_config
    from kitchenbot.fakes.render import oakd_intrinsics, render, stereo_noise

    cfg = load_config()
    world = make_sim_world(cfg, seed=4)
    K = oakd_intrinsics()
    rng = np.random.default_rng(0)
    raw, full = [], []
    for i in range(args.frames):
        world.set_joints(np.asarray(cfg.scan_waypoints[i % len(cfg.scan_waypoints)]))
        T = world.T_base_cam()
        t0 = time.perf_counter()
        r = render(world, K, T, 640, 480)
        t1 = time.perf_counter()
        stereo_noise(r.depth, r.cos_incidence, K, rng)
        t2 = time.perf_counter()
        raw.append((t1 - t0) * 1000)
        full.append((t2 - t0) * 1000)
    data = {"frames": args.frames, "objects": len(world.objects), "render_ms_median": statistics.median(raw),
            "render_plus_noise_ms_median": statistics.median(full)}
    print(f"640x480, {len(world.objects)} objects: render {data['render_ms_median']:.1f} ms, "
          f"render + stereo noise {data['render_plus_noise_ms_median']:.1f} ms (median of {args.frames})")
    _write(args.report, data)
    return 0


def bench_scenes(args: argparse.Namespace) -> int:
    from kitchenbot.executive.commands.scenes import run_generate

    with tempfile.TemporaryDirectory() as tmp:
        ns = argparse.Namespace(out=Path(tmp) / "ds", scenes=args.scenes, seed=0, config=None,
                                pose_noise_mm=0.0, pose_noise_deg=0.0)
        t0 = time.perf_counter()
        run_generate(ns)
        dt = time.perf_counter() - t0
    data = {"scenes": args.scenes, "seconds": dt, "seconds_per_scene": dt / args.scenes}
    print(f"scenes generate: {args.scenes} scenes in {dt:.1f} s")
    _write(args.report, data)
    return 0
