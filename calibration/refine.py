"""Optional refinement of a Park–Martin hand-eye solution by minimising the reprojection error of every
detected board corner in every view, jointly over X and the fixed board pose.

Park–Martin weighs the per-view PnP poses through pairwise motions; the corner pixels are what was actually
measured. With X and the board pose (12 parameters) the whole capture predicts every corner, so a
least-squares fit on the pixels (scipy's ``least_squares`` with a soft-L1 loss against stray corners) uses the
measurements directly. It starts from the Park–Martin answer, which it needs: the problem is non-convex.

Chains: eye in hand ``T_cam_board_i = (F_i X)^-1 T_base_board``; eye to hand
``T_cam_board_i = X^-1 F_i T_flange_board``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from kitchenbot.calibration.park_martin import check_mount
from kitchenbot.transforms import inv, make_T


@dataclass
class Refinement:
    X: np.ndarray
    T_fixed: np.ndarray  # T_base_board (eye in hand) or T_flange_board (eye to hand)
    rms_px_before: float
    rms_px_after: float
    n_points: int


def _pose(p: np.ndarray) -> np.ndarray:
    return make_T(Rotation.from_rotvec(p[:3]).as_matrix(), p[3:])


def _cam_board(X: np.ndarray, T_fixed: np.ndarray, F: np.ndarray, mount: str) -> np.ndarray:
    if mount == "eye_in_hand":
        return inv(F @ X) @ T_fixed
    return inv(X) @ F @ T_fixed


def refine_reprojection(
    X0: np.ndarray,
    T_fixed0: np.ndarray,
    T_base_flange: Sequence[np.ndarray],
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    K: np.ndarray,
    dist: np.ndarray | None = None,
    mount: str = "eye_in_hand",
    f_scale_px: float = 1.0,
) -> Refinement:
    """Refine X and the fixed board pose from per-view corners (object_points (N_i, 3) in the board frame,
    image_points (N_i, 2) px) and the flange poses of the same views."""
    check_mount(mount)
    if not (len(T_base_flange) == len(object_points) == len(image_points)):
        raise ValueError("refine_reprojection: expected one flange pose, object-point and image-point set per view")
    K = np.asarray(K, float)
    dist = np.zeros(5) if dist is None else np.asarray(dist, float)
    obj = [np.asarray(o, float).reshape(-1, 3) for o in object_points]
    img = [np.asarray(i, float).reshape(-1, 2) for i in image_points]
    n_pts = sum(len(o) for o in obj)

    def residuals(p: np.ndarray) -> np.ndarray:
        X = X0 @ _pose(p[:6])
        T_fixed = T_fixed0 @ _pose(p[6:])
        out = []
        for F, o, i in zip(T_base_flange, obj, img):
            T = _cam_board(X, T_fixed, F, mount)
            proj, _ = cv2.projectPoints(o, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K, dist)
            out.append((proj.reshape(-1, 2) - i).ravel())
        return np.concatenate(out)

    r0 = residuals(np.zeros(12))
    sol = least_squares(residuals, np.zeros(12), loss="soft_l1", f_scale=f_scale_px, x_scale="jac", method="trf")
    r1 = residuals(sol.x)
    return Refinement(
        X=X0 @ _pose(sol.x[:6]),
        T_fixed=T_fixed0 @ _pose(sol.x[6:]),
        rms_px_before=float(np.sqrt(np.mean(r0.reshape(-1, 2) ** 2) * 2)),
        rms_px_after=float(np.sqrt(np.mean(r1.reshape(-1, 2) ** 2) * 2)),
        n_points=n_pts,
    )
