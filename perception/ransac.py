"""Open3D's RANSACs, run so that the same points give the same answer in any process.

Open3D's RANSACs (0.20: `PointCloud.segment_plane`, `registration_ransac_based_on_feature_matching`) run their
iterations on a thread pool (TBB: OMP_NUM_THREADS does not limit it) whose threads all draw from one global
generator, and stop early at a count that depends on which thread found the best fit first. With the generator
seeded just before the call they still gave a different answer from call to call (the sink floor's plane: 4080 or
4083 inliers of 5353 points, half and half), so segmentation masks, the map and the poses differed between two runs
of the same scene (docs/perception_measurements.md, "Run-to-run determinism"). On one thread the draws and the
early stop come in one order: the same seed, the same answer. They take no more CPU time that way (a plane fit
2.7 ms either way); only their wall time is that of one core.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import open3d as o3d


@contextmanager
def one_thread():
    """Open3D's calls inside run on the calling thread only (a process-wide limit, restored on exit): for those
    whose answer depends on the order in which its threads draw random numbers."""
    before = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(before)


def segment_plane(points: np.ndarray, distance: float, iterations: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Open3D's RANSAC plane (a, b, c, d: a x + b y + c z + d = 0, refitted on its inliers) through `points` (N, 3)
    and the indices of its inliers (within `distance`), drawn from `seed` on one thread."""
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    o3d.utility.random.seed(seed)
    with one_thread():
        plane, inliers = pc.segment_plane(distance_threshold=distance, ransac_n=3, num_iterations=iterations)
    return np.asarray(plane, float), np.asarray(inliers, np.int64)
