"""Settled stacks: the item nested under another shows only a peeking rim, within 1.5 voxels of the upper item's
surface, so it is found only by re-fitting what the upper pose leaves over at the tight tolerance."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.metrics import adi
from kitchenbot.perception.pipeline import Perceiver
from kitchenbot.perception.settings import PerceptionSettings
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


def test_loose_residual_tolerance_misses_the_lower_plate(inventory, cell, stack, perceiver):
    """The same scan re-fitting only what is over 1.5 voxels away (the old behaviour) finds one plate: the test
    above exercises the tight re-fit, not an easy case."""
    loose = Perceiver(PerceptionSettings(cache_dir=perceiver.settings.cache_dir, residual_tolerance=1.5), inventory,
                      cell, database=perceiver.database)
    views, _ = render(inventory, stack, scan_poses(cell), cell, noise=0.002)
    r = loose.perceive(views)
    assert len([po for po in r.poses if po.obj_id == 2]) == 1


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


@pytest.mark.xfail(strict=True, reason="known: the dinner plate is fitted twice, 5 mm apart along its axis (a "
                   "compromise fit of both plates, then the plate's peeking rim re-fitted): as far apart as two "
                   "stacked dinner plates, so neither the twin nor the stacked-copy test merges them")
def test_plate_under_a_plate_of_another_model_is_fitted_once(perceiver, inventory, cell, side_in_dinner):
    views, _ = render(inventory, side_in_dinner, scan_poses(cell), cell, noise=0.002)
    r = perceiver.perceive(views)
    assert sorted(po.obj_id for po in r.poses) == [1, 2]
