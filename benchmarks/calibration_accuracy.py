"""Hand-eye accuracy versus board-pose noise and sample count (Park–Martin on all pairs, least-median start,
MAD rejection), both mounts, synthetic sample sets with a known X.

    python benchmarks/calibration_accuracy.py [--trials 30] [--seed 0]     # = kitchenbot bench calibration-accuracy
"""

from __future__ import annotations

import argparse

from kitchenbot.bench.calibration import accuracy_table

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    raise SystemExit(accuracy_table(a.trials, a.seed))
