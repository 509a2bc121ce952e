"""Views aimed at one spot (a placement, a drop site) are judged by the depth at that spot, not over the image."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.motion import spot_measured as _spot_measured
from kitchenbot.perception.types import View

K = np.array([[400.0, 0, 320], [0, 400.0, 240], [0, 0, 1]])


def _view(depth):
    return View(np.zeros((*depth.shape, 3), np.uint8), depth.astype(np.float32), K, np.eye(4))


def test_spot_measured_looks_at_the_window_around_the_projection():
    depth = np.zeros((480, 640))
    depth[200:280, 280:360] = 0.6  # only the middle has depth: 2 % of the image
    v = _view(depth)
    assert _spot_measured(v, np.array([0.0, 0.0, 0.6])) == 1.0  # projects to (320, 240)
    assert _spot_measured(v, np.array([0.3, 0.2, 0.6])) == 0.0  # projects to (520, 373): no depth there
    assert _spot_measured(v, np.array([0.0, 0.0, -0.5])) == 0.0  # behind the camera
    assert _spot_measured(v, np.array([5.0, 0.0, 0.6])) == 0.0  # outside the image

