"""RANSAC correspondences written out (perception.register.feature_matches) are Open3D's own."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.perception.database import ModelEntry
from kitchenbot.perception.features import FusedCloud
from kitchenbot.perception.ransac import one_thread
from kitchenbot.perception.register import feature_matches

reg = o3d.pipelines.registration


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _entry(points: np.ndarray, feats: np.ndarray) -> ModelEntry:
    n = len(points)
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    ref = FusedCloud(points, normals, np.zeros((n, 0)), feats, np.zeros(0), _unit(feats.mean(axis=0)[None])[0])
    return ModelEntry(0, ref, np.zeros((0, 0)), np.zeros((1, feats.shape[1])), points.astype(np.float32),
                      normals.astype(np.float32))


def _o3d_feature(f: np.ndarray) -> reg.Feature:
    feat = reg.Feature()
    feat.data = np.ascontiguousarray(f.T, dtype=np.float64)
    return feat


def _cloud(p: np.ndarray) -> o3d.geometry.PointCloud:
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))


def test_each_query_feature_is_matched_to_the_model_feature_open3d_matches_it_to():
    rng = np.random.default_rng(3)
    fr = _unit(rng.random((500, 49)))
    # queries: random ones, and ones a hair off model features (the nearest is clear but the second is close)
    fq = _unit(np.vstack([rng.random((700, 49)), fr[::5] + 1e-6 * rng.standard_normal((100, 49))]))
    ours = feature_matches(fq, _entry(rng.random((500, 3)), fr))
    theirs = np.asarray(reg.correspondences_from_features(_o3d_feature(fq), _o3d_feature(fr), False))
    assert ours.dtype == np.int32 and ours.shape == (800, 2)
    np.testing.assert_array_equal(ours, theirs)


def test_the_ransac_on_them_gives_open3ds_feature_matching_ransac_pose():
    rng = np.random.default_rng(5)
    P = rng.random((300, 3)) * 0.1
    fr = _unit(rng.random((300, 33)))
    a = 0.3
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    Q = P[::2] @ R.T + [0.02, -0.01, 0.0]  # the query: half the model's points, moved
    fq = _unit(fr[::2] + 0.05 * rng.standard_normal((150, 33)))
    args = (0.015, reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(0.015)],
            reg.RANSACConvergenceCriteria(1000, 0.999))
    with one_thread():
        o3d.utility.random.seed(0)
        theirs = reg.registration_ransac_based_on_feature_matching(_cloud(Q), _cloud(P), _o3d_feature(fq),
                                                                   _o3d_feature(fr), False, *args)
        o3d.utility.random.seed(0)
        corres = o3d.utility.Vector2iVector(feature_matches(fq, _entry(P, fr)))
        ours = reg.registration_ransac_based_on_correspondence(_cloud(Q), _cloud(P), corres, *args)
    assert theirs.fitness > 0.5
    np.testing.assert_array_equal(np.asarray(ours.transformation), np.asarray(theirs.transformation))
