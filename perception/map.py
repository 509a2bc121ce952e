"""Instance-aware map (paper III-C): the views fused into base-frame points (x, y, z, id).

When the scan poses are off (arm repeatability, hand-eye error), each view is first registered onto the
first one: point-to-plane ICP on the whole view (the sink walls and floor pin all six degrees of freedom),
with a coarse FPFH + RANSAC alignment first when ICP from the given pose does not converge. Corrections
larger than a few centimetres / degrees are refused (then the given pose is kept).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from kitchenbot.perception.detect import Detection
from kitchenbot.perception.ransac import one_thread
from kitchenbot.perception.rgbd import point_map
from kitchenbot.perception.types import View
from kitchenbot.transforms import pose_error

reg = o3d.pipelines.registration


@dataclass
class InstanceMap:
    """Points of the segmented instances in the base frame, with where each came from."""

    points: np.ndarray  # (N, 3) base frame, metres
    ids: np.ndarray  # (N,) instance id
    view: np.ndarray  # (N,) index of the view the point was seen in
    pixel: np.ndarray  # (N, 2) (row, col) in that view
    cam_centres: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (n_views, 3)

    @property
    def instance_ids(self) -> list[int]:
        return sorted(int(i) for i in np.unique(self.ids))

    def select(self, keep: np.ndarray) -> "InstanceMap":
        return InstanceMap(self.points[keep], self.ids[keep], self.view[keep], self.pixel[keep], self.cam_centres)

    @staticmethod
    def empty(n_views: int = 0) -> "InstanceMap":
        return InstanceMap(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2), np.int64),
                           np.zeros((n_views, 3)))


def _cloud(points: np.ndarray, voxel: float) -> o3d.geometry.PointCloud:
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc = pc.voxel_down_sample(voxel)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=voxel * 2.5, max_nn=30))
    return pc


def align_views(views: list[View], voxel: float = 0.01, max_trans: float = 0.03, max_rot_deg: float = 5.0,
                coarse: bool = True, max_range: float = 1.5, min_trans: float = 0.003,
                min_rot_deg: float = 0.3) -> tuple[list[View], list[np.ndarray]]:
    """Views with corrected T_base_cam (each registered onto view 0), and the corrections applied (base frame).
    Corrections below `min_trans` / `min_rot_deg` (the registration's own error level) are not applied."""
    if len(views) < 2:
        return list(views), [np.eye(4) for _ in views]
    clouds = []
    for v in views:
        p = point_map(v, stride=4).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1) & (np.linalg.norm(p - v.T_base_cam[:3, 3], axis=1) < max_range)]
        # Every cloud with its normals, although point-to-plane ICP reads the target's only (the sources' are
        # ~35 ms of a D435 table scan). Open3D's ICP runs threaded and its result varies in its last bits from run
        # to run under load either way (dev table scans: 3 of 8 runs without the sources' normals, 1 of 10 with
        # them); until that is settled the registration is left as it was.
        clouds.append(_cloud(p.astype(np.float64), voxel))
    out, corr = [views[0]], [np.eye(4)]
    target = clouds[0]
    for v, src in zip(views[1:], clouds[1:]):
        T = np.eye(4)
        if len(src.points) >= 50 and len(target.points) >= 50:
            res = reg.registration_icp(src, target, 2 * voxel, np.eye(4), reg.TransformationEstimationPointToPlane(),
                                       reg.ICPConvergenceCriteria(max_iteration=30))
            if res.fitness < 0.5 and coarse:
                res = _coarse_then_icp(src, target, voxel)
            rot, tr = pose_error(np.eye(4), res.transformation)
            small = tr < min_trans and np.degrees(rot) < min_rot_deg
            if res.fitness >= 0.5 and tr <= max_trans and np.degrees(rot) <= max_rot_deg and not small:
                T = res.transformation
        out.append(View(v.rgb, v.depth, v.K, T @ v.T_base_cam, v.stamp))
        corr.append(T)
    return out, corr


_CELL_CLOUDS: dict = {}  # the sampled cell surfaces of the last cell used (sampling takes ~0.3 s)


