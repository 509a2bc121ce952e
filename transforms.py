"""Rigid transforms as 4x4 float64 arrays.

Naming: ``T_a_b`` is the pose of frame b in frame a; it maps b-coordinates into a
(``p_a = T_a_b @ p_b``). Chains read left to right: ``T_base_cam = T_base_flange @ T_flange_cam``.
Rotations go through scipy's ``Rotation``; only the tiny glue that it lacks lives here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation


def make_T(R: np.ndarray | None = None, t: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
    """Build a 4x4 transform from a 3x3 rotation and a translation (metres)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (uses R^T, never a general matrix inverse)."""
    Ti = np.eye(4)
    R = T[:3, :3]
    Ti[:3, :3] = R.T
    Ti[:3, 3] = -R.T @ T[:3, 3]
    return Ti


def from_xyz_rpy(xyz: Sequence[float], rpy: Sequence[float]) -> np.ndarray:
    """Pose from a translation and roll-pitch-yaw (extrinsic x, y, z; radians), as in URDF."""
    return make_T(Rotation.from_euler("xyz", rpy).as_matrix(), xyz)


def to_xyz_rpy(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return T[:3, 3].copy(), Rotation.from_matrix(T[:3, :3]).as_euler("xyz")


def from_rotvec(rotvec: Sequence[float], t: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Pose from an axis-angle vector (radians) and a translation; the UR controller's pose format."""
    return make_T(Rotation.from_rotvec(rotvec).as_matrix(), t)


def to_rotvec(T: np.ndarray) -> np.ndarray:
    """[x, y, z, rx, ry, rz]: the UR controller's pose format."""
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])


# Rotations about one axis written out: scipy's Rotation.from_euler costs ~0.3 ms a call, and the tasks' spot search
# builds thousands of poses per target (a grid over a rack, each spot upside down).
def _axis_rotation(a: float, i: int, j: int) -> np.ndarray:
    """4x4 rotation by `a` (radians) turning axis i towards axis j."""
    c, s = np.cos(a), np.sin(a)
    T = np.eye(4)
    T[i, i], T[i, j], T[j, i], T[j, j] = c, -s, s, c
    return T


def rot_x(a: float) -> np.ndarray:
    return _axis_rotation(a, 1, 2)


def rot_y(a: float) -> np.ndarray:
    return _axis_rotation(a, 2, 0)


def rot_z(a: float) -> np.ndarray:
    return _axis_rotation(a, 0, 1)


def trans(x: float, y: float, z: float) -> np.ndarray:
    return make_T(t=(x, y, z))


def rotation_angle(R: np.ndarray) -> float:
    """Angle (radians) of a rotation matrix, robust near 0 and pi."""
    return float(np.linalg.norm(Rotation.from_matrix(R).as_rotvec()))


def pose_error(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(rotation error in radians, translation error in metres) between two poses."""
    dT = inv(T_a) @ T_b
    return rotation_angle(dT[:3, :3]), float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply T to an (N, 3) array of points."""
    points = np.asarray(points, dtype=np.float64)
    return points @ T[:3, :3].T + T[:3, 3]


def is_rigid(T: np.ndarray, tol: float = 1e-6) -> bool:
    """True when T is a finite 4x4 rigid transform (orthonormal, det +1, last row 0 0 0 1)."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return False
    R = T[:3, :3]
    return (
        np.allclose(R.T @ R, np.eye(3), atol=tol)
        and abs(np.linalg.det(R) - 1.0) < tol
        and np.allclose(T[3], [0, 0, 0, 1], atol=tol)
    )


def check_rigid(T: np.ndarray, name: str) -> np.ndarray:
    """Return T as float64 or raise ValueError naming `name` and what was expected."""
    arr = np.asarray(T, dtype=np.float64)
    if arr.shape != (4, 4):
        raise ValueError(f"{name}: expected a 4x4 rigid transform, got shape {arr.shape}")
    if not is_rigid(arr, tol=1e-4):
        raise ValueError(f"{name}: expected a rigid transform (orthonormal rotation, last row 0 0 0 1)")
    return arr
