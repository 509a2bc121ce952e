"""ADI / ADD-S, recall and AUC on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.metrics import add, adi, auc_adds, match_image, recall_at
from kitchenbot.transforms import make_T, rot_x, rot_z, trans


def test_adi_two_points_by_hand():
    pts = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    # Shift up by 0.5: each GT point's nearest estimated point is its own copy, 0.5 away.
    assert adi(trans(0, 0, 0.5), np.eye(4), pts) == pytest.approx(0.5)
    # Shift along the pair by 0.5: nearest distances 0.5 and 0.5 (to the other point's copy for the second).
    assert adi(trans(0.5, 0, 0), np.eye(4), pts) == pytest.approx(0.5)
    # Swap the two points (rotate 180 deg about the midpoint): ADI 0, ADD 1.
    T = trans(0.5, 0, 0) @ rot_z(np.pi) @ trans(-0.5, 0, 0)
    assert adi(T, np.eye(4), pts) == pytest.approx(0.0, abs=1e-12)
    assert add(T, np.eye(4), pts) == pytest.approx(1.0)


def test_cup_rotated_about_its_axis_has_adi_near_zero(inventory):
    cup = inventory.by_name("cup")
    T_gt = make_T(t=[0.4, 0.1, -0.1])
    T_est = T_gt @ rot_z(0.7)
    assert adi(T_est, T_gt, cup.points) < 0.002  # sampling density, not pose error
    assert add(T_est, T_gt, cup.points) > 0.02
    # A shift is a real error; ADI of a shift is at most the shift.
    e = adi(T_gt @ trans(0.03, 0, 0), T_gt, cup.points)
    assert 0.1 * cup.diameter < e <= 0.03 + 1e-9
    # Note: upside down about the bounding-box centre is only ~7 mm for this thin-walled, slightly tapered cup,
    # i.e. below 0.1 x diameter: ADI cannot tell an upside-down cup (the pipeline's own tests check that).
    assert adi(T_gt @ rot_x(np.pi), T_gt, cup.points) > 0.004


def test_recall_and_auc_by_hand():
    e = np.array([0.0, 0.05, np.inf])
    assert recall_at(e, 0.01) == pytest.approx(1 / 3)
    assert recall_at(e, np.array([0.01, 0.06, 1.0])) == pytest.approx(2 / 3)
    # AUC: error 0 is below every threshold > 0 (area 0.1 - 0.0005 with the trapezoid at t=0),
    # 0.05 is below thresholds > 0.05 (area 0.05 - 0.0005), a miss contributes nothing.
    assert auc_adds(e) == pytest.approx(((0.1 - 0.0005) + (0.05 - 0.0005)) / 0.1 / 3, abs=1e-6)
    assert auc_adds(np.array([])) == 0.0


def test_match_image_pairs_instances_of_the_same_object():
    pts = np.random.default_rng(0).normal(size=(200, 3)) * 0.03
    gt = [(1, trans(0, 0, 0)), (1, trans(0.3, 0, 0)), (2, trans(0, 0.3, 0))]
    est = [(1, trans(0.301, 0, 0), 0.9), (1, trans(0.001, 0, 0), 0.8), (3, trans(1, 1, 1), 0.5)]
    matches, unmatched = match_image(gt, est, {1: pts, 2: pts, 3: pts})
    assert [m.est_index for m in matches] == [1, 0, -1]
    assert matches[0].error < 0.002 and matches[1].error < 0.002 and matches[2].error == np.inf
    assert unmatched == [2]
