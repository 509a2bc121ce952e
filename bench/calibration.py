"""Calibration benchmarks (`kitchenbot bench calibration-accuracy | calibration-sim`), also run by the scripts
benchmarks/calibration_accuracy.py and benchmarks/calibration_sim.py. They print tables; nothing is timed
in the tests."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

NOISE = [(0.0, 0.0), (0.02, 0.1), (0.05, 0.25), (0.1, 0.5), (0.2, 1.0), (0.5, 2.0)]
COUNTS = [5, 10, 20]


def register(bs: argparse._SubParsersAction) -> None:
    a = bs.add_parser("calibration-accuracy",
                      help="hand-eye error vs board-pose noise and sample count (synthetic, both mounts)")
    a.add_argument("--trials", type=int, default=30)
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--report", type=Path, help="also write the rows as JSON")
    a.set_defaults(func=lambda args: accuracy_table(args.trials, args.seed, args.report))
    s = bs.add_parser("calibration-sim", help="calibrate --sim over several seeds: error vs the hidden mount")
    s.add_argument("--seeds", type=int, default=5)
    s.add_argument("--samples", type=int, default=15)
    s.add_argument("--report", type=Path, help="also write the rows as JSON")
    s.set_defaults(func=lambda args: sim_table(args.seeds, args.samples, args.report))


def accuracy_table(trials: int = 30, seed: int = 0, report: Path | None = None) -> int:
    """Median / p95 error against the hidden X for Gaussian noise on T_cam_board (sigma per axis, deg and mm),
    with and without one gross outlier (a flipped board pose); `plain` is Park–Martin without rejection."""
    from kitchenbot.calibration import synthetic
    from kitchenbot.calibration.park_martin import solve_park_martin
    from kitchenbot.calibration.residuals import solve_robust
    from kitchenbot.transforms import make_T, pose_error

    rng = np.random.default_rng(seed)
    rows = []
    print(f"{'mount':<12} {'N':>3} {'noise deg/mm':>13} {'outlier':>7} | {'err deg p50':>11} {'p95':>7} | "
          f"{'err mm p50':>10} {'p95':>7} | {'resid deg':>9} {'resid mm':>8} | {'plain mm p50':>12} | {'ms':>6}")
    for mount in ("eye_in_hand", "eye_to_hand"):
        for n in COUNTS:
            for rot, tr in NOISE:
                for outlier in (False, True):
                    if outlier and (rot, tr) != (0.05, 0.25):
                        continue
                    er, et, rr, rt, ep, dt = [], [], [], [], [], []
                    for _ in range(trials):
                        F, C = synthetic.samples(mount, n, rng, rot, tr)
                        if outlier:
                            C[1] = C[1] @ make_T(np.diag([1.0, -1.0, -1.0]), [0.02, 0.0, 0.0])
                        t0 = time.perf_counter()
                        res = solve_robust(F, C, mount)
                        dt.append(time.perf_counter() - t0)
                        r, t = pose_error(res.X, synthetic.X_TRUE)
                        er.append(np.rad2deg(r))
                        et.append(t * 1000)
                        rr.append(res.rotation_deg_mean)
                        rt.append(res.translation_mm_mean)
                        ep.append(pose_error(solve_park_martin(F, C, mount).X, synthetic.X_TRUE)[1] * 1000)
                    row = dict(mount=mount, n=n, noise_deg=rot, noise_mm=tr, outlier=outlier,
                               err_deg_p50=float(np.median(er)), err_deg_p95=float(np.percentile(er, 95)),
                               err_mm_p50=float(np.median(et)), err_mm_p95=float(np.percentile(et, 95)),
                               residual_deg=float(np.mean(rr)), residual_mm=float(np.mean(rt)),
                               plain_err_mm_p50=float(np.median(ep)), solve_ms_p50=1000 * float(np.median(dt)))
                    rows.append(row)
                    print(f"{mount:<12} {n:>3} {rot:>6.2f}/{tr:<6.2f} {'yes' if outlier else 'no':>7} | "
                          f"{row['err_deg_p50']:>11.4f} {row['err_deg_p95']:>7.4f} | "
                          f"{row['err_mm_p50']:>10.3f} {row['err_mm_p95']:>7.3f} | "
                          f"{row['residual_deg']:>9.4f} {row['residual_mm']:>8.3f} | "
                          f"{row['plain_err_mm_p50']:>12.3f} | {row['solve_ms_p50']:>6.2f}", flush=True)
    if report:
        report.write_text(json.dumps(rows, indent=1))
    return 0


def sim_table(seeds: int = 5, samples: int = 15, report: Path | None = None) -> int:
    """The full routine in the simulated cell per seed: error of Park–Martin alone and refined, wall time."""
    from kitchenbot.calibration.board import CharucoSpec
    from kitchenbot.calibration.routine import RoutineSettings, run_routine, tool_spheres
    from kitchenbot.executive.calibration_sim import make_calibration_sim
    from kitchenbot.executive.config import load_config
    from kitchenbot.transforms import pose_error
    from kitchenbot.world.cell import Cell

    cfg = load_config()
    spec = CharucoSpec()
    rows = []
    print(f"{'seed':>4} {'views':>5} | {'PM deg':>7} {'PM mm':>6} | {'refined deg':>11} {'mm':>6} | "
          f"{'resid deg':>9} {'resid mm':>8} | {'rms px':>6} | {'collisions':>10} | {'s':>5}")
    for seed in range(seeds):
        t0 = time.perf_counter()
        sim = make_calibration_sim(cfg, spec, seed=seed)
        rep = run_routine(sim.arm, sim.camera, spec, sim.T_flange_cam_nominal, RoutineSettings(samples=samples),
                          seed=seed, boxes=Cell(cfg.cell).boxes,
                          extra=tool_spheres(cfg.robot.tool.T_flange_tcp.matrix(), sim.T_flange_cam_nominal))
        wall = time.perf_counter() - t0
        truth = sim.world.T_flange_cam
        r0, t0_ = pose_error(rep.park_martin.X, truth)
        r1, t1 = pose_error(rep.result.X, truth)
        row = dict(seed=seed, views=len(rep.result.samples_used), pm_err_deg=float(np.rad2deg(r0)),
                   pm_err_mm=1000 * t0_, err_deg=float(np.rad2deg(r1)), err_mm=1000 * t1,
                   residual_deg=rep.result.rotation_deg_mean, residual_mm=rep.result.translation_mm_mean,
                   reprojection_px=rep.refinement.rms_px_after, collisions=sim.arm.log.collisions, wall_s=wall)
        rows.append(row)
        print(f"{seed:>4} {row['views']:>5} | {row['pm_err_deg']:>7.4f} {row['pm_err_mm']:>6.3f} | "
              f"{row['err_deg']:>11.4f} {row['err_mm']:>6.3f} | {row['residual_deg']:>9.4f} "
              f"{row['residual_mm']:>8.3f} | {row['reprojection_px']:>6.3f} | {row['collisions']:>10} | "
              f"{wall:>5.1f}", flush=True)
    for key in ("pm_err_deg", "pm_err_mm", "err_deg", "err_mm"):
        vals = [r[key] for r in rows]
        print(f"{key}: median {np.median(vals):.4f}, max {np.max(vals):.4f}")
    if report:
        report.write_text(json.dumps(rows, indent=1))
    return 0
