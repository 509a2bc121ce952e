#!/usr/bin/env python3
"""Hash the first perception of a simulated task scene, stage by stage (is perception run-to-run deterministic?).

    python scripts/first_perception.py sink-to-dishwasher 681 [--save views.pkl]
    python scripts/first_perception.py sink-to-dishwasher 681 --views views.pkl   # perceive saved views only
    python scripts/first_perception.py sink-to-dishwasher 681 --views views.pkl --profile OUT   # ... under cProfile

Assembles the cell as `kitchenbot run --sim` does (shipped simulation config, fake drivers), runs the task up to its
first `perceive`, and prints one line per pipeline stage: the stage, a short hash of its output (floats bit for bit)
and, for the poses, each pose's class and position. Run it in two processes and compare: the first stage whose
hash differs is where the runs part. Exits right after the first perception. `--profile OUT` (with --views): the
perception under cProfile with a process-CPU timer instead of the hashes: OUT.pstats, OUT.txt (top functions by
cumulative CPU time), and the call's CPU time and stage split printed (docs/executive.md, "Cycle time").
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pickle
import sys

import numpy as np


def digest(x, decimals: int | None = None) -> str:
    """A short hash of nested arrays / numbers / dataclasses; floats bit for bit, or rounded to `decimals`."""
    h = hashlib.sha1()

    def feed(v):
        if v is None:
            h.update(b"N")
        elif isinstance(v, np.ndarray):
            a = np.round(v.astype(float), decimals) if v.dtype.kind == "f" and decimals is not None else v
            h.update(str((a.shape, a.dtype.str)).encode())
            h.update(np.ascontiguousarray(a).tobytes())
        elif isinstance(v, (float, np.floating)):
            h.update(repr(float(v) if decimals is None else round(float(v), decimals)).encode())
        elif isinstance(v, (list, tuple)):
            h.update(b"[")
            for e in v:
                feed(e)
            h.update(b"]")
        elif isinstance(v, dict):
            for k in sorted(v, key=str):
                h.update(str(k).encode())
                feed(v[k])
        elif hasattr(v, "__dataclass_fields__"):
            h.update(type(v).__name__.encode())
            for k in v.__dataclass_fields__:
                if k not in ("timings_ms", "pose_ms", "timings_cpu_ms", "pose_cpu_ms"):
                    feed(getattr(v, k))
        else:
            h.update(repr(v).encode())

    feed(x)
    return h.hexdigest()[:12]


def instrument(perceiver, out: list[str]) -> None:
    """Wrap the pipeline's stages (module functions it calls, its own methods) to log a hash of each output."""
    from kitchenbot.perception import pipeline as P

    def wrap(owner, name, label=None):
        fn = getattr(owner, name)

        def w(*a, **k):
            r = fn(*a, **k)
            out.append(f"{label or name}: {digest(r)}")
            return r
        setattr(owner, name, w)

    for name in ("check_cell", "align_to_cell", "align_views", "find_surfaces", "associate", "build_map",
                 "consolidate", "clean_depths"):
        wrap(P, name)
    wrap(P.backends, "detect_and_segment")
    est = perceiver.estimate

    def estimate(query, views, found):
        out.append(f"  estimate in: {digest(query)} (found {len(found)})")
        hyp, q = est(query, views, found)
        out.append(f"  estimate out: {digest(hyp)} "
                   + ("none" if hyp is None else f"obj {hyp.obj_id} {np.round(hyp.T_base_obj[:3, 3], 6)}"))
        return hyp, q
    perceiver.estimate = estimate


def report(res, out: list[str]) -> None:
    out.append(f"result: {digest(res)}")
    out.append(f"poses: {digest([(p.obj_id, p.T_base_obj, p.score) for p in res.poses])}")
    for p in res.poses:
        out.append(f"  {p.cls:6s} {p.obj_id} {np.array2string(p.T_base_obj[:3, 3], precision=9)} "
                   f"score {p.score:.9f}")
    print("\n".join(out), flush=True)


def profile(perceiver, views, out: str) -> None:
    """One perception of `views` under cProfile (process CPU): OUT.pstats, OUT.txt; prints its CPU and stages."""
    from profile_run import cpu_profile  # scripts/profile_run.py (this script's folder is on sys.path)

    res, cpu = cpu_profile(lambda: perceiver.perceive(views), out, top=120)
    print(f"perceive: {cpu:.2f} s CPU (under the profiler), {len(res.poses)} poses; stages (CPU ms): "
          + ", ".join(f"{k} {v:.0f}" for k, v in res.timings_cpu_ms.items()), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("task", nargs="?")
    ap.add_argument("seed", nargs="?", type=int)
    ap.add_argument("--save", help="pickle the first scan's views here")
    ap.add_argument("--views", help="perceive the views pickled by --save (with the cell of TASK SEED), nothing else")
    ap.add_argument("--profile", help="with --views: profile the perception into PROFILE.pstats / PROFILE.txt")
    a = ap.parse_args()
    out: list[str] = []
    from kitchenbot.executive.config import DriversConfig, load_config

    cfg = load_config(None).model_copy(update={"drivers": DriversConfig()})
    if a.views:
        from kitchenbot.executive.assembly import assemble
        from kitchenbot.executive.session import make_perceiver

        with open(a.views, "rb") as f:
            views = pickle.load(f)
        perceiver, _ = make_perceiver(cfg, assemble(cfg, a.seed), False)
        if a.profile:
            profile(perceiver, views, a.profile)
            return
        out.append(f"views: {digest(views)}")
        instrument(perceiver, out)
        report(perceiver.perceive(views), out)
        return

    from kitchenbot.executive.runner import run_task

    def hook(runner) -> None:
        perceiver = runner.perceiver
        perceive = perceiver.perceive

        def first(views, *args, **kw):
            try:
                return _first(views, *args, **kw)
            except BaseException as e:  # the runner would take it for a fault and go on
                print(f"first_perception: {e!r}", flush=True)
                os._exit(1)

        def _first(views, *args, **kw):
            out.append(f"views: {digest(views)}")
            if a.save:
                with open(a.save, "wb") as f:
                    pickle.dump(views, f)
            instrument(perceiver, out)
            report(perceive(views, *args, **kw), out)
            sys.stdout.flush()
            os._exit(0)  # the first perception only
        perceiver.perceive = first

    run_task(cfg, a.task, a.seed, progress=False, journal_path=False, runner_hook=hook)


if __name__ == "__main__":
    main()
