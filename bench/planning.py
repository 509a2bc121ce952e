"""`kitchenbot bench planning [--scenes N] [--seed S] [--report FILE.json]`: planning over random sink scenes.

Per scene (``fakes.scenes.generate_scene``, true object poses): from the home configuration, try the objects
top first (up to ``--objects`` of them) until one gets a pick plan (approach, grasp-in, lift) whose grasp can
also reach a free dishwasher rack slot, then plan the place into that rack. A scene succeeds when a pick and a
place plan were found and every segment of both is collision-free when re-checked densely by the independent
python-fcl checker (planning/fcl_check.py) and the simulator's own collision check (fakes/collision.py, where
FakeArm would stop) finds no contact either. Prints a table; the JSON report holds ``success_rate``,
``ik_ms_median``, ``grasp_selection_ms_median``, ``plan_ms_median`` (RRT-Connect + simplification + dense
re-check per joint motion), failures by type and per-scene rows. ``--clear`` keeps going through the sink
(from where the last place ended, placed items as obstacles) and reports ``objects_cleared_fraction``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from pathlib import Path

import numpy as np


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("planning", help="pick-and-place planning over random sink scenes")
    p.add_argument("--scenes", type=int, default=20, help="number of random scenes (default 20)")
    p.add_argument("--seed", type=int, default=0, help="first scene seed")
    p.add_argument("--objects", type=int, default=4, help="objects tried per scene before giving up")
    p.add_argument("--check-step", type=float, default=0.003, help="independent re-check step, metres")
    p.add_argument("--pose-noise", type=float, nargs=2, default=(0.0, 0.0), metavar=("MM", "DEG"),
                   help="plan on object poses perturbed by this much (std, mm and degrees); the simulator "
                        "check still uses the true poses (robustness to perception error)")
    p.add_argument("--clear", action="store_true",
                   help="keep going after the first object: plan pick and place for the sink's objects one after "
                        "another from where the last place ended (placed items become obstacles)")
    p.add_argument("--config", default=None, help="cell config YAML (default: the simulation config)")
    p.add_argument("--report", default=None, help="write the JSON report here")
    p.set_defaults(func=run)


def sim_contacts(world, planner, pick, place, uid: int) -> list[str]:
    """The simulator's own collision check (fakes/collision.py, what FakeArm stops on) over every segment,
    with the world's held object and gripper opening as they would be when the segment runs."""
    from kitchenbot.fakes.collision import SimCollision
    from kitchenbot.planning.motion import densify, reach_bounds

    sim = SimCollision(world, world.robot)
    r = reach_bounds(planner.world.scene())
    r = r + 0.3  # the held object (not in that scene) reaches farther out
    g = pick.grasp
    T0 = world.objects[uid].T_base_obj.copy()
    out = []
    steps = [("approach", pick.approach, None, g.spec.opening), ("grasp_in", pick.grasp_in, None, g.spec.opening),
             ("lift", pick.lift, uid, g.spec.width), ("transfer", place.transfer, uid, g.spec.width),
             ("lower", place.lower, uid, g.spec.width), ("retreat", place.retreat, None, g.spec.opening)]
    try:
        for name, traj, held, opening in steps:
            if name == "retreat":
                world.held_uid, world.T_tcp_held = None, None
                T_rest = place.T_base_obj.copy()
                T_rest[2, 3] = min(T_rest[2, 3], float(place.target.T_base_obj[2, 3]))  # fell by the release drop
                world.objects[uid].T_base_obj = T_rest
            else:
                world.held_uid = held
                world.T_tcp_held = None if held is None else g.T_tcp_obj
            contact = sim.check_path(densify(traj.q, r, 0.004), opening)
            if contact is not None:
                out.append(f"{name}: {contact}")
    finally:
        world.held_uid, world.T_tcp_held = None, None
        world.objects[uid].T_base_obj = T0
    return out


def _median(xs) -> float | None:
    return float(np.median(xs)) if len(xs) else None


