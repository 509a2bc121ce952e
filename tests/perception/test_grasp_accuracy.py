"""Accuracy that grasping needs (millimetres, a few degrees), beyond ADI recall at 0.1 diameter: thin walls
fitted on their right side, items leaning as they settled, and the grasp-error metrics of `kitchenbot eval`."""

from __future__ import annotations

import numpy as np

from kitchenbot.perception.features import oriented_normals
from kitchenbot.perception.metrics import axis_tilt, grasp_error_summary, match_scan
from kitchenbot.perception.register import icp_to_model
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses
from kitchenbot.transforms import inv, make_T


def _rot_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[1.0, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def test_plate_seen_from_above_is_fitted_on_its_top_side_not_its_underside(perceiver, inventory):
    """Only the top of a side plate is seen (4.5 mm wall). ICP started 4 mm high (the underside then lies
    nearest the observed top) must come down onto the top surface when the query normals are used."""
    entry = perceiver.database[2]
    top = entry.dense_normals[:, 2] > 0.3  # what a camera above sees: surfaces facing up
    P_obj = entry.dense_points[top][::3].astype(float)
    T_true = make_T(_rot_x(3.0), np.array([0.5, 0.0, -0.18]))
    q = P_obj @ T_true[:3, :3].T + T_true[:3, 3]
    qn = oriented_normals(q, np.array([0.5, 0.0, 0.3]), 0.01)  # estimated, facing a camera above
    T_start = T_true.copy()
    T_start[2, 3] += 0.004
    v = perceiver.settings.voxel_size
    dists = (2 * v, v, 0.6 * v, 0.3 * v)
    T = inv(icp_to_model(q, entry, inv(T_start), dists, qn=qn))
    assert abs(T[2, 3] - T_true[2, 3]) < 0.0015, f"z off by {1000 * (T[2, 3] - T_true[2, 3]):.1f} mm"


def test_leaning_cup_keeps_its_lean(perceiver, inventory, cell):
    """A cup leaning 12 deg (as settled against another item) is reported leaning, not snapped upright: an
    upright fit puts its rim ~1 cm off. Also its position within a few millimetres."""
    T = resting_pose(inventory, 4, 0.48, 0.02, 0.0, cell)
    T = make_T(T[:3, :3] @ _rot_x(12.0), T[:3, 3] + np.array([0.0, 0.0, 0.008]))
    views, _ = render(inventory, [(4, T)], scan_poses(cell), cell, noise=0.002)
    r = perceiver.perceive(views)
    cups = [p for p in r.poses if p.obj_id == 4]
    assert len(cups) == 1 and len(r.poses) == 1
    assert np.degrees(axis_tilt(cups[0].T_base_obj, T)) < 4.0
    assert np.linalg.norm(cups[0].T_base_obj[:3, 3] - T[:3, 3]) < 0.004


def test_match_scan_and_summary_by_hand():
    I = np.eye(4)
    gt = [(1, make_T(I[:3, :3], np.array([0.0, 0, 0]))), (1, make_T(I[:3, :3], np.array([0.3, 0, 0]))),
          (2, make_T(I[:3, :3], np.array([0.0, 0.3, 0])))]
    est = [(1, make_T(_rot_x(10.0), np.array([0.302, 0, 0]))),  # 2 mm, 10 deg off the second plate
           (1, make_T(I[:3, :3], np.array([0.0, 0.0, 0.001]))),  # 1 mm off the first
           (1, make_T(I[:3, :3], np.array([0.0, 0.0, 0.012]))),  # a duplicate of the first
           (2, make_T(I[:3, :3], np.array([0.5, 0.5, 0])))]  # too far from object 2: a phantom, 2 missed
    matches, extra = match_scan(gt, est, {1: 0.2, 2: 0.1})
    assert [m.est_index for m in matches] == [1, 0, -1]
    assert np.isclose(matches[0].translation, 0.001) and np.isclose(matches[1].translation, 0.002)
    assert np.isclose(np.degrees(matches[1].tilt), 10.0) and np.isinf(matches[2].translation)
    assert sorted(extra) == [2, 3]
    s = grasp_error_summary([m.translation for m in matches[:2]], [m.tilt for m in matches[:2]], 1)
    assert s["n"] == 2 and s["missed"] == 0 and s["extra"] == 1
    assert np.isclose(s["translation_mm_median"], 1.5) and np.isclose(s["within"], 0.5)  # 10 deg is outside
    s = grasp_error_summary([np.inf], [np.inf], 1)
    assert s["missed"] == 1 and s["translation_mm_median"] is None and s["within"] == 0.0


def test_nest_pitch_of_the_builtin_dishware(inventory):
    """How far a copy rests above another (same way up): a few mm for plates, centimetres for cups and bowls."""
    pitch = {m.name: m.nest_pitch for m in inventory}
    assert 0.003 < pitch["side_plate"] < 0.008 and 0.003 < pitch["dinner_plate"] < 0.009
    assert 0.015 < pitch["bowl"] < 0.035 and 0.015 < pitch["cup"] < 0.040
    assert pitch["glass"] > pitch["cup"]  # a glass barely tapers: it sinks less far into another


def test_cup_nested_in_a_leaning_cup_two_poses_no_phantom(perceiver, inventory, cell):
    """Two cups nested 3.9 cm apart, both leaning 10 deg. Both are found within a few millimetres and degrees,
    and what the upper cup's fit leaves over is not fitted as a third cup between them (a pose closer along
    the axis than the nest pitch is the same cup)."""
    T = resting_pose(inventory, 4, 0.48, 0.02, 0.0, cell)
    lower = make_T(T[:3, :3] @ _rot_x(10.0), T[:3, 3] + np.array([0.0, 0.0, 0.01]))
    upper = lower.copy()
    upper[:3, 3] += 0.039 * lower[:3, 2]
    views, _ = render(inventory, [(4, lower), (4, upper)], scan_poses(cell), cell, noise=0.002)
    r = perceiver.perceive(views)
    cups = [p.T_base_obj for p in r.poses if p.obj_id == 4]
    assert len(cups) == 2 and len(r.poses) == 2, f"{len(cups)} cups, {len(r.poses)} objects for 2 cups"
    matches, extra = match_scan([(4, lower), (4, upper)], [(4, T) for T in cups], {4: inventory[4].diameter})
    assert not extra
    for m in matches:
        assert m.translation < 0.005 and np.degrees(m.tilt) < 3.0, (m.translation, np.degrees(m.tilt))
