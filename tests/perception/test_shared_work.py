"""The map and segmentation stages' shortcuts give the answers of the plain computations they replace, on
hand-made situations: the support hull's inner disc, the foreground-only pixel graph, each view's masks lifted
once for association, the fragment merge's per-instance relabelling, and components read inside their boxes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from kitchenbot.perception.associate import _prepared, associate, projected_iou
from kitchenbot.perception.map import InstanceMap, consolidate
from kitchenbot.perception.segment_geometric import GeometricSegmenter, components
from kitchenbot.perception.surfaces import Surface, _in
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses


def _support(footprint: np.ndarray, feet: np.ndarray | None = None) -> Surface:
    n = np.array([0.0, 0.0, 1.0])
    return Surface("support", n, -0.7, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.1, -0.3]),
                   0.02, footprint, 1000, feet=feet)


def test_points_in_the_hulls_inner_disc_and_outside_it_are_judged_as_by_every_edge():
    # An L-shaped table top (its hull is not a box) with a wall foot beyond one corner.
    fp = np.zeros((40, 30), bool)
    fp[2:38, 2:10] = True
    fp[2:12, 2:28] = True
    s = _support(fp, feet=np.array([[0.95, 0.4, 0.7]]))
    rng = np.random.default_rng(3)
    P = np.column_stack([rng.uniform(0.0, 1.1, 20000), rng.uniform(-0.4, 0.4, 20000), rng.uniform(0.6, 0.9, 20000)])
    # ... and points right at the disc's rim and on the hull's edges.
    s.hull()
    (cu, cv), r = s._disc
    a = rng.uniform(0, 2 * np.pi, 2000)
    rim = np.column_stack([cu + r * np.cos(a), cv + r * np.sin(a), np.full(2000, 0.75)])
    P = np.concatenate([P, rim])
    assert r > 0.05
    inner = (P[:, 0] - cu) ** 2 + (P[:, 1] - cv) ** 2 < r * r
    assert 0.05 < inner.mean() < 0.9  # the shortcut decides some points, the edges the others
    assert np.array_equal(s.under_hull(P), _in(s.hull(), P, s))


def _components_whole_image(pts, fg, link, max_gap, px_angle, cam_z):
    """The pixel graph built on whole shifted images (the implementation before the foreground-only one)."""
    h, w = fg.shape
    ids = np.full((h, w), -1, np.int64)
    n = int(fg.sum())
    ids[fg] = np.arange(n)
    rows, cols = [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = ids[max(0, -dr): h - max(0, dr), max(0, -dc): w - max(0, dc)]
        b = ids[max(0, dr): h + min(0, dr) or None, max(0, dc): w + min(0, dc) or None]
        pa = pts[max(0, -dr): h - max(0, dr), max(0, -dc): w - max(0, dc)]
        pb = pts[max(0, dr): h + min(0, dr) or None, max(0, dc): w + min(0, dc) or None]
        both = (a >= 0) & (b >= 0)
        close = np.linalg.norm(pa[both] - pb[both], axis=1) < link * (1.4 if dr and dc else 1.0)
        rows.append(a[both][close])
        cols.append(b[both][close])
    valid = np.all(np.isfinite(pts), axis=2)
    for k in range(2, max_gap + 1):
        for dr, dc in ((0, k), (k, 0)):
            a, b = ids[: h - dr, : w - dc], ids[dr:, dc:]
            mid = valid[dr // 2: h - dr + dr // 2, dc // 2: w - dc + dc // 2]
            both = (a >= 0) & (b >= 0) & ~mid
            if not both.any():
                continue
            pa, pb = pts[: h - dr, : w - dc][both], pts[dr:, dc:][both]
            foot = 2.0 * k * np.abs(pa[:, 2] - cam_z) * px_angle
            close = np.linalg.norm(pa - pb, axis=1) < link + foot
            rows.append(a[both][close])
            cols.append(b[both][close])
    r, c = np.concatenate(rows), np.concatenate(cols)
    k, lab = connected_components(coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(n, n)), directed=False)
    out = np.full((h, w), -1, np.int64)
    out[fg] = lab
    return out, k


def test_foreground_pixel_graph_links_as_the_whole_image_one():
    # A point map of two boxes' tops (one 3 cm higher), a diagonal step, a band of missing depth across one
    # (bridged) and a wide hole in the other, noise; foreground touching the image's edges.
    h, w = 60, 80
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    pts = np.stack([xx * 0.004, yy * 0.004, np.full((h, w), 0.05, np.float32)], axis=2)
    pts[:, 40:, 2] += 0.03
    pts[20:, :15, 2] += 0.004 * (yy[20:, :15] - 20)
    pts += np.random.default_rng(1).normal(0, 0.0015, pts.shape).astype(np.float32)
    pts[:, 20:22] = np.nan
    pts[30:40, 55:62] = np.nan
    fg = np.all(np.isfinite(pts), axis=2)
    fg[:5, 70:] = False
    for gap in (1, 3, 10):
        new = components(pts, fg, 0.008, gap, 0.003, 0.6)
        old = _components_whole_image(pts, fg, 0.008, gap, 0.003, 0.6)
        assert new[1] == old[1] and np.array_equal(new[0], old[0])
    lab, k = components(pts, fg, 0.008, 3, 0.003, 0.6)
    assert lab[10, 10] == lab[10, 30]  # across the missing band
    assert lab[10, 10] != lab[10, 50]  # not up the 3 cm step


def test_fragment_merge_relabels_every_point_of_an_instance():
    rng = np.random.default_rng(2)
    plate = np.column_stack([rng.uniform(0, 0.2, 3000), rng.uniform(0, 0.2, 3000), np.zeros(3000)])
    # The same plate seen by another view as its own instance (shares its surface), a handle fragment touching
    # it (joins it), and a cup far away (stays apart); ids interleaved in the map.
    again = plate[rng.choice(3000, 800)] + rng.normal(0, 0.001, (800, 3))
    handle = np.column_stack([np.full(100, 0.205), rng.uniform(0.05, 0.08, 100), rng.uniform(0, 0.02, 100)])
    cup = np.column_stack([rng.uniform(0.5, 0.6, 900), rng.uniform(0.5, 0.6, 900), np.zeros(900)])
    P = np.concatenate([plate, again, handle, cup])
    ids = np.concatenate([np.full(3000, 3), np.full(800, 1), np.full(100, 7), np.full(900, 5)])
    order = rng.permutation(len(P))
    m = InstanceMap(P[order], ids[order], np.zeros(len(P), np.int64), np.zeros((len(P), 2), np.int64))
    out = consolidate(m)
    lab = out.ids[np.argsort(order)]
    assert len(out.instance_ids) == 2
    assert len(set(lab[:3900])) == 1 and len(set(lab[3900:])) == 1 and lab[0] != lab[-1]


@pytest.fixture(scope="module")
def three_items(inventory, cell):
    placed = [(4, resting_pose(inventory, 4, 0.45, 0.09, 0.3, cell)),
              (2, resting_pose(inventory, 2, 0.56, -0.06, 0.0, cell)),
              (5, resting_pose(inventory, 5, 0.38, -0.11, 1.0, cell))]
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    return views


def test_masks_lifted_once_give_the_pairs_ious(three_items, cell):
    views = three_items
    seg = GeometricSegmenter(cell)
    dets = [seg.detect(v) for v in views]
    prep = [_prepared(v, d, 2) for v, d in zip(views, dets)]
    for i in range(len(views)):
        for j in range(len(views)):
            if i != j:
                plain = projected_iou(views[i], dets[i], views[j], dets[j])
                assert np.array_equal(plain, projected_iou(views[i], dets[i], views[j], dets[j], 0.02, 2,
                                                           prep[i], prep[j]))
                assert plain.max() > 0.6
    ids = associate(views, dets)
    assert len(set(ids[0]) & set(ids[1]) & set(ids[2])) == 3  # each item one instance in every view


def test_component_masks_read_in_their_boxes_cover_whole_stride_blocks(three_items, cell):
    seg = GeometricSegmenter(cell)
    for v in three_items:
        for d in seg.detect(v):
            rows, cols = np.nonzero(d.mask)
            assert np.array_equal(d.box, [cols.min(), rows.min(), cols.max() + 1, rows.max() + 1])
            # Every sample of the strided grid stands for its 2 x 2 block.
            sub = d.mask[::2, ::2]
            assert np.array_equal(np.repeat(np.repeat(sub, 2, 0), 2, 1)[: d.mask.shape[0], : d.mask.shape[1]],
                                  d.mask)
