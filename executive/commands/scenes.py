"""`kitchenbot scenes generate --out DIR [--scenes N] [--seed S] [--variety default|wide] [--distractors N]
[--camera oakd|d435|kinect] [--surface sink|table]`: a BOP dataset with ground truth."""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scenes", help="generate simulated sink scenes as a BOP dataset")
    ss = p.add_subparsers(dest="scenes_command", metavar="ACTION", required=True)
    g = ss.add_parser("generate", help="write N random sink scenes scanned from the config's waypoints")
    g.add_argument("--out", required=True, type=Path, help="dataset folder to write")
    g.add_argument("--scenes", type=int, default=20, help="number of scenes (default 20)")
    g.add_argument("--seed", type=int, default=0, help="seed of the first scene (default 0)")
    g.add_argument("--config", help="cell config YAML (default: the shipped simulation config)")
    g.add_argument("--pose-noise-mm", type=float, default=0.0, help="perturb each scan pose by this much")
    g.add_argument("--pose-noise-deg", type=float, default=0.0)
    g.add_argument("--variety", choices=["default", "wide"], default="default",
                   help="wide: new dishware of every family in the inventory, sink fixtures (rounded corners, "
                        "drain, faucet, floor grid), basin size, light and depth noise drawn per scene")
    g.add_argument("--distractors", type=int, default=0,
                   help="non-inventory objects per scene (box, can, bottle, sponge, cutlery, scraps); default 0")
    g.add_argument("--camera", choices=["oakd", "d435", "kinect"], default="oakd",
                   help="camera model: intrinsics and depth error (default oakd, the cell's camera)")
    g.add_argument("--surface", choices=["sink", "table"], default="sink",
                   help="table: the items stand on a flat table top (a board over the basin), no sink walls")
    g.set_defaults(func=run_generate)


def run_generate(args: argparse.Namespace) -> int:
    import numpy as np
    from rich.progress import Progress

    from kitchenbot.drivers.ur_kinematics import ur_model
    from kitchenbot.executive.config import load_config
    from kitchenbot.fakes.bop import generate_dataset
    from kitchenbot.fakes.scenes import SceneOptions

    if args.scenes < 1:
        raise ValueError(f"--scenes: expected a positive number, got {args.scenes}")
    if args.distractors < 0:
        raise ValueError(f"--distractors: expected a count >= 0, got {args.distractors}")
    cfg = load_config(args.config)
    world_kwargs = {
        "robot": ur_model(cfg.robot.model),
        "T_flange_tcp": cfg.robot.tool.T_flange_tcp.matrix(),
        "T_flange_cam": cfg.T_flange_cam(),
    }
    opts = SceneOptions(min_objects=cfg.sim.min_objects, max_objects=cfg.sim.max_objects, style=cfg.sim.style)
    t0 = time.perf_counter()
    with Progress() as bar:
        task = bar.add_task("scenes", total=args.scenes)
        stats = generate_dataset(
            args.out, args.scenes, args.seed, [np.asarray(q) for q in cfg.scan_waypoints], world_kwargs,
            width=getattr(cfg.drivers.camera, "width", 640),
            height=getattr(cfg.drivers.camera, "height", 480),
            pose_noise_m=args.pose_noise_mm / 1000.0, pose_noise_deg=args.pose_noise_deg, scene_options=opts,
            progress=lambda i, n: bar.update(task, completed=i),
            variety=args.variety, distractors=args.distractors, camera=args.camera, surface=args.surface,
        )
    dt = time.perf_counter() - t0
    print(f"wrote {stats['scenes']} scenes, {stats['images']} images, {stats['objects']} objects "
          f"({stats['distractors']} distractors), {stats['targets']} targets, {stats['inventory']} inventory models "
          f"to {args.out} in {dt:.1f} s ({dt / stats['scenes']:.2f} s/scene)")
    return 0
