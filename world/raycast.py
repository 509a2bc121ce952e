"""Pinhole rays for Open3D's RaycastingScene in the OpenCV pixel convention.

Open3D's ``create_rays_pinhole`` casts the ray of pixel (u, v) through (u + 0.5, v + 0.5) (pixel corners at
integers); an OpenCV K puts pixel centres at integers. Every render that must match a reported K (the fake
camera, dataset masks, CAD database views, overlays) goes through here, so the two conventions never mix.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d


def pinhole_rays(K: np.ndarray, T_cam_world: np.ndarray, width: int, height: int) -> o3d.core.Tensor:
    """(H, W, 6) rays [origin, direction] whose t_hit is z-depth, for an OpenCV intrinsic matrix K."""
    K_o3d = np.array(K, dtype=np.float64)
    K_o3d[:2, 2] += 0.5
    return o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        o3d.core.Tensor(K_o3d), o3d.core.Tensor(np.asarray(T_cam_world, np.float64)), int(width), int(height)
    )
