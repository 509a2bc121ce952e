"""Pose error metrics.

- ADI (= ADD-S), BOP toolkit definition: mean over the GT-posed model points of the distance to the nearest
  estimated-posed model point. Symmetric objects get ~0 error for poses that differ by a symmetry.
- ADD: mean distance between corresponding points (for completeness).
- Recall at 0.1 x diameter ("ADI %"), and the YCB-Video AUC of ADD-S up to 10 cm (1 mm steps, normalised).
- Per-image matching of estimates to ground truth of the same object id (Hungarian on the ADI errors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree


def _tf(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ T[:3, :3].T + T[:3, 3]


def adi(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray) -> float:
    """ADD-S error (same unit as the translations / points)."""
    e = _tf(T_est, points)
    g = _tf(T_gt, points)
    d, _ = cKDTree(e).query(g, k=1)
    return float(d.mean())


def add(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray) -> float:
    return float(np.linalg.norm(_tf(T_est, points) - _tf(T_gt, points), axis=1).mean())


def recall_at(errors: np.ndarray, thresholds: np.ndarray | float) -> float:
    """Fraction of errors below their threshold (inf = missed)."""
    e = np.asarray(errors, float)
    return float(np.mean(e < thresholds)) if len(e) else 0.0


def auc_adds(errors: np.ndarray, max_threshold: float = 0.10, step: float = 0.001) -> float:
    """YCB-Video AUC: area under accuracy(threshold) for thresholds 0..max (metres), divided by max."""
    e = np.asarray(errors, float)
    if len(e) == 0:
        return 0.0
    t = np.arange(0.0, max_threshold + step / 2, step)
    acc = (e[None, :] < t[:, None]).mean(axis=1)
    return float(np.trapezoid(acc, t) / max_threshold)


@dataclass
class Match:
    gt_index: int
    est_index: int  # -1 = missed
    error: float  # ADI, metres (inf when missed)


def match_image(gt: list[tuple[int, np.ndarray]], est: list[tuple[int, np.ndarray, float]],
                points: dict[int, np.ndarray]) -> tuple[list[Match], list[int]]:
    """Match estimates (obj_id, T, score) to ground truth (obj_id, T) of one image, per object id, minimising
    the total ADI. Returns one Match per GT instance and the indices of unmatched estimates."""
    matches: list[Match] = []
    used: set[int] = set()
    for oid in sorted({g[0] for g in gt} | {e[0] for e in est}):
        gi = [i for i, g in enumerate(gt) if g[0] == oid]
        ei = [j for j, e in enumerate(est) if e[0] == oid]
        if not gi:
            continue
        if not ei:
            matches += [Match(i, -1, np.inf) for i in gi]
            continue
        pts = points[oid]
        if len(pts) > 1000:
            pts = pts[np.linspace(0, len(pts) - 1, 1000).astype(int)]
        C = np.array([[adi(est[j][1], gt[i][1], pts) for j in ei] for i in gi])
        rows, cols = linear_sum_assignment(C)
        got = dict(zip(rows, cols))
        for r, i in enumerate(gi):
            if r in got:
                matches.append(Match(i, ei[got[r]], float(C[r, got[r]])))
                used.add(ei[got[r]])
            else:
                matches.append(Match(i, -1, np.inf))
    unmatched = [j for j in range(len(est)) if j not in used]
    return sorted(matches, key=lambda m: m.gt_index), unmatched
