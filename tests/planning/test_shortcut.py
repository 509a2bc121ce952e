"""RRT-Connect paths shortened for the arm's time along them (planning/shortcut.py): shorter, still free, within
the limits; the same inputs give the same path."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.planning.collision import tcp_positions
from kitchenbot.planning.fcl_check import FclChecker, verify_place
from kitchenbot.planning.motion import check_segment, reach_bounds
from kitchenbot.planning.shortcut import path_time_estimate, shortcut_path
from kitchenbot.planning.types import PickPlan, PlacePlan

VMAX = np.full(6, 1.5)


def _planar_tcp(Q: np.ndarray) -> np.ndarray:
    """A stand-in 'TCP' for the pure tests: the first two joints as a point in the plane (m per rad)."""
    Q = np.asarray(Q, float)
    return np.column_stack([Q[:, 0], Q[:, 1], np.zeros(len(Q))])


def _free_of_box(lo: np.ndarray, hi: np.ndarray):
    """is_free for segments that must not enter the box lo..hi of the first two joints (checked every 1 mrad)."""
    calls = []

    def is_free(P: np.ndarray) -> bool:
        calls.append(P.copy())
        for a, b in zip(P[:-1], P[1:]):
            n = max(2, int(np.ceil(np.max(np.abs(b - a)) / 1e-3)))
            S = a + np.linspace(0, 1, n + 1)[:, None] * (b - a)
            inside = np.all((S[:, :2] > lo) & (S[:, :2] < hi), axis=1)
            if inside.any():
                return False
        return True

    return is_free, calls


def test_a_detour_round_an_obstacle_is_cut_short_and_stays_clear():
    # a wandering path from (0, 0) to (2, 0) round a box at x 0.8..1.2, y -0.5..0.5: over it, out and back
    Q = np.zeros((7, 6))
    Q[:, :2] = [[0, 0], [0.3, 0.9], [0.9, 1.4], [1.0, 0.7], [1.1, 1.5], [1.7, 0.9], [2.0, 0.0]]
    lo, hi = np.array([0.8, -0.5]), np.array([1.2, 0.5])
    is_free, _ = _free_of_box(lo, hi)
    assert is_free(Q) and not is_free(Q[[0, -1]])  # the given path is free, the straight line is not
    P = shortcut_path(Q, is_free, VMAX, 0.5, _planar_tcp, rounds=40, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(P[0], Q[0])
    np.testing.assert_array_equal(P[-1], Q[-1])
    assert is_free(P)  # every segment of the result, not only the new ones
    before, after = path_time_estimate(Q, VMAX, 0.5, _planar_tcp), path_time_estimate(P, VMAX, 0.5, _planar_tcp)
    assert after < 0.8 * before, (before, after)
    # the same draws give the same path
    again = shortcut_path(Q, is_free, VMAX, 0.5, _planar_tcp, rounds=40, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(P, again)


def test_no_shortcut_where_every_cut_collides():
    # a path hugging a box's corner at its single vertex: no cut is free, the path comes back unchanged
    Q = np.zeros((3, 6))
    Q[:, :2] = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0]]
    is_free, calls = _free_of_box(np.array([-1.0, -1.0]), np.array([0.999, 0.999]))
    P = shortcut_path(Q, is_free, VMAX, 0.5, _planar_tcp, rounds=20, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(P, Q)
    assert calls  # cuts were tried (and refused by the check)


def test_path_time_estimate_counts_the_slowest_joint_and_the_tcp():
    Q = np.zeros((2, 6))
    Q[1, 0] = 0.3  # 0.2 s for the joint at 1.5 rad/s; the planar TCP travels 0.3 m: 0.6 s at 0.5 m/s
    assert path_time_estimate(Q, VMAX, 0.5, _planar_tcp) == pytest.approx(0.6)
    assert path_time_estimate(Q, VMAX, 5.0, _planar_tcp) == pytest.approx(0.2)


def test_a_transfer_to_the_rack_is_shortened_free_and_within_limits(planner, home, cup_for_the_upper_rack):
    # an upside-down cup carried from the sink (a plate beside it) into the upper rack: the transfer's straight
    # joint line collides, so it is an RRT-Connect path; its shortcut is faster, free and within every limit
    cup, objs, targets = cup_for_the_upper_rack
    pick = planner.plan_pick(home, objs, target=cup, place_target=targets)
    assert isinstance(pick, PickPlan), pick
    rounds = planner.settings.shortcut_rounds
    assert rounds > 0  # shipped on
    try:
        planner.settings.shortcut_rounds = 0
        plain = planner.plan_place(pick.end, pick.grasp, targets, objects=objs)
    finally:
        planner.settings.shortcut_rounds = rounds
    place = planner.plan_place(pick.end, pick.grasp, targets, objects=objs)
    assert isinstance(plain, PlacePlan) and isinstance(place, PlacePlan), (plain, place)
    np.testing.assert_allclose(place.transfer.q[0], plain.transfer.q[0])
    np.testing.assert_allclose(place.transfer.q[-1], plain.transfer.q[-1])
    assert place.transfer.duration < 0.8 * plain.transfer.duration, (plain.transfer.duration, place.transfer.duration)
    for t in place.trajectories:
        planner.limits.check_trajectory(planner.robot.ur, t.times, t.q)
    # free in the planner's own scene at its dense resolution, and by the independent python-fcl checker
    scene = planner.scene(objs, None, exclude=cup, held=pick.grasp, own=[cup])
    assert check_segment(scene, place.transfer.q, reach_bounds(scene), planner.settings.validity_resolution) < 0
    checker = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
    for name, r in verify_place(checker, planner, place, pick.grasp, objs, step=0.004):
        assert r.ok, (name, str(r))
    # the TCP's path is shorter too
    def tcp_length(q):
        return float(np.sum(np.linalg.norm(np.diff(tcp_positions(planner.robot, q), axis=0), axis=1)))
    assert tcp_length(place.transfer.q) < tcp_length(plain.transfer.q)
