"""Cross-view association of per-view masks (paper III-C "Instance segmentation across multi-view images").

Each mask is lifted to 3D with its depth and camera pose, projected into every other view, kept where the
other view's depth agrees (so occluded parts do not count), and compared with that view's masks by IoU.
Two masks get the same instance id when the IoU passes the threshold in BOTH directions (a->b and b->a)
and each is the other's best match; ids are made transitive with a union-find over all view pairs.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import binary_dilation

from kitchenbot.perception.detect import Detection
from kitchenbot.perception.rgbd import point_map, project_pixels
from kitchenbot.perception.types import View


def projected_iou(src: View, src_dets: list[Detection], dst: View, dst_dets: list[Detection],
                  depth_tol: float = 0.02, stride: int = 2, src_prep: dict | None = None,
                  dst_prep: dict | None = None) -> np.ndarray:
    """IoU[a, b] between mask a of `src` projected into `dst` and mask b of `dst`. `src_prep` / `dst_prep`:
    `_prepared(view, dets, stride)` of either side, made once per view when it takes part in several pairs."""
    na, nb = len(src_dets), len(dst_dets)
    iou = np.zeros((na, nb))
    if na == 0 or nb == 0:
        return iou
    h, w = dst.depth.shape
    dp = dst_prep or _prepared(dst, dst_dets, stride)
    sp = src_prep or _prepared(src, src_dets, stride)
    dst_lab, dst_area, dd = dp["lab"], dp["area"], dp["depth"]
    for i, d in enumerate(src_dets):
        pts = sp["points"][i]
        if len(pts) == 0:
            continue
        rc, z, _ = project_pixels(dst, pts)
        if len(rc) == 0:
            continue
        obs = dd[rc[:, 0], rc[:, 1]]
        # Visible in dst: depth agrees, or dst has no depth there (holes do not veto).
        vis = (obs <= 0) | (np.abs(obs - z) < depth_tol)
        rc = rc[vis]
        if len(rc) == 0:
            continue
        # The splat and its dilation live in the points' bounding box grown by `stride` pixels (dilating the
        # whole image per mask cost more than everything else here; the result is the same).
        r0, c0 = np.maximum(rc.min(axis=0) - stride, 0)
        r1, c1 = np.minimum(rc.max(axis=0) + stride + 1, (h, w))
        proj = np.zeros((r1 - r0, c1 - c0), bool)
        proj[rc[:, 0] - r0, rc[:, 1] - c0] = True
        proj = binary_dilation(proj, iterations=stride)  # fill the gaps of the subsampled, resampled splat
        area = proj.sum()
        lab = dst_lab[r0:r1, c0:c1]
        inter = np.bincount(lab[proj & (lab >= 0)], minlength=nb).astype(float)
        iou[i] = inter / (area + dst_area - inter)
    return iou


def _prepared(view: View, dets: list[Detection], stride: int) -> dict:
    """What projected_iou reads of a view, as source (each mask's lifted points, subsampled by `stride`) and as
    destination (label image, mask areas, depth with holes as 0)."""
    h, w = view.depth.shape
    lab = np.full((h, w), -1, np.int64)
    for j, d in enumerate(dets):
        lab[d.mask & (lab < 0)] = j
    pm = point_map(view, stride)
    points = []
    for d in dets:
        pts = pm[d.mask[::stride, ::stride]]
        points.append(pts[np.all(np.isfinite(pts), axis=1)].astype(np.float64))
    return {"lab": lab, "area": np.array([d.mask.sum() for d in dets], float),
            "depth": np.nan_to_num(np.asarray(view.depth, np.float64), nan=0.0), "points": points}


class _UnionFind:
    def __init__(self, n: int):
        self.p = list(range(n))

    def find(self, a: int) -> int:
        while self.p[a] != a:
            self.p[a] = self.p[self.p[a]]
            a = self.p[a]
        return a

    def union(self, a: int, b: int) -> None:
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.p[max(ra, rb)] = min(ra, rb)


def associate(views: list[View], dets: list[list[Detection]], iou_threshold: float = 0.6,
              depth_tol: float = 0.02) -> list[np.ndarray]:
    """Instance ids (0..n-1, consistent across views) for every detection of every view."""
    offsets = np.cumsum([0] + [len(d) for d in dets])
    uf = _UnionFind(int(offsets[-1]))
    # Each view's masks lifted, label image and depth made once: every view takes part in 2 (n - 1) pairs.
    prep = [_prepared(v, d, 2) if d else None for v, d in zip(views, dets)]
    for i in range(len(views)):
        for j in range(i + 1, len(views)):
            if not dets[i] or not dets[j]:
                continue
            a2b = projected_iou(views[i], dets[i], views[j], dets[j], depth_tol, 2, prep[i], prep[j])
            b2a = projected_iou(views[j], dets[j], views[i], dets[i], depth_tol, 2, prep[j], prep[i]).T
            both = np.minimum(a2b, b2a)
            for a in range(len(dets[i])):
                b = int(np.argmax(both[a]))
                if both[a, b] >= iou_threshold and int(np.argmax(both[:, b])) == a:
                    uf.union(offsets[i] + a, offsets[j] + b)
    roots = [uf.find(k) for k in range(int(offsets[-1]))]
    remap = {r: n for n, r in enumerate(dict.fromkeys(roots))}
    ids = np.array([remap[r] for r in roots], np.int64)
    return [ids[offsets[v]: offsets[v + 1]] for v in range(len(views))]