def _cell_cloud(cell, region_lo: np.ndarray, region_hi: np.ndarray, spacing: float = 0.005) -> o3d.geometry.PointCloud:
    """Points with normals on the cell's box surfaces inside a region (the known geometry to register to)."""
    mesh = o3d.geometry.TriangleMesh()
    for b in cell.boxes:
        if np.any(b.upper < region_lo) or np.any(b.lower > region_hi):
            continue
        m = o3d.geometry.TriangleMesh.create_box(*b.size)
        m.translate(b.lower)
        mesh += m
    if len(mesh.triangles) == 0:
        return o3d.geometry.PointCloud()
    mesh.compute_triangle_normals()
    n = int(mesh.get_surface_area() / spacing**2)
    o3d.utility.random.seed(0)
    pc = mesh.sample_points_uniformly(min(n, 400_000), use_triangle_normal=True)
    P = np.asarray(pc.points)
    keep = np.all((P >= region_lo) & (P <= region_hi), axis=1)
    return pc.select_by_index(np.nonzero(keep)[0])


def align_to_cell(views: list[View], cell, max_trans: float = 0.03, max_rot_deg: float = 5.0,
                  max_dist: float = 0.015, min_trans: float = 0.003, min_rot_deg: float = 0.3) -> tuple[list[View], np.ndarray]:
    """Register the (already mutually aligned) views onto the known cell geometry around the sink - the basin's
    floor and walls and the counter top - with robust (Tukey) point-to-plane ICP, so that a scan whose
    poses are all off by the same error (arm / hand-eye calibration) lands on the cell. Returns the views with
    corrected poses and the correction (identity when refused: too large, or too little cell in view; and
    when smaller than `min_trans` / `min_rot_deg`, this registration's own error level on cluttered scenes)."""
    lo, hi = cell.sink_interior
    lo, hi = lo - np.array([0.1, 0.1, 0.03]), hi + np.array([0.1, 0.1, 0.05])
    key = (id(cell), cell.spec.model_dump_json())
    if key not in _CELL_CLOUDS:
        _CELL_CLOUDS.clear()
        # 1 cm apart: the cell is flat boxes, so point-to-plane residuals do not depend on the spacing, and
        # Open3D rebuilds the target's KD-tree on every call (at 6 mm: 50k points, 40 % more time per view;
        # corrections the same within 0.1 mm on dev scans with 6 mm / 1 deg pose errors).
        _CELL_CLOUDS[key] = _cell_cloud(cell, lo, hi, 0.01)
    target = _CELL_CLOUDS[key]
    pts = []
    for v in views:
        p = point_map(v, stride=6).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1)]
        pts.append(p[np.all((p >= lo) & (p <= hi), axis=1)])
    P = np.concatenate(pts).astype(np.float64) if pts else np.zeros((0, 3))
    if len(P) < 200 or len(target.points) < 200:
        return list(views), np.eye(4)
    # Point-to-plane needs the target's normals only: the source is just voxel-downsampled.
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P)).voxel_down_sample(0.008)
    est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=0.005))
    res = reg.registration_icp(src, target, max_dist, np.eye(4), est, reg.ICPConvergenceCriteria(max_iteration=40))
    rot, tr = pose_error(np.eye(4), res.transformation)
    if res.fitness < 0.3 or tr > max_trans or np.degrees(rot) > max_rot_deg:
        return list(views), np.eye(4)
    if tr < min_trans and np.degrees(rot) < min_rot_deg:
        return list(views), np.eye(4)
    T = res.transformation
    return [View(v.rgb, v.depth, v.K, T @ v.T_base_cam, v.stamp) for v in views], T


def _coarse_then_icp(src: o3d.geometry.PointCloud, dst: o3d.geometry.PointCloud, voxel: float):
    param = o3d.geometry.KDTreeSearchParamHybrid(radius=voxel * 5, max_nn=100)
    fs = reg.compute_fpfh_feature(src, param)
    fd = reg.compute_fpfh_feature(dst, param)
    with one_thread():  # same answer every run (perception/ransac.py)
        coarse = reg.registration_ransac_based_on_feature_matching(
            src, dst, fs, fd, True, 1.5 * voxel, reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
            reg.RANSACConvergenceCriteria(20000, 0.999))
    return reg.registration_icp(src, dst, 2 * voxel, coarse.transformation, reg.TransformationEstimationPointToPlane(),
                                reg.ICPConvergenceCriteria(max_iteration=30))


