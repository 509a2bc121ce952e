"""RANSAC plane fit that gives the same answer for the same points in any process.

Open3D's `PointCloud.segment_plane` (0.20) runs its iterations on a thread pool (TBB: OMP_NUM_THREADS does not
limit it) that all draw from one global generator, and stops early at a count that depends on which thread found
the best plane first: `o3d.utility.random.seed` set just before the call still gave a different plane from call
to call (the sink floor's inliers 4080 or 4083 of 5353 points, half and half), so segmentation masks, the map
and the poses differed between two runs of the same scene (docs/perception.md, "Run-to-run determinism"). Here
the samples come from a local generator and the iterations are evaluated in a fixed order.
"""

from __future__ import annotations

import numpy as np

# Iterations evaluated together (one matrix product); the early stop is checked between blocks, so where it
# stops depends only on the points and the seed.
BLOCK = 32


def segment_plane(points: np.ndarray, distance: float, iterations: int, seed: int = 0,
                  probability: float = 0.99999999) -> tuple[np.ndarray, np.ndarray]:
    """The plane (a, b, c, d), unit normal, a x + b y + c z + d = 0, of most inliers among `iterations` planes
    through 3 random points (ties: the smaller summed distance of the inliers / sqrt(count), as Open3D), refitted
    by least squares on its inliers; and the indices of the points within `distance` of the best sampled plane.
    Stops early, as Open3D does, once `probability` says a better plane is unlikely. Zeros and no inliers for
    fewer than 3 points."""
    P = np.asarray(points, np.float64)
    n = len(P)
    if n < 3:
        return np.zeros(4), np.zeros(0, np.int64)
    rng = np.random.default_rng(seed)
    best = (-1, np.inf, None)  # (inlier count, rmse, plane)
    needed = iterations
    done = 0
    while done < min(iterations, needed):
        k = min(BLOCK, iterations - done)
        idx = rng.integers(0, n, (k, 3))
        a, b, c = P[idx[:, 0]], P[idx[:, 1]], P[idx[:, 2]]
        nrm = np.cross(b - a, c - a)
        length = np.linalg.norm(nrm, axis=1)
        ok = length > 0  # three distinct, non-collinear points
        nrm = nrm[ok] / length[ok, None]
        d = -np.einsum("ij,ij->i", nrm, a[ok])
        done += k
        if len(nrm) == 0:
            continue
        dist = np.abs(P @ nrm.T + d)  # (n, planes)
        inl = dist < distance
        count = inl.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            rmse = np.where(inl, dist, 0.0).sum(axis=0) / np.sqrt(count)
        j = np.lexsort((rmse, -count))[0]  # most inliers, then the smaller error; first on an exact tie
        if count[j] > best[0] or (count[j] == best[0] and rmse[j] < best[1]):
            best = (int(count[j]), float(rmse[j]), np.append(nrm[j], d[j]))
            f = best[0] / n
            needed = 0 if f >= 1.0 else int(np.ceil(min(np.log(1 - probability) / np.log(1 - f**3), iterations)))
    if best[2] is None:
        return np.zeros(4), np.zeros(0, np.int64)
    plane = best[2]
    inliers = np.nonzero(np.abs(P @ plane[:3] + plane[3]) < distance)[0]
    return refit(P[inliers], plane), inliers


def refit(points: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """The least-squares plane through `points` (the covariance's least axis through their centroid), its normal
    on the side of `plane`'s; `plane` itself for fewer than 3 points."""
    if len(points) < 3:
        return plane
    c = points.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((points - c).T))
    nrm = vecs[:, 0]
    if nrm @ plane[:3] < 0:
        nrm = -nrm
    return np.append(nrm, -nrm @ c)
