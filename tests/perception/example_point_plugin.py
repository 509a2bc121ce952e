"""An example point-encoder plug-in (see kitchenbot/perception/plugins.py), used by the tests.

A small deterministic local descriptor: for each point, histograms of the distances to its neighbours within
5 voxels and of how parallel their normals are to its own. Name it in a config as
``point_encoder: example_point_plugin:RadialHistogramEncoder`` (with this folder on the Python path), or
publish it under the entry-point group ``kitchenbot.point_encoders``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


class RadialHistogramEncoder:
    name = "radial-hist"
    dim = 8

    def encode(self, points: np.ndarray, normals: np.ndarray, voxel: float) -> np.ndarray:
        r = 5.0 * voxel
        out = np.zeros((len(points), self.dim))
        for i, nb in enumerate(cKDTree(points).query_ball_point(points, r)):
            d = np.linalg.norm(points[nb] - points[i], axis=1) / r
            c = np.abs(normals[nb] @ normals[i])
            out[i, :4] = np.histogram(d, 4, (0.0, 1.0))[0]
            out[i, 4:] = np.histogram(c, 4, (0.0, 1.0 + 1e-9))[0]
        return out / np.maximum(out[:, :4].sum(axis=1, keepdims=True), 1)


class BrokenEncoder:
    """Keeps the attribute names but returns the wrong shape: loading must refuse it."""

    name = "broken"
    dim = 8

    def encode(self, points, normals, voxel):
        return np.zeros((len(points), 3))