def build_map(views: list[View], dets: list[list[Detection]], ids: list[np.ndarray], stride: int = 2) -> InstanceMap:
    """Fuse the masked pixels of all views into one instance map (pixels subsampled by `stride`)."""
    pts, lab, vw, px = [], [], [], []
    for k, (v, ds, iv) in enumerate(zip(views, dets, ids)):
        pm = point_map(v, stride)
        finite = np.all(np.isfinite(pm), axis=2)
        for d, i in zip(ds, iv):
            sel = d.mask[::stride, ::stride] & finite
            p = pm[sel].astype(np.float64)
            rc = np.argwhere(sel) * stride
            pts.append(p)
            lab.append(np.full(len(p), int(i)))
            vw.append(np.full(len(p), k))
            px.append(rc)
    centres = np.array([v.T_base_cam[:3, 3] for v in views]) if views else np.zeros((0, 3))
    if not pts:
        return InstanceMap.empty(len(views))
    return InstanceMap(np.concatenate(pts), np.concatenate(lab).astype(np.int64), np.concatenate(vw).astype(np.int64),
                       np.concatenate(px).astype(np.int64), centres)


def consolidate(m: InstanceMap, radius: float = 0.006, min_shared: float = 0.5, max_fragment: int = 400,
                touch: float = 0.012) -> InstanceMap:
    """Merge instances that are the same surface seen in different views but were not associated
    (e.g. one view saw two touching items as one mask): ids whose points mostly lie on each other's."""
    inst = m.instance_ids
    if len(inst) < 2:
        return m
    # Each instance's points (in map order) from one stable sort, not a pass over the map per instance.
    order = np.argsort(m.ids, kind="stable")
    start = np.searchsorted(m.ids[order], inst, side="left")
    stop = np.searchsorted(m.ids[order], inst, side="right")
    points = {i: m.points[order[a:b]] for i, a, b in zip(inst, start, stop)}
    trees = {i: cKDTree(points[i]) for i in inst}
    parent = {i: i for i in inst}

    def find(a):
        while parent[a] != a:
            a = parent[a]
        return a

    # Bounding boxes: an instance farther than the query radius from another's box has no point near it (the
    # KD-tree queries of all pairs were most of this function on a cluttered table).
    box = {i: (trees[i].mins, trees[i].maxes) for i in inst}

    def apart(a, b, r):
        return bool(np.any(box[a][0] - box[b][1] > r) or np.any(box[b][0] - box[a][1] > r))

    for a in inst:
        pa = points[a]
        if len(pa) > 400:
            pa = pa[np.linspace(0, len(pa) - 1, 400).astype(int)]
        for b in inst:
            if b == a or apart(a, b, radius):
                continue
            d, _ = trees[b].query(pa, distance_upper_bound=radius)
            if np.mean(np.isfinite(d)) >= min_shared:
                ra, rb = find(a), find(b)
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
    # Small fragments (a mug handle or a rim seen apart from the body) join the instance they touch; if that
    # over-merges two objects, the pose stage splits them again by re-fitting what one model leaves over.
    sizes = {i: len(points[i]) for i in inst}
    for a in sorted(inst, key=lambda i: sizes[i]):
        if sizes[a] > max_fragment:
            break
        pa = points[a]
        best, best_d = None, np.inf
        for b in inst:
            if find(b) == find(a) or sizes[b] < 3 * sizes[a] or apart(a, b, touch):
                continue
            d = trees[b].query(pa, distance_upper_bound=touch)[0].min()
            if d < best_d:
                best, best_d = b, d
        if best is not None and np.isfinite(best_d):
            ra, rb = find(a), find(best)
            parent[max(ra, rb)] = min(ra, rb)
    # Each point takes its instance's root: one lookup per instance, not a Python call per point (the per-point
    # loop was most of the map stage on a D435 table scan, ~200k points).
    ids_u, where = np.unique(m.ids, return_inverse=True)
    new = np.array([find(int(i)) for i in ids_u], np.int64)[where.reshape(-1)] if len(m.ids) else m.ids
    _, dense = np.unique(new, return_inverse=True)
    return InstanceMap(m.points, dense.astype(np.int64), m.view, m.pixel, m.cam_centres)
