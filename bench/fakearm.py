"""`kitchenbot bench fakearm`: wall-clock cost of FakeArm motions (path sampling + collision checks + IK).

Per random sink scene: home -> each scan waypoint -> home (joint moves), then a pick of a cup on the counter
(linear approach, grasp, lift while holding, joint move home). Prints the median / p95 wall time per motion
kind and the number of path samples checked.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np


def register(bs: argparse._SubParsersAction) -> None:
    p = bs.add_parser("fakearm", help="time FakeArm motions (path collision checks, IK) in random scenes")
    p.add_argument("--scenes", type=int, default=5)
    p.add_argument("--report", type=Path)
    p.set_defaults(func=bench_fakearm)


def bench_fakearm(args: argparse.Namespace) -> int:
    from kitchenbot.executive.config import CellConfig
    from kitchenbot.fakes import FakeArm, FakeGripper, generate_scene
    from kitchenbot.fakes import collision as coll
    from kitchenbot.fakes.placement import drop_onto
    from kitchenbot.planning.grasp_synthesis import generate_grasps
    from kitchenbot.transforms import trans

    cfg = CellConfig()
    limits = cfg.safety_limits()
    home = np.array(cfg.robot.home)
    times: dict[str, list[float]] = {"move_joints": [], "move_linear": [], "move_joints_holding": []}
    samples: list[int] = []
    orig = coll.SimCollision.check_path

    def counting(self, qs, opening):
        samples.append(len(qs))
        return orig(self, qs, opening)

    coll.SimCollision.check_path = counting
    try:
        collisions = 0
        for seed in range(args.scenes):
            world = generate_scene(seed, world_kwargs={"T_flange_tcp": limits.T_flange_tcp, "q": home.copy(),
                                                       "T_flange_cam": cfg.T_flange_cam()})
            cup = world.add_object(world.inventory.by_name("cup"), trans(0.35, 0.45, 0.3))
            world.set_pose(cup, drop_onto(world, cup, world.objects[cup].T_base_obj))
            arm, gripper = FakeArm(world, limits), FakeGripper(world)
            arm.connect()
            gripper.connect()
            for q in [*cfg.scan_waypoints, cfg.robot.home]:
                t = time.perf_counter()
                arm.move_joints(np.array(q), speed=1.0, accel=2.0)
                times["move_joints"].append(time.perf_counter() - t)
            spec = next(g for g in generate_grasps(world.objects[cup].model) if g.name.startswith("rim"))
            T_grasp = world.objects[cup].T_base_obj @ spec.T_obj_tcp
            for T in (T_grasp @ trans(0, 0, -0.08), T_grasp):
                t = time.perf_counter()
                arm.move_linear(T, speed=0.25, accel=1.0)
                times["move_linear"].append(time.perf_counter() - t)
            gripper.grasp(0.6)
            t = time.perf_counter()
            arm.move_linear(trans(0, 0, 0.15) @ T_grasp, speed=0.25, accel=1.0)
            times["move_linear"].append(time.perf_counter() - t)
            t = time.perf_counter()
            arm.move_joints(home, speed=1.0, accel=2.0)
            times["move_joints_holding"].append(time.perf_counter() - t)
            collisions += arm.log.collisions
    finally:
        coll.SimCollision.check_path = orig

    out = {"scenes": args.scenes, "collisions": collisions, "samples_median": statistics.median(samples)}
    for k, v in times.items():
        v = sorted(v)
        out[f"{k}_median_ms"] = 1000 * statistics.median(v)
        out[f"{k}_p95_ms"] = 1000 * v[min(len(v) - 1, int(0.95 * len(v)))]
    for k, v in out.items():
        print(f"{k:28s} {v:.1f}" if isinstance(v, float) else f"{k:28s} {v}")
    if args.report:
        args.report.write_text(json.dumps(out, indent=1))
    return 0