def _perturb(T: np.ndarray, rng: np.random.Generator, mm: float, deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    out = np.asarray(T, float).copy()
    if mm > 0:
        out[:3, 3] += rng.normal(0.0, mm * 1e-3, 3)
    if deg > 0:
        out[:3, :3] = Rotation.from_rotvec(rng.normal(0.0, np.radians(deg), 3)).as_matrix() @ out[:3, :3]
    return out


def run_bench(n_scenes: int, seed: int, cfg=None, objects_per_scene: int = 4, check_step: float = 0.003,
              progress=None, pose_noise: tuple[float, float] = (0.0, 0.0), clear: bool = False) -> dict:
    from kitchenbot.fakes.scenes import generate_scene  # the simulator's scene generator (bench only)
    from kitchenbot.perception.types import ObjectPose
    from kitchenbot.planning.fcl_check import FclChecker, verify_pick, verify_place
    from kitchenbot.planning.pick_place import Planner
    from kitchenbot.planning.placement import SlotBook
    from kitchenbot.world.inventory import Inventory

    if cfg is None:
        from kitchenbot.executive.config import load_config

        cfg = load_config(None)
    inventory = Inventory.builtin()
    planner = Planner.from_config(cfg, inventory)
    checker = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
    home = np.asarray(cfg.robot.home, float)
    ik_ms, sel_ms, plan_ms, pick_ms, place_ms = [], [], [], [], []
    parts: dict[str, list[float]] = {"search": [], "simplify": [], "recheck": []}
    check_us: list[float] = []
    rrt_ms: list[float] = []
    failures: Counter = Counter()
    rows = []
    ok_scenes = 0
    fcl_violations = 0
    sim_collisions = 0
    segments_checked = 0
    for s in range(seed, seed + n_scenes):
        world = generate_scene(s, inventory, cfg.cell, world_kwargs={
            "T_flange_tcp": planner.robot.T_flange_tcp.copy(),
            "T_flange_cam": planner.world.T_flange_cam.copy() if planner.world.T_flange_cam is not None else np.eye(4),
        })
        rng = np.random.default_rng(1000 + s)
        objs = [ObjectPose(o.model.obj_id, o.model.cls, _perturb(o.T_base_obj, rng, *pose_noise), 1.0, instance_id=uid)
                for uid, o in world.objects.items()]
        # IK timing on this scene's grasp poses (reachable or not, as the selector meets them)
        for o in objs:
            for g in inventory[o.obj_id].grasps[::3]:
                t0 = time.perf_counter()
                planner.robot.ik(o.T_base_obj @ g.T_obj_tcp, home)
                ik_ms.append((time.perf_counter() - t0) * 1e3)
        # collision check time per configuration in this scene (random arm configurations around home)
        sc = planner.scene(objs)
        Q = np.clip(home + rng.uniform(-1.2, 1.2, (200, 6)), planner.robot.lower, planner.robot.upper)
        t0 = time.perf_counter()
        for q in Q:
            sc.valid(q)
        check_us.append((time.perf_counter() - t0) / len(Q) * 1e6)
        book = SlotBook(planner.cell)
        row = {"seed": s, "objects": len(objs), "status": "failed", "object": None, "reason": None, "tries": [],
               "cleared": 0}
        q = home.copy()
        remaining = list(objs)
        placed: list = []  # ObjectPoses of what is already in the racks (obstacles from then on)
        moved = True
        while remaining and moved:
            moved = False
            scene_objs = remaining + placed
            for o in sorted(remaining, key=lambda o: -float(o.T_base_obj[2, 3]))[:objects_per_scene]:
                targets = book.targets_for(inventory[o.obj_id])[:4]
                t0 = time.perf_counter()
                pick = planner.plan_pick(q, scene_objs, target=o, place_target=targets)
                dt = (time.perf_counter() - t0) * 1e3
                upright = False
                if not pick.ok and pick.kind == "no_feasible_placement" and o.cls != "plate":
                    # the grasps that reach it cannot turn it over: the documented fallback, upright in the rack
                    failures[f"pick:{pick.kind}(inverted)"] += 1
                    targets = book.targets_for(inventory[o.obj_id], inverted=False)[:4]
                    t0 = time.perf_counter()
                    pick = planner.plan_pick(q, scene_objs, target=o, place_target=targets)
                    dt = (time.perf_counter() - t0) * 1e3
                    upright = True
                if not pick.ok:
                    failures[f"pick:{pick.kind}"] += 1
                    row["reason"] = f"pick {pick.kind}"
                    row["tries"].append(f"{o.cls}: {row['reason']}")
                    continue
                pick_ms.append(dt)
                sel_ms.append(pick.timings_ms.get("grasp_selection_ms", np.nan))
                others = [x for x in scene_objs if x is not o]
                t0 = time.perf_counter()
                place = planner.plan_place(pick.end, pick.grasp, targets, objects=others)
                dt = (time.perf_counter() - t0) * 1e3
                if not place.ok:
                    failures[f"place:{place.kind}"] += 1
                    row["reason"] = f"place {place.kind}"
                    row["tries"].append(f"{o.cls}: {row['reason']}")
                    continue
                place_ms.append(dt)
                for plan in (pick, place):
                    tm = plan.timings_ms
                    plan_ms.extend(v for k, v in tm.items() if k.endswith("_plan_ms"))
                    rrt_ms.extend(v for k, v in tm.items() if k.endswith("_plan_ms") and tm.get(k.replace("_plan_ms", "_rrt")))
                    for k, v in tm.items():
                        for p_ in parts:
                            if k.endswith(f"_{p_}_ms"):
                                parts[p_].append(v)
                checks = verify_pick(checker, planner, pick, scene_objs, step=check_step) + \
                    verify_place(checker, planner, place, pick.grasp, others, step=check_step)
                segments_checked += len(checks)
                bad = [(n, str(r)) for n, r in checks if not r.ok]
                sim_bad = sim_contacts(world, planner, pick, place, o.instance_id)
                if sim_bad:
                    sim_collisions += 1
                    failures["sim_contact"] += 1
                    row["reason"] = f"simulator contact {sim_bad}"
                    row["tries"].append(f"{o.cls}: {row['reason']}")
                    continue
                if bad:
                    fcl_violations += len(bad)
                    failures["fcl_recheck"] += 1
                    row["reason"] = f"fcl {bad}"
                    row["tries"].append(f"{o.cls}: {row['reason']}")
                    continue
                row["cleared"] += 1
                if row["status"] != "succeeded":
                    row.update(status="succeeded", object=o.cls, grasp=pick.grasp.spec.name, slot=place.target.slot,
                               pick_ms=round(pick_ms[-1], 1), place_ms=round(dt, 1), reason=None, upright=upright)
                    ok_scenes += 1
                if not clear:
                    break
                # it rests where it was released over (dropped by the release height); carry on from there
                T_rest = place.T_base_obj.copy()
                T_rest[2, 3] = place.target.T_base_obj[2, 3]
                world.set_pose(o.instance_id, T_rest)
                book.fill(place.target.slot, T_rest, inventory[o.obj_id])
                remaining = [x for x in remaining if x is not o]
                placed.append(ObjectPose(o.obj_id, o.cls, T_rest, 1.0, instance_id=o.instance_id))
                q = place.end
                moved = True
                break
            if not clear:
                break
        rows.append(row)
        if progress:
            progress(row)
    return {
        "benchmark": "planning",
        "scenes": n_scenes,
        "seed": seed,
        "robot": cfg.robot.model,
        "pose_noise_mm_deg": list(pose_noise),
        "success_rate": ok_scenes / max(n_scenes, 1),
        "clear_mode": clear,
        "objects_cleared_fraction": sum(r["cleared"] for r in rows) / max(sum(r["objects"] for r in rows), 1),
        "success_inverted_or_plate_rate": sum(1 for r in rows if r["status"] == "succeeded" and not r.get("upright"))
        / max(n_scenes, 1),
        "ik_ms_median": _median(ik_ms),
        "collision_check_us_median": _median(check_us),
        "grasp_selection_ms_median": _median([x for x in sel_ms if np.isfinite(x)]),
        "plan_ms_median": _median(plan_ms),
        "plan_ms_p90": float(np.percentile(plan_ms, 90)) if plan_ms else None,
        "plan_ms_median_rrt": _median(rrt_ms),
        "plan_rrt_count": len(rrt_ms),
        "plan_search_ms_median": _median(parts["search"]),
        "plan_simplify_ms_median": _median(parts["simplify"]),
        "plan_recheck_ms_median": _median(parts["recheck"]),
        "pick_ms_median": _median(pick_ms),
        "place_ms_median": _median(place_ms),
        "segments_rechecked": segments_checked,
        "fcl_violations": fcl_violations,
        "sim_contact_plans": sim_collisions,
        "failures": dict(failures),
        "per_scene": rows,
    }


def run(args: argparse.Namespace) -> int:
    from kitchenbot.executive.config import load_config

    cfg = load_config(args.config)

    def progress(row):
        print(f"  scene {row['seed']:4d}: {row['status']:9s} {row.get('object') or '':6s} "
              f"{row.get('grasp') or '':18s} {row.get('slot') or '':10s} cleared {row['cleared']}/{row['objects']} "
              f"{row.get('reason') or ''}", flush=True)

    rep = run_bench(args.scenes, args.seed, cfg, args.objects, args.check_step, progress, tuple(args.pose_noise),
                    args.clear)
    print()
    fmt = lambda v, u="": "-" if v is None else (f"{v:.3f}{u}" if isinstance(v, float) else f"{v}{u}")  # noqa: E731
    for key, unit in (("success_rate", ""), ("success_inverted_or_plate_rate", ""), ("objects_cleared_fraction", ""),("ik_ms_median", " ms"), ("collision_check_us_median", " us"),
                      ("grasp_selection_ms_median", " ms"),
                      ("plan_ms_median", " ms"), ("plan_ms_p90", " ms"), ("plan_ms_median_rrt", " ms"),
                      ("plan_rrt_count", ""),
                      ("plan_search_ms_median", " ms"), ("plan_simplify_ms_median", " ms"),
                      ("plan_recheck_ms_median", " ms"), ("pick_ms_median", " ms"),
                      ("place_ms_median", " ms"), ("segments_rechecked", ""), ("fcl_violations", ""),
                      ("sim_contact_plans", "")):
        print(f"{key:28s} {fmt(rep[key], unit)}")
    print(f"{'failures':28s} {rep['failures']}")
    if args.report:
        Path(args.report).write_text(json.dumps(rep, indent=2))
        print(f"report: {args.report}")
    return 0
