"""Settled stacks: the item nested under another shows only a peeking rim, within 1.5 voxels of the upper item's
surface, so it is found only by re-fitting what the upper pose leaves over at the tight tolerance."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from kitchenbot.perception.metrics import adi
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses
from kitchenbot.transforms import make_T


def _tilt(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return make_T(np.array([[1.0, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]), np.zeros(3))


@pytest.fixture(scope="module")
def stack(inventory, cell):
    """Two side plates: the lower one flat, the upper one 6 mm higher, 2 cm off-centre and tilted 10 deg (as the
    quasi-static settling leaves them), and a cup nearby."""
    lower = resting_pose(inventory, 2, 0.50, -0.03, 0.0, cell)
    upper = lower @ _tilt(10.0)
    upper[:3, 3] += [0.0, 0.02, 0.006]
    return [(2, lower), (2, upper), (4, resting_pose(inventory, 4, 0.40, 0.12, 0.3, cell))]


def test_plate_nested_under_an_off_centre_tilted_plate_is_found(perceiver, inventory, cell, stack):
    views, _ = render(inventory, stack, scan_poses(cell), cell, noise=0.002)
    r = perceiver.perceive(views)
    plates = [po for po in r.poses if po.obj_id == 2]
    assert len(plates) == 2, f"{len(plates)} side plates for 2"
    assert len(r.poses) == 3
    # One estimate per plate: the two plates matched one-to-one, each within 0.1 diameter (ADI).
    d = inventory[2].diameter
    E = np.array([[adi(po.T_base_obj, T, inventory[2].points) / d for po in plates] for _, T in stack[:2]])
    assert min(max(E[0, 0], E[1, 1]), max(E[0, 1], E[1, 0])) < 0.1, f"ADI / diameter, plates x estimates: {E}"
    cup = [po for po in r.poses if po.obj_id == 4]
    assert len(cup) == 1 and adi(cup[0].T_base_obj, stack[2][1], inventory[4].points) < 0.1 * inventory[4].diameter


def _resting_on(inventory, lower_id: int, T_lower: np.ndarray, upper_id: int, dx: float, dy: float) -> np.ndarray:
    """Pose of model `upper_id` resting on model `lower_id` (posed T_lower), shifted (dx, dy) across the lower one's
    axis: lifted along that axis until no upper surface point is under a lower one within 4 mm across, + 1 mm."""
    from scipy.spatial import cKDTree
    lower, upper = inventory[lower_id].points, inventory[upper_id].points + np.array([dx, dy, 0.0])
    tree = cKDTree(lower[:, :2])
    lift = max(lower[idx, 2].max() - p[2] for p in upper[::5] for idx in [tree.query_ball_point(p[:2], 0.004)] if idx)
    return T_lower @ make_T(np.eye(3), np.array([dx, dy, lift + 0.001]))


@pytest.fixture(scope="module")
def side_in_dinner(inventory, cell):
    """A side plate resting in a dinner plate's well, 2 cm off-centre: the dinner plate's visible ring lies a few
    millimetres under the side plate's plane."""
    dinner = resting_pose(inventory, 1, 0.50, 0.0, 0.0, cell)
    return [(1, dinner), (2, _resting_on(inventory, 1, dinner, 2, 0.0, 0.02))]


def test_plate_under_a_plate_of_another_model_is_not_taken_for_its_duplicate(perceiver, inventory, cell,
                                                                             side_in_dinner):
    """Before: the side plate's pose "explained" 65 % of the dinner plate's points at 1.5 voxels (15 mm) and the
    right dinner plate pose was dropped as its duplicate (fresh sink block 4656, scene 6, a pile). Items of
    different nesting models resting one in the other are judged like stacked copies: only points on the other's
    surface within 3 mm, facing the same way, are the other's."""
    views, _ = render(inventory, side_in_dinner, scan_poses(cell), cell, noise=0.002)
    r = perceiver.perceive(views)
    for oid, T in side_in_dinner:
        d = inventory[oid].diameter
        err = [adi(po.T_base_obj, T, inventory[oid].points) / d for po in r.poses if po.obj_id == oid]
        assert err and min(err) < 0.1, f"{inventory[oid].name}: ADI / diameter of its poses {err}"


