"""A nest of plates of one model: the lower plates show only a thin band of their rims' outer edges, a few
millimetres under the rim above, which the top plate's pose explains at the splitting tolerance. Each nest level
the data supports is counted (perception/nest.py); a plate with nothing under it gets no level."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from kitchenbot.perception.metrics import adi
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses
from kitchenbot.transforms import make_T

SIDE_PLATE, DINNER_PLATE = 2, 1


def _tilt_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return make_T(np.array([[1.0, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]), np.zeros(3))


def _nest(inventory, cell, oid: int, n: int, tilt_deg: float, pitch: float, x: float, y: float,
          yaw: float) -> list[tuple[int, np.ndarray]]:
    """`n` copies of model `oid` leaning `tilt_deg`, `pitch` apart along their axis (a settled nest sits a little
    looser than the model's nest pitch), the lowest one's lowest point 1 mm over the sink floor."""
    base = resting_pose(inventory, oid, x, y, yaw, cell)
    T0 = base @ _tilt_x(tilt_deg)
    pts = inventory[oid].points

    def low(T):
        return (pts @ T[:3, :3].T + T[:3, 3])[:, 2].min()

    T0[2, 3] += low(base) - low(T0) + 0.001
    out = []
    for k in range(n):
        T = T0.copy()
        T[:3, 3] += k * pitch * T0[:3, 2]
        out.append((oid, T))
    return out


def _matched(inventory, placed, poses) -> int:
    """Ground-truth items matched one-to-one by an estimate of their model within 0.1 diameter (ADI)."""
    E = np.full((len(placed), max(1, len(poses))), np.inf)
    for i, (oid, T) in enumerate(placed):
        for j, po in enumerate(poses):
            if po.obj_id == oid:
                E[i, j] = adi(po.T_base_obj, T, inventory[oid].points) / inventory[oid].diameter
    E = np.where(np.isfinite(E), E, 9.0)
    r, c = linear_sum_assignment(E)
    return int((E[r, c] < 0.1).sum())


@pytest.mark.parametrize("tilt_deg", [32.0, 8.0])
def test_every_plate_of_a_nest_of_four_is_found(perceiver, inventory, cell, tilt_deg):
    """Four side plates 6.5 mm apart along their axis (the model's nest pitch is 5 mm), leaning 32 deg (a nest
    against a basin wall) or 8 deg. Before: one pose for the four (the lower rims, 1-10 % visible, explained by the
    top plate's pose)."""
    placed = _nest(inventory, cell, SIDE_PLATE, 4, tilt_deg, 0.0065, 0.50, 0.0, 0.3)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    r = perceiver.perceive(views)
    plates = [po for po in r.poses if po.obj_id == SIDE_PLATE]
    assert _matched(inventory, placed, r.poses) == 4, f"{len(plates)} side plate poses for a nest of 4"
    assert len(r.poses) == 4, [inventory[po.obj_id].name for po in r.poses]


def test_plates_alone_get_no_level_under_them(perceiver, inventory, cell):
    """A side plate lying flat and a dinner plate leaning 25 deg, each alone: one pose each, nothing under them
    (a level under a plate with nothing under it would stand where the cameras see through it, or in the floor)."""
    placed = _nest(inventory, cell, SIDE_PLATE, 1, 0.0, 0.0, 0.50, 0.0, 0.3) + \
        _nest(inventory, cell, DINNER_PLATE, 1, 25.0, 0.0, 0.40, 0.12, 0.0)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    r = perceiver.perceive(views)
    assert _matched(inventory, placed, r.poses) == 2
    assert len(r.poses) == 2, [inventory[po.obj_id].name for po in r.poses]
