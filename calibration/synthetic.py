"""Synthetic hand-eye sample sets with a known answer: random flange poses, the board poses they imply through
a hidden X, optional Gaussian noise. Used by the tests and the accuracy benchmark."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kitchenbot.transforms import inv, make_T

# A generic mount (no symmetry: X != X^-1, no identity-like rotation).
X_TRUE = make_T(Rotation.from_euler("xyz", [0.12, -0.2, 1.4]).as_matrix(), [0.032, -0.071, 0.046])
T_BASE_BOARD = make_T(Rotation.from_euler("xyz", [np.pi, 0.05, 0.3]).as_matrix(), [0.55, 0.05, 0.0])
T_FLANGE_BOARD = make_T(Rotation.from_euler("xyz", [0.1, 0.0, 0.4]).as_matrix(), [0.0, 0.02, 0.08])


def flange_poses(n: int, rng: np.random.Generator, max_tilt: float = 0.6) -> list[np.ndarray]:
    """Flange poses above a work area, rotations spread around a downward-looking nominal."""
    nominal = Rotation.from_euler("x", np.pi)
    out = []
    for _ in range(n):
        r = Rotation.from_rotvec(rng.uniform(-max_tilt, max_tilt, 3)) * nominal
        out.append(make_T(r.as_matrix(), [0.45, 0.0, 0.45] + rng.uniform(-0.15, 0.15, 3)))
    return out


def perturb(T: np.ndarray, rng: np.random.Generator, rot_deg: float, trans_mm: float) -> np.ndarray:
    if rot_deg == 0 and trans_mm == 0:
        return T.copy()
    dR = Rotation.from_rotvec(rng.normal(0.0, np.deg2rad(rot_deg), 3)).as_matrix()
    return T @ make_T(dR, rng.normal(0.0, trans_mm / 1000.0, 3))


def samples(mount: str, n: int, rng: np.random.Generator, cam_rot_deg: float = 0.0, cam_trans_mm: float = 0.0,
            X: np.ndarray = X_TRUE) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(T_base_flange, T_cam_board) for `mount`, with optional Gaussian noise on the board poses."""
    F = flange_poses(n, rng)
    if mount == "eye_in_hand":  # X = T_flange_cam; board fixed in base
        C = [inv(f @ X) @ T_BASE_BOARD for f in F]
    else:  # X = T_base_cam; board on the flange
        C = [inv(X) @ f @ T_FLANGE_BOARD for f in F]
    return F, [perturb(c, rng, cam_rot_deg, cam_trans_mm) for c in C]
