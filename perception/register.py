"""Candidate proposal and object registration (paper III-C "Object candidate proposal" / "Object registration").

Candidates: cosine similarity of the query's class tokens (image class token, mean point feature) against
each model's rendered views, aggregated per model (max over views); the top-K over a threshold survive.

Registration per candidate, multi-hypothesis:
  1. correspondence-based coarse alignment in fused-feature space (Open3D RANSAC on feature matches with
     the edge-length 0.9 and distance checkers);
  2. gravity priors: dishware rests on surfaces, so its symmetry axis is up, down, or along one of the
     query's principal axes (leaning / on its side); for models without a continuous symmetry, yaws around
     that axis are enumerated too;
  3. every hypothesis is refined by coarse-to-fine point-to-plane ICP and scored;
  4. the best hypothesis is refined once more with fine ICP.
Score: the paper's bidirectional overlap ratios with epsilon = voxel size, where the model->query ratio is
taken over the model points the cameras could see (facing a camera and not behind the observed depth),
and model points seen to be in free space (in front of the observed depth) count against it.
Candidates scoring below ``min_overlap`` are rejected: unknown objects are never forced into a class.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from kitchenbot.perception.database import NORMAL_WEIGHT, CadDatabase, ModelEntry
from kitchenbot.perception.features import FusedCloud
from kitchenbot.perception.ransac import one_thread
from kitchenbot.perception.rgbd import project_pixels
from kitchenbot.perception.types import View
from kitchenbot.transforms import inv, make_T
from kitchenbot.world.inventory import ObjectModel

reg = o3d.pipelines.registration


@dataclass
class Hypothesis:
    obj_id: int
    T_base_obj: np.ndarray
    score: float = 0.0
    or_query: float = 0.0  # fraction of query points within eps of the model
    or_model: float = 0.0  # fraction of the visible model points confirmed by the depth
    free_space: float = 0.0  # fraction of the visible model points seen to be empty space
    visible_fraction: float = 0.0
    source: str = ""
    verification: "object | None" = None  # perception/verify.Verification of the final pose


@dataclass
class RegistrationConfig:
    voxel: float = 0.01
    top_k: int = 3
    candidate_threshold: float = 0.3
    min_overlap: float = 0.5
    ransac_iterations: int = 1000
    ransac_runs: int = 1
    n_yaw: int = 8  # yaw hypotheses for models without a continuous symmetry
    keep_for_refine: int = 2
    seed: int = 0


def propose(query: FusedCloud, db: CadDatabase, top_k: int, threshold: float) -> list[tuple[int, float, float]]:
    """Top-K (obj_id, similarity, image similarity) over the threshold, best first. Similarity: cosine of the
    class tokens [image class token || mean point feature] against each rendered view, max over views;
    the image part alone is returned too (NaN without an image encoder)."""
    out = []
    for oid, e in db.entries.items():
        geo = e.view_geo @ query.geo_token if len(e.view_geo) else np.zeros(1)
        if query.cls_token.size and e.view_cls.size:
            img = e.view_cls @ query.cls_token
            sim, img_sim = 0.5 * img + 0.5 * geo, float(np.max(img))
        else:
            sim, img_sim = geo, float("nan")
        out.append((oid, float(np.max(sim)), img_sim))
    out.sort(key=lambda t: -t[1])
    return [c for c in out if c[1] >= threshold][:top_k]


def _pcd(points: np.ndarray, normals: np.ndarray) -> o3d.geometry.PointCloud:
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc.normals = o3d.utility.Vector3dVector(normals)
    return pc


def feature_matches(fq: np.ndarray, entry: ModelEntry) -> np.ndarray:
    """(N, 2) int32 pairs (query point i, the model reference point nearest it in fused-feature space): the
    correspondences Open3D's `registration_ransac_based_on_feature_matching` (mutual filter off) would draw from.

    Written out because Open3D builds a KD-tree over the model's features on every call and searches it point by
    point; in ~50 dimensions that was ~3/4 of the RANSAC's time. Here all squared distances at once with scipy's
    `cdist` (summed directly, like Open3D's; single-threaded C: a BLAS product would wake BLAS's threads, whose
    spinning cost more process CPU time than the product saved), the first minimum per row."""
    d2 = cdist(np.asarray(fq, np.float64), entry.fused_features, "sqeuclidean")
    return np.column_stack([np.arange(len(d2)), np.argmin(d2, axis=1)]).astype(np.int32)


def _rot_from_z(axis: np.ndarray) -> np.ndarray:
    """A rotation taking the object z axis onto `axis`."""
    a = axis / np.linalg.norm(axis)
    # ref x a and a x x written out (np.cross costs ~20 us per call on 3-vectors; this runs per hypothesis)
    x = np.array([0.0, -a[2], a[1]]) if abs(a[0]) < 0.9 else np.array([a[2], 0.0, -a[0]])
    x /= np.linalg.norm(x)
    y = np.array([a[1] * x[2] - a[2] * x[1], a[2] * x[0] - a[0] * x[2], a[0] * x[1] - a[1] * x[0]])
    return np.stack([x, y, a], axis=1)


def clean_depths(views: list[View]) -> list[np.ndarray]:
    """Depth images with unknown depth as 0 (computed once per scan, shared by the scorers)."""
    out = []
    for v in views:
        d = np.asarray(v.depth, np.float32)
        out.append(np.where(np.isfinite(d), d, 0.0).astype(np.float32))
    return out


# Metres: model surface this far behind the depth the camera saw (more than its noise) and near points another pose
# explains is hidden under that item (Scorer `covered`).
HIDDEN_DEPTH = 0.002


class Scorer:
    """Overlap ratios of a posed model against the query points and the views' depth."""

    def __init__(self, entry: ModelEntry, query_points: np.ndarray, views: list[View], eps: float, n_model: int = 800,
                 inside_solid: Callable[[np.ndarray], np.ndarray] | None = None,
                 depths: list[np.ndarray] | None = None, covered: np.ndarray | None = None,
                 context: np.ndarray | None = None):
        """`inside_solid(P)`: which base-frame points lie inside known solid matter (the cell's counter and sink
        walls, or below the support plane); a pose that puts the model there is penalised. `covered`: points
        another pose already explains (the item stacked on this one): model surface the depth confirms near them
        but not near the query, and behind the seen surface (HIDDEN_DEPTH), is hidden under that item (a plate's
        top 6 mm under the plate on it lies within the depth tolerance of the upper one's surface), neither for
        nor against the pose. (Surface in front of the seen one still counts against it: with it, a fit of a
        nested bowl leaning 10 deg more than the bowl poked out of the bowl in it for free and won.)
        `context`: points of the segment the query was cut from (the other regions of a blob cut into item-sized
        regions): model surface the depth confirms near them counts as confirmed (`or_model`) as near the query's
        own points, while `or_query` stays the share of the query's points the pose explains. An item longer than
        a region (a 12 cm glass leaning in a pile) has most of its seen surface in the neighbouring regions; judged
        on its region alone, the right fit confirmed a fifth of its visible surface and no fit of any region
        passed."""
        self.inside_solid = inside_solid
        self.covered_tree = cKDTree(covered) if covered is not None and len(covered) else None
        step = max(1, len(entry.dense_points) // n_model)
        self.mp = entry.dense_points[::step].astype(np.float64)
        self.mn = entry.dense_normals[::step].astype(np.float64)
        self.model_tree = entry.tree
        self.q = query_points
        self.q_tree = cKDTree(query_points if context is None or not len(context)
                              else np.concatenate([query_points, context]))
        self.views = views
        self.depths = depths if depths is not None else clean_depths(views)
        self.eps = eps
        self._scores: dict[tuple[bytes, bool], tuple[float, ...]] = {}  # `__call__`'s answers by pose

    def __call__(self, T_base_obj: np.ndarray, coarse: bool = False) -> tuple[float, float, float, float, float]:
        """(score, or_query, or_model, free_space, visible_fraction); `coarse` uses a third of the points.
        Remembered per pose: the estimate asks again for the score of the pose it holds (the colour weight of
        each refinement it tries from there: flipped, turned, held upright)."""
        T = np.ascontiguousarray(T_base_obj, dtype=np.float64)
        key = (T.tobytes(), bool(coarse))
        if key not in self._scores:
            self._scores[key] = tuple(float(x[0]) for x in self.batch(T[None], coarse))
        return self._scores[key]

    def batch(self, T_base_obj: np.ndarray, coarse: bool = False) -> tuple[np.ndarray, ...]:
        """`__call__` for H poses at once ((H, 4, 4) -> five (H,) arrays): every point of every pose goes
        through one KD-tree query and one projection per view (per-pose calls were dominated by numpy's
        per-call overhead: ~270 points each, dozens of small array operations)."""
        T = np.asarray(T_base_obj, float)
        H = len(T)
        k = 3 if coarse else 1
        R, t = T[:, :3, :3], T[:, :3, 3]
        q = self.q[::k]
        nq = len(q)
        # query points into each pose's object frame: R^T (q - t)
        q_obj = (q[None] - t[:, None]) @ R  # (batched matmul; einsum is slow here)
        if nq:
            d, _ = self.model_tree.query(q_obj.reshape(-1, 3), distance_upper_bound=self.eps)
            or_q = np.isfinite(d).reshape(H, nq).mean(axis=1)
        else:
            or_q = np.zeros(H)
        mp, mn = self.mp[::k], self.mn[::k]
        n = len(mp)
        Rt = R.transpose(0, 2, 1)
        P = (mp @ Rt + t[:, None]).reshape(-1, 3)
        N = (mn @ Rt).reshape(-1, 3)
        support = np.zeros(len(P), bool)
        violate = np.zeros(len(P), bool)
        in_view = np.zeros(len(P), bool)
        behind = np.zeros(len(P), bool)  # confirmed, but behind what the camera saw (under a thin item on it)
        tol = max(self.eps, 0.006)
        for v, D in zip(self.views, self.depths):
            # Facing the camera clearly (< ~70 deg): grazing points sit on silhouettes, where depth is least sure.
            ray = v.T_base_cam[:3, 3] - P
            facing = np.einsum("ij,ij->i", N, ray) > 0.35 * np.linalg.norm(ray, axis=1)
            rc, z, inside = project_pixels(v, P)
            obs = D[rc[:, 0], rc[:, 1]]
            idx = np.nonzero(inside)[0]
            in_view[idx] = True
            known = (obs > 0) & facing[idx]
            support[idx[known & (np.abs(z - obs) <= tol)]] = True
            if self.covered_tree is not None:
                behind[idx[known & (z - obs > HIDDEN_DEPTH) & (z - obs <= tol)]] = True
            violate[idx[known & (z < obs - 2 * tol)]] = True  # clearly in front of what the camera saw
        violate &= ~support
        n_sup = support.reshape(H, n).sum(axis=1)
        n_vio = violate.reshape(H, n).sum(axis=1)
        n_vis = n_sup + n_vio
        # Model points confirmed by the depth must also be near the query (not just any surface).
        sup_idx = np.nonzero(support)[0]
        near = np.zeros(H)
        if len(sup_idx):
            dq, _ = self.q_tree.query(P[sup_idx], distance_upper_bound=2 * self.eps)
            near = np.bincount(sup_idx[np.isfinite(dq)] // n, minlength=H).astype(float)
            if self.covered_tree is not None:
                far = sup_idx[~np.isfinite(dq) & behind[sup_idx]]
                dc, _ = self.covered_tree.query(P[far], distance_upper_bound=tol)
                n_vis = n_vis - np.bincount(far[np.isfinite(dc)] // n, minlength=H)
        has = n_vis > 0
        den = np.maximum(n_vis, 1)
        or_m = np.where(has, near / den, 0.0)
        fs = np.where(has, n_vio / den, 0.0)
        score = 0.5 * (or_q + or_m)
        # A pose mostly outside every image is weakly supported (its unseen part could be anywhere).
        score *= np.minimum(1.0, in_view.reshape(H, n).mean(axis=1) / 0.7)
        if self.inside_solid is not None:
            score -= 2.0 * self.inside_solid(P).reshape(H, n).mean(axis=1)
        score = np.where(has, np.maximum(score, 0.0), 0.0)
        vis = np.where(has, near / max(n, 1), 0.0)
        return score, or_q, or_m, fs, vis


def _exp_se3_small(x: np.ndarray) -> np.ndarray:
    """4x4 transform of a rotation vector x[:3] (Rodrigues) and a translation x[3:]."""
    w = x[:3]
    th = np.linalg.norm(w)
    Kx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if th < 1e-9:
        R = _EYE3 + Kx
    else:
        R = _EYE3 + np.sin(th) / th * Kx + (1 - np.cos(th)) / th**2 * (Kx @ Kx)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = x[3:]
    return T


_EYE3 = np.eye(3)


def _converged(x: np.ndarray, dmax: float) -> np.ndarray:
    """Whether ICP steps x (rotation vector, translation; (6,) or (H, 6)) are small enough to stop the level:
    under 1e-4 rad and 0.01 mm. (A test relative to the level's distance, 1 %, saved ~15 % of the refinement's
    iterations; with it, held-out scenes with distractors had 12 more false positives in 24 images: fits in
    piles follow any change in the ICP.)"""
    return (np.einsum("...i,...i->...", x[..., :3], x[..., :3]) < 1e-8) & \
        (np.einsum("...i,...i->...", x[..., 3:], x[..., 3:]) < 1e-10)


def icp_to_model(q: np.ndarray, entry: ModelEntry, T_obj_base: np.ndarray, dists: tuple[float, ...],
                 iters: int = 10, coarse: bool = False, upright: bool = False,
                 qn: np.ndarray | None = None, symmetric: bool = False) -> np.ndarray:
    """Point-to-plane ICP of query points (base frame) onto the model surface; returns T_obj_base.

    Hand-written (numpy + the model's prebuilt KD-tree) because Open3D's registration_icp rebuilds the target
    KD-tree on every call, and one object needs dozens of ICP runs against the same model: this is ~10x
    faster at these sizes. Gauss-Newton on the linearised point-to-plane residual; correspondences farther
    than the current distance are dropped. `upright`: only translation and the rotation about the object's
    z axis are free (the axis stays where it is: gravity-aligned hypotheses stay gravity-aligned).
    `qn`: the query points' normals (facing the cameras, base frame); with the dense model, each point is
    then matched to a near model point on a surface facing the same way. Without them a thin wall's two
    sides (a plate's top and underside, 4.5 mm apart) are equally good matches, and fits settled on the
    wrong side: plates sat one wall thickness high, stacked ones more.
    `symmetric`: the model is a surface of revolution about its z axis; the turn about it is left out (the
    data cannot fix it: it drifted by degrees per iteration and the ICP never met its convergence test).
    The loop keeps numpy calls per iteration few (it runs ~30 times per refinement on a few hundred points,
    where per-call overhead, not arithmetic, was the cost).
    """
    free = np.array([2, 3, 4, 5]) if upright else np.arange(6)
    if symmetric:
        free = free[free != 2]
    damp = 1e-6 * np.eye(len(free))
    T = np.array(T_obj_base, float)
    if coarse:  # voxel-level model points: a smaller tree, good enough to screen hypotheses
        tree, mp, mn = entry.ref_tree, entry.ref.points, entry.ref.normals
        qn = None  # the voxel-level model merges a thin wall's two sides into one point: no side to choose
    else:
        tree, mp, mn = entry.tree, entry.dense_points, entry.dense_normals
    mp, mn = np.asarray(mp, np.float64), np.asarray(mn, np.float64)
    J = np.empty((len(q), 6))
    X = np.empty((len(q), 6)) if qn is not None else None
    for dmax in dists:
        dmax2 = dmax * dmax
        for _ in range(iters):
            R, t = T[:3, :3], T[:3, 3]
            p = q @ R.T + t
            if qn is None:
                d, j = tree.query(p, distance_upper_bound=dmax)
                ok = d < np.inf
            else:
                pn = qn @ R.T
                X[:, :3] = p
                np.multiply(pn, NORMAL_WEIGHT, out=X[:, 3:])
                # (a match facing within 60 deg is at most sqrt(dmax^2 + NORMAL_WEIGHT^2) away in the 6-D tree)
                d6, j = entry.oriented_tree.query(X, distance_upper_bound=math.hypot(dmax, NORMAL_WEIGHT))
                np.minimum(j, len(mp) - 1, out=j)
                # Near in space and facing within ~60 deg of the query normal (normals of 1 cm voxel centres
                # on a rim or a tight curve are rough). The matches' points and normals gathered once.
                mj, nj = mp[j], mn[j]
                diff = p - mj
                ok = (d6 < np.inf) & (np.einsum("ij,ij->i", diff, diff) <= dmax2) & \
                    (np.einsum("ij,ij->i", pn, nj) > 0.5)
            k = int(np.count_nonzero(ok))
            if k < 6:
                break
            if qn is None:
                jo = j[ok]
                p, m, n = p[ok], mp[jo], mn[jo]
            else:
                p, m, n = p[ok], mj[ok], nj[ok]
            r = np.einsum("ij,ij->i", p - m, n)
            Jk = J[:k]
            Jk[:, 0] = p[:, 1] * n[:, 2] - p[:, 2] * n[:, 1]  # p x n, written out (np.cross is slow on small arrays)
            Jk[:, 1] = p[:, 2] * n[:, 0] - p[:, 0] * n[:, 2]
            Jk[:, 2] = p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0]
            Jk[:, 3:] = n
            Jf = Jk[:, free]
            x = np.zeros(6)
            x[free] = -np.linalg.solve(Jf.T @ Jf + damp, Jf.T @ r)
            T = _exp_se3_small(x) @ T
            if x[0] * x[0] + x[1] * x[1] + x[2] * x[2] < 1e-8 and x[3] * x[3] + x[4] * x[4] + x[5] * x[5] < 1e-10:
                break  # _converged, on scalars
    return T


def _exp_se3_batch(x: np.ndarray) -> np.ndarray:
    """(H, 4, 4) transforms of rotation vectors x[:, :3] (Rodrigues) and translations x[:, 3:]."""
    w = x[:, :3]
    th = np.linalg.norm(w, axis=1)
    Kx = np.zeros((len(x), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    Kx[:, 1, 0], Kx[:, 2, 0], Kx[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    safe = np.maximum(th, 1e-9)
    a = np.where(th > 1e-9, np.sin(th) / safe, 1.0)
    b = np.where(th > 1e-9, (1 - np.cos(th)) / safe**2, 0.5)
    T = np.tile(np.eye(4), (len(x), 1, 1))
    T[:, :3, :3] += a[:, None, None] * Kx + b[:, None, None] * (Kx @ Kx)
    T[:, :3, 3] = x[:, 3:]
    return T


def icp_batch(q: np.ndarray, entry: ModelEntry, T_obj_base: np.ndarray, dists: tuple[float, ...], iters: int = 5,
              coarse: bool = True, keep_axis: np.ndarray | None = None, symmetric: bool = False) -> np.ndarray:
    """`icp_to_model` for H starting poses at once ((H, 4, 4) T_obj_base -> (H, 4, 4)): one KD-tree query and
    one batched 6x6 solve per iteration for all hypotheses (the per-call Python overhead dominated).
    `keep_axis[h]`: hypothesis h keeps its object z axis (translation and yaw only)."""
    T = np.array(T_obj_base, float)
    H, n = len(T), len(q)
    if H == 0:
        return T
    tree, mp, mn = (entry.ref_tree, entry.ref.points, entry.ref.normals) if coarse else \
        (entry.tree, entry.dense_points, entry.dense_normals)
    mp, mn = np.asarray(mp, np.float64), np.asarray(mn, np.float64)
    lock = np.zeros(H, bool) if keep_axis is None else np.asarray(keep_axis, bool)
    eye6 = 1e-6 * np.eye(6)
    for dmax in dists:
        active = np.ones(H, bool)
        for _ in range(iters):
            idx = np.nonzero(active)[0]
            if len(idx) == 0:
                break
            Ta = T[idx]
            p = q @ Ta[:, :3, :3].transpose(0, 2, 1) + Ta[:, None, :3, 3]  # (batched matmul: einsum is slow here)
            d, j = tree.query(p.reshape(-1, 3), distance_upper_bound=dmax)
            ok = np.isfinite(d).reshape(len(idx), n)
            jj = np.where(ok, j.reshape(len(idx), n), 0)
            m, nn = mp[jj], mn[jj]
            r = np.einsum("hni,hni->hn", p - m, nn) * ok
            J = np.empty(p.shape[:2] + (6,))
            # p x n written out (np.cross's checks and copies cost more than the products here)
            J[..., 0] = p[..., 1] * nn[..., 2] - p[..., 2] * nn[..., 1]
            J[..., 1] = p[..., 2] * nn[..., 0] - p[..., 0] * nn[..., 2]
            J[..., 2] = p[..., 0] * nn[..., 1] - p[..., 1] * nn[..., 0]
            J[..., 3:] = nn
            J *= ok[..., None]
            A = J.transpose(0, 2, 1) @ J + eye6
            bvec = (J.transpose(0, 2, 1) @ r[..., None])[..., 0]
            lk = lock[idx]
            for c in (0, 1):  # locked axis: no rotation about the object's x and y
                A[lk, c, :] = 0.0
                A[lk, :, c] = 0.0
                A[lk, c, c] = 1.0
                bvec[lk, c] = 0.0
            if symmetric:  # no turn about the axis of a surface of revolution (undetermined)
                A[:, 2, :] = 0.0
                A[:, :, 2] = 0.0
                A[:, 2, 2] = 1.0
                bvec[:, 2] = 0.0
            x = -np.linalg.solve(A, bvec[..., None])[..., 0]
            x[ok.sum(axis=1) < 6] = 0.0
            T[idx] = _exp_se3_batch(x) @ Ta
            active[idx[_converged(x, dmax)]] = False
    return T


def seeds(points: np.ndarray, diameter: float, max_seeds: int = 6) -> list[np.ndarray]:
    """Where to centre hypotheses: the query's centroid, and when the query is larger than the model (touching
    items segmented together), farthest-point samples about half a diameter apart, each moved to the centroid
    of the points around it."""
    c = points.mean(axis=0)
    out = [c]
    if len(points) < 10 or np.ptp(points, axis=0).max() < 0.9 * diameter:
        return out
    r = 0.5 * diameter
    d = np.linalg.norm(points - c, axis=1)
    picked = [int(np.argmin(d))]
    dmin = np.linalg.norm(points - points[picked[0]], axis=1)
    while len(out) < max_seeds:
        k = int(np.argmax(dmin))
        if dmin[k] < r:
            break
        picked.append(k)
        dmin = np.minimum(dmin, np.linalg.norm(points - points[k], axis=1))
        local = points[np.linalg.norm(points - points[k], axis=1) < r]
        out.append(local.mean(axis=0))
    return out


def gravity_axes(points: np.ndarray, up: np.ndarray) -> list[np.ndarray]:
    """Candidate directions of the object's z axis: up, down, and the points' most and least extended
    principal axes (an item leaning or on its side), both ways."""
    axes = [up, -up]
    if len(points) >= 5:
        c = points.mean(axis=0)
        _, vecs = np.linalg.eigh(np.cov((points - c).T))
        for k in (0, 2):
            a = vecs[:, k]
            if abs(a @ up) < 0.95:  # not already covered by up/down
                axes += [a, -a]
    return axes


def _pose(axis: np.ndarray, yaw: float, centre: np.ndarray) -> np.ndarray:
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
    return make_T(_rot_from_z(axis) @ Rz, centre)


def same_starts(starts: list[tuple[np.ndarray, bool]]) -> tuple[list[int], list[int]]:
    """Screening starts (T_base_obj, keep axis) told apart exactly: the index of each distinct start's first
    occurrence, and for every start the position of its own in that list."""
    first: list[int] = []
    where: list[int] = []
    at: dict[tuple[bytes, bool], int] = {}
    for i, (T, keep) in enumerate(starts):
        key = (np.ascontiguousarray(T, dtype=np.float64).tobytes(), bool(keep))
        if key not in at:
            at[key] = len(first)
            first.append(i)
        where.append(at[key])
    return first, where


def screen_candidate(query: FusedCloud, entry: ModelEntry, model: ObjectModel, scorer: Scorer,
                     cfg: RegistrationConfig, up: np.ndarray | None = None,
                     stacked_on: list[np.ndarray] = (), bar: float = -math.inf) -> list[tuple[float, str, np.ndarray]]:
    """Hypotheses for one candidate model, each after a quick ICP, with a quick score; best first.
    `stacked_on`: poses of the same model found nearby; nested/stacked copies along their axis are tried.
    `bar`: a quick score this model must reach to stay in the running (another model's lead); when no hypothesis
    of the first round reaches it, the yaw round is skipped (it turns the same hypotheses about their axes)."""
    v = cfg.voxel
    up = np.array([0.0, 0.0, 1.0]) if up is None else up
    qs = query.points[:: max(1, len(query.points) // 150)]  # screening runs on <= ~150 points
    scored: list[tuple[float, str, np.ndarray]] = []
    starts: list[tuple[str, np.ndarray, bool]] = []  # (name, T_base_obj, keep axis)

    def screen_all() -> None:
        # Coarse ICP (all starts at once) estimates T_obj_base (query points -> model frame); then each is scored.
        if not starts:
            return
        # A start given twice (the same pose and axis lock: a yaw turn of a hypothesis that is also the best
        # tilted one, the same stacking shift of two poses found) is fitted and scored once: each hypothesis's
        # ICP and score depend on its own start only (`same_starts`).
        first, where = same_starts([(T, k) for _, T, k in starts])
        T0 = np.array([inv(starts[i][1]) for i in first])
        Ts = icp_batch(qs, entry, T0, (4 * v, 1.5 * v), iters=5, coarse=True,
                       keep_axis=np.array([starts[i][2] for i in first]), symmetric=model.is_rotationally_symmetric)
        Tbs = np.array([inv(T_ob) for T_ob in Ts])
        scores = scorer.batch(Tbs, coarse=True)[0]
        for (name, _, _), u in zip(starts, where):
            scored.append((float(scores[u]), name, Tbs[u].copy()))
        starts.clear()

    # (0) stacking: the same model nested in / stacked on one already found, shifted along its axis (by its
    # nest pitch, where a copy really rests, and by fractions of its height for copies that settled askew).
    height = float(model.extents[2])
    shifts = [f * height for f in (-0.8, -0.5, -0.25, 0.25, 0.5, 0.8)]
    if model.nest_pitch > 0:
        shifts += [-model.nest_pitch, model.nest_pitch]
    for T in stacked_on:
        for dz in shifts:
            Ts = T.copy()
            Ts[:3, 3] += dz * T[:3, 2]
            starts.append(("stack", Ts, True))

    # (1) fused-feature RANSAC: query -> model frame.
    if len(query.points) >= 6 and cfg.ransac_runs > 0:
        src = _pcd(query.points, query.normals)
        dst = _pcd(entry.ref.points, entry.ref.normals)
        corres = o3d.utility.Vector2iVector(feature_matches(query.fused, entry))
        for run in range(cfg.ransac_runs):
            # Seeded per call, and on one thread: Open3D's threads draw from one global generator in a
            # timing-dependent order (perception/ransac.py), which gave different poses run to run.
            o3d.utility.random.seed(cfg.seed + run)
            with one_thread():
                res = reg.registration_ransac_based_on_correspondence(
                    src, dst, corres, 1.5 * v, reg.TransformationEstimationPointToPoint(False), 3,
                    [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                     reg.CorrespondenceCheckerBasedOnDistance(1.5 * v)],
                    reg.RANSACConvergenceCriteria(cfg.ransac_iterations, 0.999))
            if res.fitness > 0:
                starts.append(("ransac", inv(res.transformation), False))
    # (2) gravity priors: axis hypotheses (yaw 0) at each seed, then yaws around the best axes when yaw matters.
    r = 0.5 * model.diameter
    for k, c in enumerate(seeds(query.points, model.diameter)):
        local = query.points if k == 0 else query.points[np.linalg.norm(query.points - c, axis=1) < r]
        for a in gravity_axes(local, up):
            starts.append(("gravity", _pose(a, 0.0, c), False))
    screen_all()
    if not model.is_rotationally_symmetric and cfg.n_yaw > 1 and max((t[0] for t in scored), default=0.0) >= bar:
        # Yaw matters (a mug's handle): every yaw upright and upside down at the centroid, and around the
        # best-scoring other axis.
        c0 = query.points.mean(axis=0)
        grav = [(0.0, "", _pose(up, 0.0, c0)), (0.0, "", _pose(-up, 0.0, c0))]
        grav += sorted([t for t in scored if t[1] == "gravity" and abs(t[2][:3, 2] @ up) < 0.9],
                       key=lambda t: -t[0])[:1]
        # ... and around the best two hypotheses so far, where they are: in a blob of touching items the
        # centroid lies between them, and a mug fitted there first had its handle on the neighbour's side.
        grav += sorted(scored, key=lambda t: -t[0])[:2]
        for _, _, Tb in grav:
            for y in np.linspace(0, 2 * np.pi, cfg.n_yaw, endpoint=False)[1:]:
                starts.append(("gravity-yaw", make_T(Tb[:3, :3] @ _pose(np.array([0, 0, 1.0]), y, np.zeros(3))[:3, :3],
                                                     Tb[:3, 3]), False))
        screen_all()
    scored.sort(key=lambda t: -t[0])
    return scored


def refine(query: FusedCloud, entry: ModelEntry, scorer: Scorer, T_base_obj: np.ndarray, cfg: RegistrationConfig,
           source: str = "", upright: bool = False, symmetric: bool = False, local: bool = False) -> Hypothesis:
    """Fine ICP against the dense model surface (<= ~600 query points) and the full score. `local`: a few
    iterations at the finer levels only, from a pose already within about a voxel (a tracked prior)."""
    v = cfg.voxel
    step = max(1, len(query.points) // 600)
    q, qn = query.points[::step], query.normals[::step]
    if local:
        dists, iters = (1.5 * v, 0.6 * v, 0.3 * v), 4
    else:
        dists, iters = ((3 * v, 1.5 * v, v, 0.6 * v, 0.3 * v) if upright else (2 * v, v, 0.6 * v, 0.3 * v)), 10
    Tb = inv(icp_to_model(q, entry, inv(T_base_obj), dists, iters=iters, upright=upright, qn=qn, symmetric=symmetric))
    return Hypothesis(entry.obj_id, Tb, *scorer(Tb), source=source + ("-upright" if upright else ""))


def on_surface(points: np.ndarray, normals: np.ndarray | None, entry: ModelEntry, T_base_obj: np.ndarray,
               tol: float) -> np.ndarray:
    """Which points (base frame) lie within `tol` of the posed model's surface; with `normals` (facing the
    cameras), on a side facing the same way (within ~60 deg): a point on the rim of a plate nested just under
    this one is near this plate's underside, but faces the other way."""
    if len(points) == 0:
        return np.zeros(0, bool)
    # Only points within the model's reach of its origin can be on it (the duplicate and verification checks
    # ask about whole segments against every pose nearby; most points are beyond the reach).
    d2 = ((points - T_base_obj[:3, 3]) ** 2).sum(axis=1)
    out = np.zeros(len(points), bool)
    cand = np.nonzero(d2 <= (entry.reach + tol) ** 2)[0]
    if len(cand) == 0:
        return out
    Ti = inv(T_base_obj)
    p = points[cand] @ Ti[:3, :3].T + Ti[:3, 3]
    if normals is None:
        d, _ = entry.tree.query(p, distance_upper_bound=tol)
        out[cand] = np.isfinite(d)
        return out
    pn = normals[cand] @ Ti[:3, :3].T
    d6, j = entry.oriented_tree.query(np.hstack([p, NORMAL_WEIGHT * pn]), distance_upper_bound=np.hypot(tol, NORMAL_WEIGHT))
    j = np.minimum(j, len(entry.dense_points) - 1)
    out[cand] = np.isfinite(d6) & (np.linalg.norm(p - entry.dense_points[j], axis=1) <= tol) & \
        (np.einsum("ij,ij->i", pn, entry.dense_normals[j]) > 0.5)
    return out


def surface_fit(points: np.ndarray, normals: np.ndarray, entry: ModelEntry, T_base_obj: np.ndarray,
                tol: float) -> float:
    """Fraction of the query points (normals facing the cameras) on the posed model's surface within `tol`, on
    a side facing the same way. Finer than the overlap score (whose epsilon is a voxel): it tells two fits a
    few millimetres or degrees apart."""
    return float(on_surface(points, normals, entry, T_base_obj, tol).mean()) if len(points) else 0.0


def snap_upright(T_base_obj: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The pose with its z axis turned onto +up or -up (whichever is nearer), keeping the position."""
    z = T_base_obj[:3, 2]
    a = up if z @ up >= 0 else -up
    R = _rot_from_z(a)
    # Keep the yaw: align the rotated x axis with the original one projected onto the plane.
    x = T_base_obj[:3, 0] - a * (T_base_obj[:3, 0] @ a)
    if np.linalg.norm(x) > 1e-6:
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(a, x), a], axis=1)
    return make_T(R, T_base_obj[:3, 3])


def register_candidate(query: FusedCloud, entry: ModelEntry, model: ObjectModel, scorer: Scorer,
                       cfg: RegistrationConfig, up: np.ndarray | None = None) -> Hypothesis:
    """Screen hypotheses for one model, refine the best few, return the best."""
    best = None
    for _, name, Tb in screen_candidate(query, entry, model, scorer, cfg, up)[: cfg.keep_for_refine]:
        h = refine(query, entry, scorer, Tb, cfg, name, symmetric=model.is_rotationally_symmetric)
        if best is None or h.score > best.score:
            best = h
    return best if best is not None else Hypothesis(entry.obj_id, np.eye(4))
