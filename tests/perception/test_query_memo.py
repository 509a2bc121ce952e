"""An instance's query (its voxel centres, normals and fused features: Perceiver._query) is made once per scan: the
same points asked again get the cloud made for them, and one made without point features gets them added rather
than being fused again; what it gives equals the query fused afresh. Other points, or another scan's views, are
fused afresh."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception import pipeline
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses


@pytest.fixture
def scan(perceiver, inventory, cell):
    """A perceived scan of a cup and a mug: (the views used, the map)."""
    placed = [(4, resting_pose(inventory, 4, 0.45, 0.09, 0.3, cell)),
              (5, resting_pose(inventory, 5, 0.38, -0.11, 1.0, cell))]
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    r = perceiver.perceive(views)
    return r.views, r.map


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(a, f), getattr(b, f))
               for f in ("points", "normals", "img", "pts", "cls_token", "geo_token"))


def test_an_instance_asked_again_gets_its_query_and_point_features_are_added_not_fused_again(perceiver, scan,
                                                                                             monkeypatch):
    views, m = scan
    ids = [i for i in m.instance_ids if i >= 0 and (m.ids == i).sum() > 200]
    assert len(ids) >= 2
    a, b = (m.select(np.nonzero(m.ids == i)[0]) for i in ids[:2])
    fused, encoded = [], []
    real_fuse, real_encode = pipeline.fuse_instance, perceiver.pt_enc.encode
    monkeypatch.setattr(pipeline, "fuse_instance", lambda *x, **k: fused.append(1) or real_fuse(*x, **k))
    monkeypatch.setattr(perceiver.pt_enc, "encode", lambda *x, **k: encoded.append(1) or real_encode(*x, **k))
    perceiver._query_memo = None  # a new scan
    bare = perceiver._query(a, views, point_features=False)
    assert (len(fused), len(encoded)) == (1, 0) and bare.pts.shape[1] == 0
    assert perceiver._query(a, views, point_features=False) is bare
    full = perceiver._query(a, views)
    assert (len(fused), len(encoded)) == (1, 1)  # the point features added, nothing fused again
    assert perceiver._query(a, views) is full and perceiver._query(a, views, point_features=False) is full
    assert len(encoded) == 1
    # what it gives is what fusing the instance afresh gives
    assert _same(full, perceiver._fused(a, views, True)) and _same(bare, perceiver._fused(a, views, False))
    fused.clear()
    # other points: fused afresh (and their own query)
    qb = perceiver._query(b, views)
    assert len(fused) == 1 and not np.array_equal(qb.points, full.points)
    # the same points in another scan's views (a new list): fused afresh, to the same cloud for the same images
    other = list(views)
    assert perceiver._query(a, other) is not full and len(fused) == 2
    assert _same(perceiver._query(a, other), full)
