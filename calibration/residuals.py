"""How good is a hand-eye solution: AX = XB residuals per pair, the spread of the fixed frame across samples,
and robust rejection of outlier pairs (median/MAD on pair residuals, then re-solve on the retained ones).

Park & Martin report 0.614 deg / 3.44 mm mean residuals on their robot; a good wrist camera on a UR with
ChArUco reaches a fraction of that.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
from scipy.spatial.transform import Rotation

from kitchenbot.calibration.park_martin import (
    MIN_ROTATION_DEG,
    DegenerateSetError,
    X_NAME,
    as_transforms,
    check_mount,
    log_rotations,
    motion_pairs,
    rotation_from_logs,
    solve_motions,
    solve_translation,
)
from kitchenbot.transforms import inv

# 1.4826 * MAD estimates the standard deviation of normally distributed data.
MAD_SCALE = 1.4826


def pair_residuals(X: np.ndarray, A: Sequence[np.ndarray], B: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per pair: rotation residual (deg) = angle of (A X)^-1 (X B); translation residual (mm) = |t(AX) - t(XB)|."""
    if len(A) == 0:
        return np.zeros(0), np.zeros(0)
    L = np.asarray(A) @ X
    R = X @ np.asarray(B)
    rel = np.transpose(L[:, :3, :3], (0, 2, 1)) @ R[:, :3, :3]
    rot = np.rad2deg(np.linalg.norm(Rotation.from_matrix(rel).as_rotvec(), axis=1))
    tr = 1000.0 * np.linalg.norm(L[:, :3, 3] - R[:, :3, 3], axis=1)
    return rot, tr


def fixed_frame_poses(
    X: np.ndarray, T_base_flange: Sequence[np.ndarray], T_cam_board: Sequence[np.ndarray], mount: str
) -> np.ndarray:
    """The frame that should not move, once per sample: T_base_board_i = F_i X C_i (eye in hand) or
    T_flange_board_i = F_i^-1 X C_i (eye to hand)."""
    check_mount(mount)
    if mount == "eye_in_hand":
        return np.array([F @ X @ C for F, C in zip(T_base_flange, T_cam_board)])
    return np.array([inv(F) @ X @ C for F, C in zip(T_base_flange, T_cam_board)])


@dataclass
class Spread:
    """Scatter of the fixed frame (board) across samples around its mean pose."""

    frame: str  # "T_base_board" or "T_flange_board"
    mean: np.ndarray
    translation_rms_mm: float
    translation_max_mm: float
    rotation_rms_deg: float
    rotation_max_deg: float
    per_sample_mm: np.ndarray
    per_sample_deg: np.ndarray

    def as_dict(self) -> dict:
        return {
            "frame": self.frame,
            "translation_rms_mm": self.translation_rms_mm,
            "translation_max_mm": self.translation_max_mm,
            "rotation_rms_deg": self.rotation_rms_deg,
            "rotation_max_deg": self.rotation_max_deg,
            "mean": self.mean.tolist(),
        }


def board_spread(
    X: np.ndarray, T_base_flange: Sequence[np.ndarray], T_cam_board: Sequence[np.ndarray], mount: str
) -> Spread:
    poses = fixed_frame_poses(X, T_base_flange, T_cam_board, mount)
    t = poses[:, :3, 3]
    t_mean = t.mean(axis=0)
    rots = Rotation.from_matrix(poses[:, :3, :3])
    r_mean = rots.mean()
    dt = 1000.0 * np.linalg.norm(t - t_mean, axis=1)
    dr = np.rad2deg(np.linalg.norm((r_mean.inv() * rots).as_rotvec(), axis=1))
    mean = np.eye(4)
    mean[:3, :3] = r_mean.as_matrix()
    mean[:3, 3] = t_mean
    return Spread(
        frame="T_base_board" if mount == "eye_in_hand" else "T_flange_board",
        mean=mean,
        translation_rms_mm=float(np.sqrt(np.mean(dt**2))),
        translation_max_mm=float(dt.max()),
        rotation_rms_deg=float(np.sqrt(np.mean(dr**2))),
        rotation_max_deg=float(dr.max()),
        per_sample_mm=dt,
        per_sample_deg=dr,
    )


def robust_z(x: np.ndarray) -> np.ndarray:
    """|x - median| / (1.4826 MAD); a tiny floor keeps noise-free data from dividing by zero."""
    med = np.median(x)
    mad = MAD_SCALE * np.median(np.abs(x - med))
    floor = 1e-9 + 1e-3 * abs(med)
    return np.abs(x - med) / max(mad, floor)


@dataclass
class HandEyeResult:
    X: np.ndarray
    mount: str
    n_samples: int
    pairs_used: list[tuple[int, int]]
    pairs_rejected: list[tuple[int, int]]
    rotation_deg: np.ndarray  # residual per used pair
    translation_mm: np.ndarray
    spread: Spread
    samples_used: list[int] = field(default_factory=list)
    method: str = "park_martin_1994"

    @property
    def name(self) -> str:
        return X_NAME[self.mount]

    @property
    def rotation_deg_mean(self) -> float:
        return float(np.mean(self.rotation_deg))

    @property
    def translation_mm_mean(self) -> float:
        return float(np.mean(self.translation_mm))

    def summary(self) -> dict:
        """Plain numbers for reports and the calibration file."""
        return {
            "rotation_deg": self.rotation_deg_mean,
            "translation_mm": self.translation_mm_mean,
            "rotation_deg_max": float(np.max(self.rotation_deg)),
            "translation_mm_max": float(np.max(self.translation_mm)),
            "rotation_deg_median": float(np.median(self.rotation_deg)),
            "translation_mm_median": float(np.median(self.translation_mm)),
            "pairs_used": len(self.pairs_used),
            "pairs_rejected": [list(p) for p in self.pairs_rejected],
            "pairs_retained": [list(p) for p in self.pairs_used],
            "samples_used": list(self.samples_used),
            "board_spread": self.spread.as_dict(),
        }


