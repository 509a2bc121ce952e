"""Attitudes from poses: upright, inverted, lying / on edge, tilted, with the thresholds named in world.attitude."""

import numpy as np
import pytest

from kitchenbot.transforms import rot_x
from kitchenbot.world.attitude import (
    Attitude,
    attitude,
    faces_down,
    faces_up,
    is_inverted,
    is_level,
    is_lying,
    is_upright,
)


@pytest.mark.parametrize(
    ("tilt_deg", "expected", "up", "down"),
    [
        (0, Attitude.UPRIGHT, True, False),
        (15, Attitude.UPRIGHT, True, False),  # cos 15 deg = 0.966 >= 0.95
        (25, Attitude.TILTED, True, False),  # not level, but its mouth still faces up
        (70, Attitude.TILTED, False, False),  # mouth sideways
        (90, Attitude.LYING, False, False),
        (100, Attitude.LYING, False, False),  # cos 100 deg = -0.17: within 17 deg of horizontal
        (130, Attitude.TILTED, False, True),
        (180, Attitude.INVERTED, False, True),
    ],
)
def test_attitude_of_a_tilted_item(tilt_deg, expected, up, down):
    T = rot_x(np.radians(tilt_deg))
    T[:3, 3] = (0.4, 0.1, -0.1)  # position plays no part
    assert attitude(T) is expected
    assert faces_up(T) is up and faces_down(T) is down
    assert is_level(T) == (is_upright(T) or is_inverted(T))
    assert is_lying(T) == (expected is Attitude.LYING)


def test_a_flat_item_lying_stands_on_edge():
    T = rot_x(np.pi / 2)
    assert attitude(T, flat=True) is Attitude.ON_EDGE and attitude(T) is Attitude.LYING
    assert attitude(np.eye(4), flat=True) is Attitude.UPRIGHT
