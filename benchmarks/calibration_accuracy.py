"""Hand-eye accuracy versus board-pose noise and sample count (Park–Martin, all pairs, MAD rejection).

    python benchmarks/calibration_accuracy.py [--trials 30] [--seed 0]

Synthetic eye-in-hand and eye-to-hand sets (kitchenbot.calibration.synthetic): Gaussian noise on each
T_cam_board (rotation sigma per axis in deg, translation sigma per axis in mm), and optionally one gross outlier.
Prints the median and 95th percentile of the error against the hidden X, and the mean AX=XB residuals.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from kitchenbot.calibration import synthetic
from kitchenbot.calibration.park_martin import solve_park_martin
from kitchenbot.calibration.residuals import solve_robust
from kitchenbot.transforms import make_T, pose_error

NOISE = [(0.0, 0.0), (0.02, 0.1), (0.05, 0.25), (0.1, 0.5), (0.2, 1.0), (0.5, 2.0)]
COUNTS = [5, 10, 20]


def run(trials: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    print(f"{'mount':<12} {'N':>3} {'noise deg/mm':>13} {'outlier':>7} | {'err deg p50':>11} {'p95':>7} | "
          f"{'err mm p50':>10} {'p95':>7} | {'resid deg':>9} {'resid mm':>8} | {'plain mm p50':>12} | {'ms':>6}")
    for mount in ("eye_in_hand", "eye_to_hand"):
        for n in COUNTS:
            for rot, tr in NOISE:
                for outlier in (False, True):
                    if outlier and (rot, tr) not in ((0.05, 0.25),):
                        continue
                    er, et, rr, rt, ep, dt = [], [], [], [], [], []
                    for _ in range(trials):
                        F, C = synthetic.samples(mount, n, rng, rot, tr)
                        if outlier:
                            C[1] = C[1] @ make_T(np.diag([1.0, -1.0, -1.0]), [0.02, 0.0, 0.0])  # a flipped pose
                        t0 = time.perf_counter()
                        res = solve_robust(F, C, mount)
                        dt.append(time.perf_counter() - t0)
                        r, t = pose_error(res.X, synthetic.X_TRUE)
                        er.append(np.rad2deg(r))
                        et.append(t * 1000)
                        rr.append(res.rotation_deg_mean)
                        rt.append(res.translation_mm_mean)
                        ep.append(pose_error(solve_park_martin(F, C, mount).X, synthetic.X_TRUE)[1] * 1000)
                    print(f"{mount:<12} {n:>3} {rot:>6.2f}/{tr:<6.2f} {'yes' if outlier else 'no':>7} | "
                          f"{np.median(er):>11.4f} {np.percentile(er, 95):>7.4f} | "
                          f"{np.median(et):>10.3f} {np.percentile(et, 95):>7.3f} | "
                          f"{np.mean(rr):>9.4f} {np.mean(rt):>8.3f} | {np.median(ep):>12.3f} | "
                          f"{1000 * np.median(dt):>6.2f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    run(a.trials, a.seed)
