"""Hand-eye calibration by Park & Martin (1994), "Robot sensor calibration: solving AX = XB on the
Euclidean group", IEEE T-RA 10(5).

Every pair of samples (i, j) gives one motion equation ``A X = X B`` between two rigid motions A (robot side)
and B (camera side) that share the unknown X. The chains per mount (F_i = T_base_flange_i, C_i = T_cam_board_i):

* eye in hand (camera on the flange, board fixed in the base frame), X = T_flange_cam.
  The board does not move: ``F_i X C_i = F_j X C_j = T_base_board``, hence
  ``A = F_j^-1 F_i`` (flange motion seen from flange j), ``B = C_j C_i^-1`` (board motion in camera j).
* eye to hand (camera fixed, board on the flange), X = T_base_cam.
  The board does not move on the flange: ``F_i^-1 X C_i = F_j^-1 X C_j = T_flange_board``, hence
  ``A = F_j F_i^-1`` (flange motion in the base frame), ``B = C_j C_i^-1``.

Rotation: with alpha = log(R_A), beta = log(R_B) (axis-angle vectors), ``R_A R_X = R_X R_B`` means
``alpha = R_X beta``. The least-squares R_X over all pairs is the orthogonal polar factor of
``M = sum beta alpha^T``: ``R_X = (M^T M)^(-1/2) M^T``. It is unique when at least two motions have
non-parallel rotation axes (so >= 3 samples). Translation: ``(R_A - I) t_X = R_X t_B - t_A`` stacked over
all pairs, ``t_X = (C^T C)^-1 C^T d`` (solved with lstsq).

Written here because OpenCV 5 dropped ``calibrateHandEye`` and the method is a dozen lines of numpy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from kitchenbot.transforms import check_rigid, inv

Mount = Literal["eye_in_hand", "eye_to_hand"]
MOUNTS: tuple[str, ...] = ("eye_in_hand", "eye_to_hand")
# The name of X in each mount, as written to the calibration file.
X_NAME: dict[str, str] = {"eye_in_hand": "T_flange_cam", "eye_to_hand": "T_base_cam"}

MIN_SAMPLES = 3
MIN_ROTATION_DEG = 2.0  # relative rotations smaller than this carry almost no axis information
MIN_AXIS_SPREAD_DEG = 5.0  # the rotation axes must span a plane at least this "open"


class DegenerateSetError(ValueError):
    """The sample set cannot determine X (too few samples, parallel rotation axes, or tiny rotations)."""


@dataclass
class HandEyeSolution:
    X: np.ndarray  # T_flange_cam (eye in hand) or T_base_cam (eye to hand)
    mount: str
    pairs: list[tuple[int, int]]  # sample index pairs (i, j) used
    A: list[np.ndarray] = field(repr=False)
    B: list[np.ndarray] = field(repr=False)

    @property
    def name(self) -> str:
        return X_NAME[self.mount]


def check_mount(mount: str) -> str:
    if mount not in MOUNTS:
        raise ValueError(f"mount: expected one of {list(MOUNTS)}, got {mount!r}")
    return mount


def as_transforms(Ts: Sequence[np.ndarray], name: str) -> list[np.ndarray]:
    """Validate a list of rigid 4x4 transforms, naming the offending entry."""
    return [check_rigid(T, f"{name}[{k}]") for k, T in enumerate(Ts)]


def all_pairs(n: int) -> list[tuple[int, int]]:
    return list(combinations(range(n), 2))


def motion_pairs(
    T_base_flange: Sequence[np.ndarray],
    T_cam_board: Sequence[np.ndarray],
    mount: str,
    pairs: Sequence[tuple[int, int]] | None = None,
) -> tuple[list[np.ndarray], list[np.ndarray], list[tuple[int, int]]]:
    """The (A, B) motions of each sample pair for `mount` (chains in the module docstring)."""
    check_mount(mount)
    F = as_transforms(T_base_flange, "T_base_flange")
    C = as_transforms(T_cam_board, "T_cam_board")
    if len(F) != len(C):
        raise ValueError(f"got {len(F)} T_base_flange but {len(C)} T_cam_board samples; expected one of each per pose")
    pairs = all_pairs(len(F)) if pairs is None else [tuple(p) for p in pairs]
    A, B = [], []
    for i, j in pairs:
        if mount == "eye_in_hand":
            A.append(inv(F[j]) @ F[i])
        else:
            A.append(F[j] @ inv(F[i]))
        B.append(C[j] @ inv(C[i]))
    return A, B, list(pairs)


def check_motions(A: Sequence[np.ndarray], n_samples: int | None = None) -> None:
    """Raise DegenerateSetError when the robot motions cannot determine the rotation of X."""
    n = n_samples if n_samples is not None else len(A) + 1
    if n < MIN_SAMPLES or len(A) < 2:
        raise DegenerateSetError(
            f"too few samples: {n} poses ({len(A)} motion pairs); hand-eye calibration needs at least "
            f"{MIN_SAMPLES} poses with non-parallel relative rotation axes"
        )
    rv = Rotation.from_matrix(np.array([a[:3, :3] for a in A])).as_rotvec()
    ang = np.linalg.norm(rv, axis=1)
    big = ang > np.deg2rad(MIN_ROTATION_DEG)
    if np.count_nonzero(big) < 2:
        raise DegenerateSetError(
            f"rotations too small: only {np.count_nonzero(big)} of {len(A)} relative motions rotate more than "
            f"{MIN_ROTATION_DEG} deg (largest {np.rad2deg(ang.max()):.2f} deg); tilt the wrist between poses"
        )
    axes = rv[big] / ang[big, None]
    # Axes are lines (a and -a are the same axis): the second singular value of the stacked unit axes
    # measures how far they leave a single line.
    s = np.linalg.svd(axes, compute_uv=False)
    spread = s[1] / s[0] if s[0] > 0 else 0.0
    if spread < np.sin(np.deg2rad(MIN_AXIS_SPREAD_DEG)):
        raise DegenerateSetError(
            f"rotation axes parallel: all {len(axes)} relative rotations turn about (nearly) one axis "
            f"(spread {np.rad2deg(np.arcsin(min(spread, 1.0))):.2f} deg < {MIN_AXIS_SPREAD_DEG} deg); "
            "rotate about at least two different axes"
        )


def log_rotations(Ts: Sequence[np.ndarray]) -> np.ndarray:
    """(m, 3) axis-angle vectors (the log map) of the rotation parts of m transforms."""
    return Rotation.from_matrix(np.array([T[:3, :3] for T in Ts])).as_rotvec()


def rotation_from_logs(alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """R_X = (M^T M)^(-1/2) M^T with M = sum beta alpha^T (Park & Martin's rotation step).

    Computed through the SVD M^T = U S V^T, where (M^T M)^(-1/2) M^T = U V^T. With consistent data that is a
    rotation; grossly inconsistent data (outliers, a wrong mount) can make it a reflection, and then the
    nearest rotation U diag(1, 1, -1) V^T (the Kabsch/Wahba correction) is returned so that outlier rejection
    can still start from it.
    """
    M = beta.T @ alpha  # sum_k beta_k alpha_k^T
    U, S, Vt = np.linalg.svd(M.T)
    if S[1] <= 1e-9 * max(S[0], 1e-300):
        raise DegenerateSetError("rotation axes parallel: M^T M is singular, the rotation of X is not determined")
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def solve_rotation(A: Sequence[np.ndarray], B: Sequence[np.ndarray]) -> np.ndarray:
    """Rotation of X from motion pairs (see :func:`rotation_from_logs`)."""
    return rotation_from_logs(log_rotations(A), log_rotations(B))


def solve_translation(A: Sequence[np.ndarray], B: Sequence[np.ndarray], R_X: np.ndarray) -> np.ndarray:
    """t_X from (R_A - I) t_X = R_X t_B - t_A, least squares over all pairs."""
    C = np.concatenate([a[:3, :3] - np.eye(3) for a in A])
    d = np.concatenate([R_X @ b[:3, 3] - a[:3, 3] for a, b in zip(A, B)])
    t, *_ = np.linalg.lstsq(C, d, rcond=None)
    return t


def solve_motions(A: Sequence[np.ndarray], B: Sequence[np.ndarray], n_samples: int | None = None) -> np.ndarray:
    """X from motion pairs A_k X = X B_k."""
    if len(A) != len(B):
        raise ValueError(f"got {len(A)} A motions but {len(B)} B motions")
    check_motions(A, n_samples)
    R = solve_rotation(A, B)
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = solve_translation(A, B, R)
    return X


def solve_park_martin(
    T_base_flange: Sequence[np.ndarray],
    T_cam_board: Sequence[np.ndarray],
    mount: str = "eye_in_hand",
    pairs: Sequence[tuple[int, int]] | None = None,
) -> HandEyeSolution:
    """Solve X (T_flange_cam for eye in hand, T_base_cam for eye to hand) from per-pose samples.

    `pairs` selects which sample pairs form motions (default: all i < j). Raises DegenerateSetError naming
    the degeneracy when the samples cannot determine X.
    """
    n = len(T_base_flange)
    if n < MIN_SAMPLES:
        raise DegenerateSetError(
            f"too few samples: {n} poses; hand-eye calibration needs at least {MIN_SAMPLES} poses with "
            "non-parallel relative rotation axes"
        )
    A, B, used = motion_pairs(T_base_flange, T_cam_board, mount, pairs)
    n_used = len({k for p in used for k in p})
    X = solve_motions(A, B, n_samples=n_used)
    return HandEyeSolution(X=X, mount=mount, pairs=used, A=A, B=B)