# A rotation error of X moves the board like a translation error at roughly this lever arm (mm/rad); it puts the
# two residuals on one scale for the least-median start.
LEVER_MM = 300.0


def _lmeds_start(A: list, B: list, pairs: list[tuple[int, int]], n: int, X_all: np.ndarray,
                 trials: int = 300, seed: int = 0) -> np.ndarray:
    """Least-median-of-squares start: X from random 3-sample subsets (3 pairs each) and from all pairs; keep the
    one whose median pair residual is smallest. Gross outliers (a flipped board pose) drag the all-pairs
    solution far enough that median/MAD alone may not find them; a clean minimal subset does not."""
    index = {p: k for k, p in enumerate(pairs)}
    rng = np.random.default_rng(seed)
    alpha, beta = log_rotations(A), log_rotations(B)
    min_angle = np.deg2rad(MIN_ROTATION_DEG)

    def score(X: np.ndarray) -> float:
        rot, tr = pair_residuals(X, A, B)
        return float(np.median(tr + LEVER_MM * np.deg2rad(rot)))

    best, best_score = X_all, score(X_all)
    subsets = list(combinations(range(n), 3))
    if len(subsets) > trials:
        subsets = [subsets[k] for k in rng.choice(len(subsets), trials, replace=False)]
    for i, j, k in subsets:
        sel = [index[(i, j)], index[(i, k)], index[(j, k)]]
        if np.count_nonzero(np.linalg.norm(alpha[sel], axis=1) > min_angle) < 2:
            continue
        try:
            R = rotation_from_logs(alpha[sel], beta[sel])
        except DegenerateSetError:
            continue
        X = np.eye(4)
        X[:3, :3] = R
        X[:3, 3] = solve_translation([A[m] for m in sel], [B[m] for m in sel], R)
        sc = score(X)
        if sc < best_score:
            best, best_score = X, sc
    return best


def solve_robust(
    T_base_flange: Sequence[np.ndarray],
    T_cam_board: Sequence[np.ndarray],
    mount: str = "eye_in_hand",
    z_max: float = 3.5,
    max_rounds: int = 3,
    reject: bool = True,
) -> HandEyeResult:
    """Park–Martin with outlier rejection: start from the least-median solution over minimal sample subsets,
    drop pairs whose rotation or translation residual is a robust outlier (z > `z_max` on median/MAD), re-solve
    on the retained pairs; repeat until the retained set stops changing. `reject=False` (or < 4 samples): plain
    Park–Martin on all pairs."""
    check_mount(mount)
    F = as_transforms(T_base_flange, "T_base_flange")
    C = as_transforms(T_cam_board, "T_cam_board")
    n = len(F)
    if n < 3:
        raise DegenerateSetError(
            f"too few samples: {n} poses; hand-eye calibration needs at least 3 poses with non-parallel "
            "relative rotation axes"
        )
    A_all, B_all, pairs_all = motion_pairs(F, C, mount)
    X = solve_motions(A_all, B_all, n_samples=n)  # also checks the whole set for degeneracy
    keep = np.ones(len(pairs_all), bool)
    if reject and n >= 4:
        X_start = _lmeds_start(A_all, B_all, pairs_all, n, X)
        prev = None
        for _ in range(max_rounds):
            rot, tr = pair_residuals(X_start, A_all, B_all)
            new_keep = (robust_z(rot) <= z_max) & (robust_z(tr) <= z_max)
            if prev is not None and np.array_equal(new_keep, prev):
                break
            idx = np.flatnonzero(new_keep)
            try:
                X_start = solve_motions([A_all[k] for k in idx], [B_all[k] for k in idx],
                                        n_samples=len({s for k in idx for s in pairs_all[k]}))
            except DegenerateSetError:
                break  # rejecting more would leave a degenerate set: keep the last good solution
            prev = new_keep
            X, keep = X_start, new_keep
    used = [pairs_all[k] for k in np.flatnonzero(keep)]
    rejected = [pairs_all[k] for k in np.flatnonzero(~keep)]
    return evaluate(X, F, C, mount, used, rejected)


def evaluate(
    X: np.ndarray,
    T_base_flange: Sequence[np.ndarray],
    T_cam_board: Sequence[np.ndarray],
    mount: str,
    pairs_used: Sequence[tuple[int, int]],
    pairs_rejected: Sequence[tuple[int, int]] = (),
    method: str = "park_martin_1994",
) -> HandEyeResult:
    """Residuals and board spread of a given X on the given pairs (used for Park–Martin and refined X alike)."""
    A, B, used = motion_pairs(T_base_flange, T_cam_board, mount, pairs_used)
    rot, tr = pair_residuals(X, A, B)
    samples_used = sorted({s for p in used for s in p})
    spread = board_spread(X, [T_base_flange[k] for k in samples_used], [T_cam_board[k] for k in samples_used], mount)
    return HandEyeResult(
        X=X,
        mount=mount,
        n_samples=len(T_base_flange),
        pairs_used=list(used),
        pairs_rejected=list(pairs_rejected),
        rotation_deg=rot,
        translation_mm=tr,
        spread=spread,
        samples_used=samples_used,
        method=method,
    )
