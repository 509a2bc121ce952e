"""The calibration routine end to end in the simulated cell over several seeds: error against the hidden camera
mount for Park–Martin alone and after the pixel refinement.

    python benchmarks/calibration_sim.py [--seeds 5] [--samples 15]        # = kitchenbot bench calibration-sim
"""

from __future__ import annotations

import argparse

from kitchenbot.bench.calibration import sim_table

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--samples", type=int, default=15)
    a = ap.parse_args()
    raise SystemExit(sim_table(a.seeds, a.samples))
