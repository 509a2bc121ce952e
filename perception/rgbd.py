"""RGB-D geometry shared by the stages: valid depth, back-projection to the base frame, projection into a view."""

from __future__ import annotations

import numpy as np

from kitchenbot.perception.types import View
from kitchenbot.transforms import inv


def check_view(view: View, where: str = "view") -> None:
    """Raise ValueError naming the field when a View is malformed."""
    if view.rgb.ndim != 3 or view.rgb.shape[2] != 3:
        raise ValueError(f"{where}.rgb: expected (H, W, 3) uint8, got shape {view.rgb.shape}")
    if view.depth.shape != view.rgb.shape[:2]:
        raise ValueError(f"{where}.depth: expected shape {view.rgb.shape[:2]} (same as rgb), got {view.depth.shape}")
    if np.asarray(view.K).shape != (3, 3):
        raise ValueError(f"{where}.K: expected a 3x3 intrinsic matrix, got shape {np.asarray(view.K).shape}")
    if np.asarray(view.T_base_cam).shape != (4, 4) or not np.all(np.isfinite(view.T_base_cam)):
        raise ValueError(f"{where}.T_base_cam: expected a finite 4x4 transform")


def valid_depth(depth: np.ndarray, max_range: float = 5.0) -> np.ndarray:
    """Pixels with a usable depth (finite, > 0, < max_range metres)."""
    d = np.asarray(depth, np.float32)
    with np.errstate(invalid="ignore"):
        return np.isfinite(d) & (d > 1e-4) & (d < max_range)


def backproject_cam(depth: np.ndarray, K: np.ndarray, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points of the valid (and masked) pixels, and their (row, col) indices."""
    ok = valid_depth(depth)
    if mask is not None:
        ok &= mask
    rows, cols = np.nonzero(ok)
    z = depth[rows, cols].astype(np.float64)
    x = (cols - K[0, 2]) * z / K[0, 0]
    y = (rows - K[1, 2]) * z / K[1, 1]
    return np.stack([x, y, z], axis=1), np.stack([rows, cols], axis=1)


def backproject(view: View, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Base-frame points of the valid (and masked) pixels of a view, and their (row, col) indices."""
    p, rc = backproject_cam(view.depth, view.K, mask)
    T = view.T_base_cam
    return p @ T[:3, :3].T + T[:3, 3], rc


def point_map(view: View, stride: int = 1) -> np.ndarray:
    """(ceil(H/s), ceil(W/s), 3) base-frame points of every s-th pixel (rows and columns); NaN where the
    depth is unusable. float32: enough for millimetres, half the memory traffic."""
    d = np.asarray(view.depth, np.float32)[::stride, ::stride]
    rows = np.arange(0, view.depth.shape[0], stride, dtype=np.float32)
    cols = np.arange(0, view.depth.shape[1], stride, dtype=np.float32)
    K = view.K
    ok = valid_depth(d)
    z = np.where(ok, d, np.nan).astype(np.float32)
    x = ((cols[None, :] - K[0, 2]) / K[0, 0]).astype(np.float32) * z
    y = ((rows[:, None] - K[1, 2]) / K[1, 1]).astype(np.float32) * z
    R = view.T_base_cam[:3, :3].astype(np.float32)
    t = view.T_base_cam[:3, 3].astype(np.float32)
    pc = np.stack([x, y, z], axis=-1)
    return pc @ R.T + t


def project(view: View, points_base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (col, row) as floats and camera z of base-frame points in a view."""
    T = inv(view.T_base_cam)
    pc = points_base @ T[:3, :3].T + T[:3, 3]
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = view.K[0, 0] * pc[:, 0] / z + view.K[0, 2]
        v = view.K[1, 1] * pc[:, 1] / z + view.K[1, 2]
    return np.stack([u, v], axis=1), z


def project_pixels(view: View, points_base: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integer (row, col) of points that land inside the image in front of the camera, their z, and which ones."""
    uv, z = project(view, points_base)
    h, w = view.depth.shape
    with np.errstate(invalid="ignore"):
        col = np.floor(uv[:, 0] + 0.5)
        row = np.floor(uv[:, 1] + 0.5)
        inside = (z > 1e-3) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
    rc = np.stack([row[inside], col[inside]], axis=1).astype(np.int64)
    return rc, z[inside], inside
