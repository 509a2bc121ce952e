"""The scan waypoints are visited in the order of least joint travel from where the arm is."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.scan_order import travel, visit_order


def test_the_order_of_least_travel_is_chosen():
    W = np.zeros((3, 6))
    W[:, 0] = [0.0, 1.0, -1.0]  # a line of waypoints along joint 0: 0 in the middle
    assert visit_order(np.full(6, 0.0) + [0.9, 0, 0, 0, 0, 0], W) == [1, 0, 2]  # start at the near end
    assert visit_order(np.array([-0.9, 0, 0, 0, 0, 0.0]), W) == [2, 0, 1]
    # from the middle either end costs the same: the configured order breaks the tie
    assert visit_order(np.zeros(6), W) == [0, 1, 2]
    o = visit_order(np.array([0.9, 0, 0, 0, 0, 0.0]), W)
    assert travel(np.array([0.9, 0, 0, 0, 0, 0.0]), tuple(o), W) < travel(np.array([0.9, 0, 0, 0, 0, 0.0]), (0, 1, 2), W)


def test_the_shipped_waypoints_from_home():
    from kitchenbot.executive.config import load_config

    cfg = load_config()
    W = np.asarray(cfg.scan_waypoints, float)
    home = np.asarray(cfg.robot.home, float)
    o = visit_order(home, W)
    assert sorted(o) == [0, 1, 2]
    assert travel(home, tuple(o), W) <= travel(home, (0, 1, 2), W)
