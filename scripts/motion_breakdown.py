"""Where one simulated run's time goes: `python scripts/motion_breakdown.py TASK SEED [--objects N] [--oracle]
[--json F]` (`--oracle`: oracle perception, motion without perception's variance; with `--json F` every trajectory
run is also pickled to F + ".trajs.pkl" as (name, times, q, carrying) for offline analysis).

Runs ``run_task`` (the path `kitchenbot run --sim` takes, fake drivers) and sums the simulated seconds spent in each
kind of motion (the runner's trajectories by their planner name: approach, grasp_in, lift, transfer, lower,
retreat, move (scan waypoints, look-downs, home), escape, ...), in the gripper's commands and in camera frames,
beside the run report's simulated seconds per state and its compute (CPU) per stage. Per placed item too.
Set KITCHENBOT_PLANNER_MAX_ITERATIONS / KITCHENBOT_PLANNER_SEED for runs that do not depend on the machine's load.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter


def _timed(counter: Counter, counts: Counter, key_of, fn, clock):
    def wrapper(*args, **kwargs):
        t0 = clock()
        try:
            return fn(*args, **kwargs)
        finally:
            k = key_of(*args, **kwargs)
            counter[k] += clock() - t0
            counts[k] += 1
    return wrapper


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("task")
    ap.add_argument("seed", type=int)
    ap.add_argument("--objects", type=int, default=None)
    ap.add_argument("--json", default=None)
    ap.add_argument("--oracle", action="store_true", help="oracle perception (motion without perception's variance)")
    a = ap.parse_args()
    from kitchenbot.executive.config import DriversConfig, load_config
    from kitchenbot.executive.runner import run_task

    cfg = load_config()
    cfg = cfg.model_copy(update={"drivers": DriversConfig()})
    if a.objects is not None:
        cfg.sim.min_objects = cfg.sim.max_objects = a.objects
    sim, n = Counter(), Counter()
    moves, n_moves = Counter(), Counter()  # planned joint moves ("trajectory move") by what they were for

    trajs: list = []  # every trajectory run: (name, times, q), for offline analysis (--json F: F + ".trajs.pkl")

    def hook(runner) -> None:
        clock = runner._sim_now
        run = runner._run_trajectory

        def recorded(traj, *args, **kwargs):
            trajs.append((traj.name, traj.times, traj.q, bool(kwargs.get("carrying", args[0] if args else False))))
            return run(traj, *args, **kwargs)
        runner._run_trajectory = recorded
        runner._run_trajectory = _timed(sim, n, lambda traj, *a, **k: f"trajectory {traj.name}",
                                        runner._run_trajectory, clock)
        runner._move_joints = _timed(moves, n_moves, lambda q, what, *a, **k: what.split(" (")[0].rstrip("0123456789 "),
                                     runner._move_joints, clock)
        g = runner.robot.gripper
        for name in ("open", "grasp"):
            setattr(g, name, _timed(sim, n, lambda *a, _n=name, **k: f"gripper {_n}", getattr(g, name), clock))
        cam = runner.robot.camera
        cam.capture = _timed(sim, n, lambda *a, **k: "camera frames", cam.capture, clock)

    rep = run_task(cfg, a.task, a.seed, progress=False, journal_path=False, runner_hook=hook,
                   oracle_perception=a.oracle)
    placed = rep.truth["end"]["delivered"]
    total = rep.sim_time_s or 0.0
    print(f"{a.task} {a.seed}: {rep.status}, placed {placed}/{rep.truth['start']['in_sink']}, collisions "
          f"{rep.collisions}, simulated {total:.1f} s, compute CPU {rep.compute_cpu_time_s:.1f} s")
    print(f"{'simulated time in':<28} {'s':>7} {'count':>6} {'s per placed':>13}")
    for k, v in sorted(sim.items(), key=lambda kv: -kv[1]):
        print(f"{k:<28} {v:7.1f} {n[k]:6d} {v / max(placed, 1):13.2f}")
    for k, v in sorted(moves.items(), key=lambda kv: -kv[1]):
        print(f"{'  of which joint moves to ' + k:<28} {v:7.1f} {n_moves[k]:6d} {v / max(placed, 1):13.2f}")
    rest = total - sum(sim.values())
    print(f"{'other (polls, waits)':<28} {rest:7.1f} {'':6} {rest / max(placed, 1):13.2f}")
    print("simulated s by state: " + ", ".join(f"{k} {v:.1f}" for k, v in
                                              sorted(rep.state_sim_time_s.items(), key=lambda x: -x[1])))
    print("compute CPU s by stage: " + ", ".join(f"{k} {v:.1f}" for k, v in
                                                 sorted(rep.compute_cpu_by_stage_s.items(), key=lambda x: -x[1])))
    if a.json:
        import pickle

        with open(a.json + ".trajs.pkl", "wb") as f:
            pickle.dump(trajs, f)
        with open(a.json, "w") as f:
            json.dump({"placed": placed, "sim_s": total, "by_kind_s": dict(sim), "counts": dict(n), "joint_moves_s": dict(moves),
                       "state_sim_s": rep.state_sim_time_s, "compute_cpu_by_stage_s": rep.compute_cpu_by_stage_s,
                       "cycles": rep.cycles, "collisions": rep.collisions,
                       "compute_cpu_s": rep.compute_cpu_time_s}, f, indent=1, default=str)


if __name__ == "__main__":
    main()
