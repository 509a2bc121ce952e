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


# ---- errors that matter to grasping ------------------------------------------------------------------------------
# ADI at 0.1 d forgives a 2 cm shift of a plate or a 20 deg lean of a nested bowl; a gripper with millimetres of
# margin does not. Per scan, in the base frame: how far the object's frame origin is off, how far its symmetry
# (z) axis leans from the true one, and which objects were missed or reported twice / where there is none.

def axis_tilt(T_est: np.ndarray, T_gt: np.ndarray) -> float:
    """Angle between the estimated and the true object z axes (radians; pi = upside down)."""
    return float(np.arccos(np.clip(T_est[:3, 2] @ T_gt[:3, 2], -1.0, 1.0)))


@dataclass
class ScanMatch:
    gt_index: int
    est_index: int  # -1 = missed
    translation: float  # metres (inf when missed)
    tilt: float  # radians (inf when missed)


def match_scan(gt: list[tuple[int, np.ndarray]], est: list[tuple[int, np.ndarray]],
               diameters: dict[int, float], gate: float = 0.5) -> tuple[list[ScanMatch], list[int]]:
    """Match estimates (obj_id, T_base_obj) to ground truth of one scan, per object id, minimising the total
    distance between frame origins; pairs farther apart than `gate` x diameter are not matched. Returns one
    ScanMatch per GT object and the indices of unmatched estimates (duplicates and phantoms)."""
    out: list[ScanMatch] = []
    used: set[int] = set()
    for oid in sorted({g[0] for g in gt}):
        gi = [i for i, g in enumerate(gt) if g[0] == oid]
        ei = [j for j, e in enumerate(est) if e[0] == oid]
        got: dict[int, int] = {}
        if ei:
            C = np.array([[np.linalg.norm(est[j][1][:3, 3] - gt[i][1][:3, 3]) for j in ei] for i in gi])
            big = 1e6
            rows, cols = linear_sum_assignment(np.where(C < gate * diameters[oid], C, big))
            got = {r: c for r, c in zip(rows, cols) if C[r, c] < gate * diameters[oid]}
        for r, i in enumerate(gi):
            if r in got:
                j = ei[got[r]]
                used.add(j)
                out.append(ScanMatch(i, j, float(np.linalg.norm(est[j][1][:3, 3] - gt[i][1][:3, 3])),
                                     axis_tilt(est[j][1], gt[i][1])))
            else:
                out.append(ScanMatch(i, -1, np.inf, np.inf))
    return sorted(out, key=lambda m: m.gt_index), [j for j in range(len(est)) if j not in used]


def grasp_error_summary(translations: list[float], tilts: list[float], extra: int,
                        max_translation: float = 0.01, max_tilt: float = np.radians(5)) -> dict:
    """Per-class summary: GT count, missed, extra estimates, median / 90th-percentile translation (mm) and
    tilt (deg) over the matched ones, and the fraction of GT objects within max_translation and max_tilt
    (a missed object counts as outside)."""
    t, a = np.asarray(translations, float), np.asarray(tilts, float)
    found = np.isfinite(t)

    def q(x: np.ndarray, p: float, scale: float) -> float | None:
        return float(np.percentile(x, p) * scale) if len(x) else None

    return {"n": int(len(t)), "missed": int((~found).sum()), "extra": int(extra),
            "translation_mm_median": q(t[found], 50, 1000), "translation_mm_p90": q(t[found], 90, 1000),
            "tilt_deg_median": q(a[found], 50, np.degrees(1)), "tilt_deg_p90": q(a[found], 90, np.degrees(1)),
            "within": float(np.mean(found & (t < max_translation) & (a < max_tilt))) if len(t) else 0.0}
