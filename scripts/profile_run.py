"""Profile one simulated task run (CPU time): `python scripts/profile_run.py TASK SEED OUT [--objects N] [--oracle]
[--plan-only]`.

cProfile with a process-CPU timer over ``run_task`` (the path `kitchenbot run --sim` takes), the shipped simulation
config with fake drivers. Writes OUT.pstats, OUT.txt (the top functions by cumulative CPU time) and prints the run's
placed count, compute per cycle (CPU) and compute by stage. `--plan-only`: the profiler runs only inside the plan
stage (`Execution._do_plan`), the rest of the run unprofiled (docs/executive.md, "The plan stage by function"). Set KITCHENBOT_PLANNER_MAX_ITERATIONS /
KITCHENBOT_PLANNER_SEED for a planner that does not depend on the machine's load (docs/executive.md, "Cycle time").
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time

import numpy as np


def cpu_profile(call, out: str, top: int = 80, plan_only: bool = False):
    """`call()` under cProfile with a process-CPU timer: OUT.pstats, OUT.txt (the top functions by cumulative CPU
    time); returns (its result, the CPU seconds it took, profiler included). scripts/first_perception.py uses it.
    `plan_only`: profile only while the task runner plans an item (Execution._do_plan)."""
    pr = cProfile.Profile(time.process_time)
    c0 = time.process_time()
    if plan_only:
        from kitchenbot.executive import execution

        plan = execution.Execution._do_plan

        def profiled(self):
            pr.enable()
            try:
                return plan(self)
            finally:
                pr.disable()

        execution.Execution._do_plan = profiled
        try:
            res = call()
        finally:
            execution.Execution._do_plan = plan
    else:
        pr.enable()
        res = call()
        pr.disable()
    cpu = time.process_time() - c0
    pr.dump_stats(out + ".pstats")
    s = io.StringIO()
    pstats.Stats(pr, stream=s).sort_stats("cumulative").print_stats(top)
    with open(out + ".txt", "w") as f:
        f.write(s.getvalue())
    return res, cpu


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("task")
    ap.add_argument("seed", type=int)
    ap.add_argument("out")
    ap.add_argument("--objects", type=int, default=None)
    ap.add_argument("--top", type=int, default=80)
    ap.add_argument("--oracle", action="store_true", help="oracle perception (simulator truth), not the pipeline")
    ap.add_argument("--plan-only", action="store_true", help="profile the plan stage only (Execution._do_plan)")
    a = ap.parse_args()
    from kitchenbot.executive.config import DriversConfig, load_config
    from kitchenbot.executive.runner import run_task

    cfg = load_config()
    cfg = cfg.model_copy(update={"drivers": DriversConfig()})
    if a.objects is not None:
        cfg.sim.min_objects = cfg.sim.max_objects = a.objects
    rep, _ = cpu_profile(lambda: run_task(cfg, a.task, a.seed, progress=False, journal_path=False,
                                          oracle_perception=a.oracle), a.out, a.top, a.plan_only)
    cpu = [c.get("compute_cpu_s") for c in rep.cycles if c.get("compute_cpu_s") is not None]
    print(f"{a.task} {a.seed}: {rep.status}, placed {rep.truth['end']['delivered']}/{rep.truth['start']['in_sink']}, "
          f"collisions {rep.collisions}, cycles {len(rep.cycles)}, simulated {rep.sim_time_s:.1f} s")
    if cpu:
        print(f"compute per cycle (CPU s): median {np.median(cpu):.2f}, p90 {np.percentile(cpu, 90):.2f}, "
              f"total {rep.compute_cpu_time_s:.1f}")
    print("compute by stage (CPU s): " + ", ".join(f"{k} {v:.1f}" for k, v in
                                                   sorted(rep.compute_cpu_by_stage_s.items(), key=lambda x: -x[1])))


if __name__ == "__main__":
    main()
