"""A straight rise out of the sink keeps the arm's own margins (planning.leave.rise_keeping_own_margins).

A lift stopped part-way up (the held plate slipped out) left the tool low in the sink; the recovery's unplanned
straight 8 cm rise from there swung the wrist (link6) within the margin of the forearm (link3): every planner
then refused that start and the run gave up with items left. Hand-made: the arm part-way along a lift from a
grasp low in the sink, the wrist turned towards the forearm."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.leave import rise_keeping_own_margins
from kitchenbot.planning.motion import cartesian_line
from kitchenbot.planning.types import PlanningFailure
from kitchenbot.transforms import trans

# part-way up a lift out of the sink (TCP ~9 cm below the rim), the wrist turned back towards the forearm
Q_STOPPED = np.array([2.6288, -1.0942, 2.0646, 0.2484, 1.3321, 2.5246])


def test_the_premise_a_straight_rise_ends_within_the_margin_of_the_arms_own_links(planner):
    free = planner.world.scene()
    assert free.valid(Q_STOPPED)
    unchecked = free.allowing(free.pair_names)
    Q = cartesian_line(planner.robot, unchecked, Q_STOPPED, trans(0.0, 0.0, 0.08) @ planner.robot.fk_tcp(Q_STOPPED),
                       check_start=False)
    assert not isinstance(Q, PlanningFailure)
    assert ("link3", "link6") in free.colliding_pairs(Q[-1])  # no planner starts from there


def test_the_rise_is_refused_where_it_would_end_within_the_arms_own_margin_and_kept_where_it_does_not(planner):
    assert isinstance(rise_keeping_own_margins(planner, Q_STOPPED, 0.08), PlanningFailure)
    r = rise_keeping_own_margins(planner, Q_STOPPED, 0.02)
    assert not isinstance(r, PlanningFailure)
    traj, q_end = r
    free = planner.world.scene()
    assert free.valid(q_end) and all(free.valid(q) for q in traj.q)
    assert np.isclose(planner.robot.fk_tcp(q_end)[2, 3] - planner.robot.fk_tcp(Q_STOPPED)[2, 3], 0.02, atol=1e-3)
