"""Geometric detection + segmentation per view, needing no weights.

Back-project the depth into the base frame, keep what lies inside the sink (the known cell surfaces and
everything outside the basin removed), then split the rest into surface-connected components: neighbouring
pixels belong together when their 3D points are close. Touching or stacked items can come out as one
component; the pose stage splits those with the inventory's shapes (fit one model, re-fit what it leaves
unexplained), so this stage only has to avoid splitting one object into many.

Connected components run on the pixel graph with scipy's sparse graph routines (exact, ~10 ms for VGA).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from kitchenbot.perception.detect import Detection, box_of
from kitchenbot.perception.ransac import segment_plane
from kitchenbot.perception.rgbd import point_map
from kitchenbot.perception.surfaces import SurfaceMap
from kitchenbot.perception.types import View
from kitchenbot.world.cell import Cell


@dataclass
class GeometricSegmenterConfig:
    surface_margin: float = 0.004  # m: points this close to (or inside) a cell box are the cell, not objects
    wall_margin: float = 0.006  # m: extra clearance from the basin walls
    above_rim: float = 0.30  # m: how far above the counter an item in the sink may reach
    link_distance: float = 0.010  # m: neighbouring pixels farther apart than this (3D) are not connected
    min_pixels: int = 120  # at full resolution
    max_gap: int = 3  # (strided) pixels of unknown depth bridged between two parts of one surface
    stride: int = 2  # segment every 2nd row/column (the map samples the same grid), masks at full size
    min_extent: float = 0.012  # m: components smaller than this in every direction are noise


def foreground_mask(view: View, cell: Cell, cfg: GeometricSegmenterConfig, pts: np.ndarray | None = None) -> np.ndarray:
    """Pixels whose 3D point lies inside the sink region and is not a cell surface."""
    if pts is None:
        pts = point_map(view)
    ok = np.all(np.isfinite(pts), axis=2)
    lo, hi = cell.sink_interior
    lo = lo + np.array([cfg.wall_margin, cfg.wall_margin, 0.0])
    hi = hi + np.array([-cfg.wall_margin, -cfg.wall_margin, cfg.above_rim])
    with np.errstate(invalid="ignore"):
        ok &= np.all((pts >= lo) & (pts <= hi), axis=2)
    idx = np.nonzero(ok)
    p = pts[idx]
    keep = np.ones(len(p), bool)
    for b in cell.boxes:
        if np.any(b.lower - hi > cfg.surface_margin) or np.any(lo - b.upper > cfg.surface_margin):
            continue  # farther than the margin from the whole region kept: removes nothing
        # Distance to an axis-aligned box (0 inside).
        d = np.linalg.norm(np.maximum(np.maximum(b.lower - p, p - b.upper), 0.0), axis=1)
        keep &= d > cfg.surface_margin
    ok[idx[0][~keep], idx[1][~keep]] = False
    ok &= ~measured_surfaces(pts, cell, cfg)
    return ok


def measured_surfaces(pts: np.ndarray, cell: Cell, cfg: GeometricSegmenterConfig, band: float = 0.02) -> np.ndarray:
    """Pixels on (or behind) the basin's floor and walls as MEASURED: near each nominal surface a plane is fitted
    (RANSAC, perception/ransac.py) to the points, and what lies within the margin of it, or beyond it, is the sink. This keeps the
    removal right when the scan poses are a few millimetres / tenths of a degree off the nominal cell."""
    lo, hi = cell.sink_interior
    out = np.zeros(pts.shape[:2], bool)
    finite = np.all(np.isfinite(pts), axis=2)
    P = np.where(finite[..., None], pts, 0.0)
    inside_xy = (P[..., 0] > lo[0] - band) & (P[..., 0] < hi[0] + band) & (P[..., 1] > lo[1] - band) & \
        (P[..., 1] < hi[1] + band) & finite
    below_rim = P[..., 2] < hi[2] + 0.01
    # (axis, nominal coordinate, inward direction) of the floor and the four walls.
    faces = [(2, lo[2], 1.0), (0, lo[0], 1.0), (0, hi[0], -1.0), (1, lo[1], 1.0), (1, hi[1], -1.0)]
    for axis, value, sign in faces:
        d_nom = sign * (P[..., axis] - value)
        near = inside_xy & below_rim & (np.abs(d_nom) < band)
        Q = P[near]
        if len(Q) < 200:
            continue
        sub = Q[:: max(1, len(Q) // 5000)].astype(np.float64)
        plane, inl = segment_plane(sub, 0.004, 100)
        n, d = plane[:3], float(plane[3])
        if abs(n[axis]) < np.cos(np.radians(6)) or len(inl) < 0.3 * len(sub):
            continue  # no clear plane here (the surface is hidden under items): keep the nominal removal only
        if np.sign(n[axis]) != sign:
            n, d = -n, -d
        h = P @ n + d  # signed distance, positive towards the inside of the basin
        out |= inside_xy & below_rim & (np.abs(d_nom) < 2 * band) & (h < cfg.surface_margin)
    return out


def components(pts: np.ndarray, fg: np.ndarray, link: float, max_gap: int = 10, px_angle: float = 0.0,
               cam_z: float = 0.0) -> tuple[np.ndarray, int]:
    """Label image (-1 = background) of 3D-connected foreground pixels (8-neighbourhood, and across gaps of
    up to `max_gap` pixels without depth; `px_angle` = radians per pixel, `cam_z` = camera height, used to
    bound how far apart the two sides of a gap may be)."""
    h, w = fg.shape
    ids = np.full((h, w), -1, np.int64)
    n = int(fg.sum())
    ids[fg] = np.arange(n)
    # Work on the foreground pixels only (row-major, as their ids), not on whole shifted images: the same
    # edges in the same order for the part of the view that matters.
    y, x = np.nonzero(fg)
    P = pts[y, x]
    rows, cols = [], []

    def neighbours(dr: int, dc: int) -> tuple[np.ndarray, np.ndarray]:
        """(own ids, neighbour ids) of the foreground pixels whose pixel (dr, dc) away is foreground."""
        inb = (y + dr < h) & (x + dc >= 0) & (x + dc < w)
        own = np.nonzero(inb)[0]
        other = ids[y[own] + dr, x[own] + dc]
        ok = other >= 0
        return own[ok], other[ok]

    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a, b = neighbours(dr, dc)
        d = np.linalg.norm(P[a] - P[b], axis=1)
        close = d < link * (1.4 if dr and dc else 1.0)
        rows.append(a[close])
        cols.append(b[close])
    # Bridge short runs of unknown depth (stereo holes, NaN bands): pixels k apart along a row or column,
    # with no depth in between, are linked when their 3D distance is consistent with one smooth surface.
    valid = np.all(np.isfinite(pts), axis=2)
    for k in range(2, max_gap + 1):
        for dr, dc in ((0, k), (k, 0)):
            a, b = neighbours(dr, dc)
            gap = ~valid[y[a] + dr // 2, x[a] + dc // 2]
            a, b = a[gap], b[gap]
            if not len(a):
                continue
            pa, pb = P[a], P[b]
            # A surface seen at up to ~60 deg spans at most ~2 pixel footprints per pixel.
            foot = 2.0 * k * np.abs(pa[:, 2] - cam_z) * px_angle if px_angle else 0.0
            close = np.linalg.norm(pa - pb, axis=1) < link + foot
            rows.append(a[close])
            cols.append(b[close])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(n, n))
    k, lab = connected_components(graph, directed=False)
    out = np.full((h, w), -1, np.int64)
    out[fg] = lab
    return out, k


def plane_foreground(view: View, cfg: GeometricSegmenterConfig, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Without a known cell: pixels above the dominant plane (RANSAC, perception/ransac.py), and that plane's normal
    (base frame, towards the camera)."""
    ok = np.all(np.isfinite(pts), axis=2)
    P = pts[ok]
    if len(P) < 100:
        return np.zeros_like(ok), None, 0.0
    plane, _ = segment_plane(P[:: max(1, len(P) // 20000)], 0.006, 300)
    n, d = plane[:3], float(plane[3])
    if n @ view.T_base_cam[:3, 3] + d < 0:
        n, d = -n, -d
    with np.errstate(invalid="ignore"):
        h = pts @ n + d
        fg = ok & (h > cfg.surface_margin + 0.002) & (h < cfg.above_rim)
    # Other large planes (walls, a basin's sides) are background too: no dish is flat over 35 cm.
    for _ in range(3):
        Q = pts[fg]
        if len(Q) < 500:
            break
        sub = Q[:: max(1, len(Q) // 20000)].astype(np.float64)
        pl, inl = segment_plane(sub, 0.006, 200)
        I = sub[inl]
        if len(inl) < 0.1 * len(sub) or np.linalg.norm(np.percentile(I, 95, 0) - np.percentile(I, 5, 0)) < 0.35:
            break
        with np.errstate(invalid="ignore"):
            fg &= ~(np.abs(pts @ np.asarray(pl[:3]) + pl[3]) < cfg.surface_margin + 0.002)
    return fg, n, d


class GeometricSegmenter:
    """Detector and segmenter in one: instance masks of everything in the sink that is not the sink.
    With `surfaces` (found in the scan, perception/surfaces.py) and no cell: everything standing on a support
    that is not a surface. With neither (a single image without gravity): everything standing on the
    dominant plane of each view (generic table tops)."""

    def __init__(self, cell: Cell | None, cfg: GeometricSegmenterConfig | None = None,
                 surfaces: SurfaceMap | None = None):
        self.cell = cell
        self.surfaces = surfaces  # set per scan by the Perceiver when it uses no cell
        self.cfg = cfg or GeometricSegmenterConfig()
        self.support_normal: np.ndarray | None = None  # plane mode: 'up' of the last view (base frame) ...
        self.support_offset: float | None = None  # ... and the plane's offset: p . n + d = 0

    def detect(self, view: View) -> list[Detection]:
        cfg = self.cfg
        s = cfg.stride
        pts = point_map(view, s)
        if self.cell is not None:
            fg = foreground_mask(view, self.cell, cfg, pts)
        elif self.surfaces is not None:
            fg = self.surfaces.foreground(pts, view.T_base_cam[:3, 3])
        else:
            fg, self.support_normal, self.support_offset = plane_foreground(view, cfg, pts)
        if not fg.any():
            return []
        lab, k = components(pts, fg, cfg.link_distance, cfg.max_gap, s / view.K[0, 0], view.T_base_cam[2, 3])
        counts = np.bincount(lab[fg], minlength=k)
        h, w = view.depth.shape
        # Each component is read inside its bounding box (a table scan has tens of components; whole-image
        # passes per component were a fifth of the segmentation). Same points in the same (row-major) order.
        boxes = ndimage.find_objects(lab + 1, max_label=k)
        out = []
        for i in np.nonzero(counts * s * s >= cfg.min_pixels)[0]:
            rs, cs = boxes[i]
            m = lab[rs, cs] == i
            p = pts[rs, cs][m]
            ext = np.percentile(p, 98, axis=0) - np.percentile(p, 2, axis=0)
            if ext.max() < cfg.min_extent:
                continue
            if self.cell is None and self.surfaces is not None and (
                    self.surfaces.is_crease(p.astype(np.float64)) or self.surfaces.is_wall_remnant(p.astype(np.float64))):
                continue  # a basin's rounded corner or bevel between a floor and a wall, or a wall little seen
            # Back to full resolution: each sample covers its s x s block.
            full = np.zeros((h, w), bool)
            r0, c0 = rs.start * s, cs.start * s
            block = np.repeat(np.repeat(m, s, axis=0), s, axis=1)[: h - r0, : w - c0]
            full[r0: r0 + block.shape[0], c0: c0 + block.shape[1]] = block
            box = box_of(block) + np.array([c0, r0, c0, r0], float)
            out.append(Detection(box=box, score=1.0, mask=full, label="object"))
        return out

    def segment(self, view: View, detections: list[Detection]) -> list[Detection]:
        return [d for d in detections if d.mask is not None and d.mask.any()]