def test_plate_under_a_plate_of_another_model_is_fitted_once(perceiver, inventory, cell, side_in_dinner):
    """Before: the dinner plate was fitted twice, 5 mm apart along its axis (a compromise fit of both plates, then
    the plate's peeking rim re-fitted): as far apart as two stacked dinner plates, so neither the twin nor the
    stacked-copy test merged them. The compromise puts 4 % of the points on its surface that the others do not:
    it is dropped as redundant (Perceiver._drop_redundant)."""
    views, _ = render(inventory, side_in_dinner, scan_poses(cell), cell, noise=0.002)
    r = perceiver.perceive(views)
    assert sorted(po.obj_id for po in r.poses) == [1, 2]


def _pile(inventory, cell, obj_id: int, n: int, pitch: float, step: tuple[float, float] = (0.0, 0.0),
          lean: float = 0.0) -> list[tuple[int, np.ndarray]]:
    """n copies of one model stacked `pitch` apart along their axis, each shifted `step` across it from the one
    under it; the whole pile leaning `lean` degrees (about the x axis, its low rim on the floor)."""
    T0 = resting_pose(inventory, obj_id, 0.50, 0.0, 0.0, cell)
    if lean:
        T0 = T0 @ _tilt(lean)
        T0[2, 3] += 0.5 * inventory[obj_id].diameter * np.sin(np.radians(lean))
    return [(obj_id, T0 @ make_T(np.eye(3), np.array([step[0] * k, step[1] * k, pitch * k]))) for k in range(n)]


def _one_pose_each(inventory, placed, poses):
    """Every placed item has its own pose within 0.1 diameter (ADI), and there are no more poses than items."""
    assert len(poses) == len(placed), f"{len(poses)} poses for {len(placed)} items"
    E = np.array([[adi(po.T_base_obj, T, inventory[oid].points) / inventory[oid].diameter if po.obj_id == oid else 9.0
                   for po in poses] for oid, T in placed])
    r, c = linear_sum_assignment(E)
    assert E[r, c].max() < 0.1, f"ADI / diameter, items x poses: {np.round(E, 3)}"


# A pile is one segment; the pose of its top item leaves the lower items' rims over, which are fitted again. The
# lower items' model surface under the item on them lies within the depth tolerance of the upper one's surface:
# before, it counted as visible and missing (model->query ratio 0.08 for the lower of two leaning dinner plates,
# under the 0.15 gate), and the lower items were lost. Now the points the upper pose took are `covered`
# (register.Scorer); a middle item's segment also holds the rim under it, which no longer counts against its
# normals once that rim has its own pose (verify.facing_unclaimed).

def test_three_stacked_dinner_plates_are_three_poses(perceiver, inventory, cell):
    """Three dinner plates 8 mm apart, each 1.5 cm off the one under it. Before: one pose."""
    placed = _pile(inventory, cell, 1, 3, 0.008, (0.0, 0.015))
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    _one_pose_each(inventory, placed, perceiver.perceive(views).poses)


def test_leaning_pile_of_two_dinner_plates_is_two_poses(perceiver, inventory, cell):
    """Two dinner plates leaning 40 deg, the upper one 2 cm up the slope. Before: one pose."""
    placed = _pile(inventory, cell, 1, 2, 0.008, (0.0, 0.02), lean=40.0)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    _one_pose_each(inventory, placed, perceiver.perceive(views).poses)


def test_three_stacked_side_plates_are_three_poses(perceiver, inventory, cell):
    """Three side plates 7 mm apart, each 1.2 cm off the one under it. Before: the top and the bottom plate (the
    middle one's pose was rejected on the normals of the bottom plate's rim in its segment)."""
    placed = _pile(inventory, cell, 2, 3, 0.007, (0.012, 0.0))
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    _one_pose_each(inventory, placed, perceiver.perceive(views).poses)


def test_three_nested_cups_are_three_poses(perceiver, inventory, cell):
    """Three cups nested 2.7 cm apart, each 4 mm off the one under it. Before: the top and the middle cup."""
    placed = _pile(inventory, cell, 4, 3, 0.027, (0.004, 0.0))
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    _one_pose_each(inventory, placed, perceiver.perceive(views).poses)

def test_two_nested_bowls_leaning_are_two_poses(perceiver, inventory, cell):
    """Two bowls nested (at the bowl's nest pitch), leaning 20 deg. The base found both; kept as a guard: with the
    covered surface free wherever it lay, a fit of the lower bowl leaning 10 deg more poked out of the upper bowl
    for free, won, and failed the fine check (surface in front of the seen depth still counts against a pose)."""
    placed = _pile(inventory, cell, 3, 2, inventory[3].nest_pitch, lean=20.0)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    _one_pose_each(inventory, placed, perceiver.perceive(views).poses)
