"""The order the arm visits the scan waypoints in: the one with the least joint travel from where the arm is.

The views are the same whatever the order (the scene does not change during a scan) and perception gets them
back in the configured order, so only the time the moves take changes. Travel between two joint configurations
is measured as the largest joint change (a synchronised joint move's duration grows with it). All orders are
tried: a scan has a handful of waypoints (more than MAX_PERMUTED: the configured order).
"""

from __future__ import annotations

from itertools import permutations

import numpy as np

MAX_PERMUTED = 6  # 720 orders


def travel(q0: np.ndarray, order: tuple[int, ...], waypoints: np.ndarray) -> float:
    """Joint travel (rad, the largest joint change per move, summed) from q0 through the waypoints in `order`."""
    path = np.vstack([np.asarray(q0, float)[None], waypoints[list(order)]])
    return float(np.abs(np.diff(path, axis=0)).max(axis=1).sum())


def visit_order(q_now: np.ndarray, waypoints) -> list[int]:
    """Indices of `waypoints` in the order of least joint travel from `q_now` (ties: the configured order)."""
    W = np.asarray(waypoints, float).reshape(-1, 6)
    n = len(W)
    if n > MAX_PERMUTED:
        return list(range(n))
    best = min(permutations(range(n)), key=lambda o: (round(travel(q_now, o, W), 9), o))
    return list(best)
