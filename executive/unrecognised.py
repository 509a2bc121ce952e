"""What is in the sink that no perceived item explains, grouped into things.

When a run ends with items left, the robot names each perceived one with the reasons its attempts failed
(executive/verification.py). Items that were never perceived (buried under others, seen too little for any pose,
or not dishware at all) have no pose to name; they still leave map points that neither the cell nor a perceived
item explains. Those points, as the planner's occupied voxels inside the basin, grouped into connected
components, are what this module reports: one line per thing with where it is and how big, so that "every
object placed or reported" holds for what perception could not recognise too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class Unrecognised:
    """One connected group of unexplained occupied voxels: centre and extent in the base frame (m)."""

    centre: np.ndarray
    extent: np.ndarray
    voxels: int

    def describe(self) -> str:
        x, y, z = self.centre
        return (f"at ({x:.2f}, {y:.2f}, {z:.2f}) m, {100 * self.extent[0]:.0f} x {100 * self.extent[1]:.0f} x "
                f"{100 * self.extent[2]:.0f} cm")


def unrecognised_things(voxels: np.ndarray, voxel_size: float, lo: np.ndarray, hi: np.ndarray,
                        min_voxels: int = 4, min_extent: float = 0.03) -> list[Unrecognised]:
    """Group the centres of unexplained occupied voxels (N, 3) that lie inside the box `lo`..`hi` into things:
    voxels that touch (26-neighbourhood) belong together. Groups of fewer than `min_voxels` or no wider than
    `min_extent` in every direction are dropped: single stray voxels and slivers beside a pose fitted a centimetre
    off are noise, not things. Largest first."""
    V = np.asarray(voxels, float).reshape(-1, 3)
    V = V[np.all((V >= np.asarray(lo) - 1e-9) & (V <= np.asarray(hi) + 1e-9), axis=1)]
    if len(V) == 0:
        return []
    pairs = cKDTree(V).query_pairs(r=voxel_size * 1.75, output_type="ndarray")  # sqrt(3) ~ 1.73: corner neighbours
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(V), len(V)))
    n, label = connected_components(graph, directed=False)
    out = []
    for k in range(n):
        G = V[label == k]
        extent = G.max(axis=0) - G.min(axis=0) + voxel_size
        if len(G) < min_voxels or np.all(extent <= min_extent + 1e-9):
            continue
        out.append(Unrecognised((G.max(axis=0) + G.min(axis=0)) / 2, extent, len(G)))
    return sorted(out, key=lambda t: -t.voxels)
