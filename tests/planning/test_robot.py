"""Robot model: Pinocchio FK against the numpy DH code, IK round trips, wrapping, unreachable targets."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.drivers.ur_kinematics import UR_MODELS, fk_flange
from kitchenbot.executive.config import CellConfig
from kitchenbot.planning.robot import RobotModel
from kitchenbot.transforms import trans


@pytest.mark.parametrize("name", sorted(UR_MODELS))
def test_fk_matches_dh_table(name):
    cfg = CellConfig.model_validate({"robot": {"model": name}})
    robot = RobotModel.from_config(cfg)
    rng = np.random.default_rng(1)
    for _ in range(50):
        q = rng.uniform(-np.pi, np.pi, 6)
        np.testing.assert_allclose(robot.fk(q, "flange"), fk_flange(robot.ur, q), atol=1e-12)
        np.testing.assert_allclose(robot.fk_tcp(q), fk_flange(robot.ur, q) @ robot.T_flange_tcp, atol=1e-12)


def test_ik_round_trips(planner, home):
    robot = planner.robot
    rng = np.random.default_rng(2)
    solved = 0
    for _ in range(100):
        q = home + rng.uniform(-1.0, 1.0, 6)
        q = np.clip(q, robot.lower, robot.upper)
        T = robot.fk_tcp(q)
        res = robot.ik(T, q + rng.uniform(-0.2, 0.2, 6))
        assert res.q is not None, "a pose from FK must be reachable"
        np.testing.assert_allclose(robot.fk_tcp(res.q), T, atol=1e-4)
        assert robot.within_limits(res.q)
        solved += 1
    assert solved == 100


def test_ik_prefers_the_current_branch(planner, home):
    robot = planner.robot
    q = home + np.array([0.2, 0.1, -0.1, 0.1, 0.2, -0.3])
    res = robot.ik(robot.fk_tcp(q), q + 0.05)
    assert np.max(np.abs(res.q - q)) < 1e-3  # the same configuration, not another branch or a 2*pi turn


def test_wrap_near_uses_the_closest_equivalent(planner):
    robot = planner.robot
    q = np.array([3.0, -1.0, 1.0, -1.5, -1.5, -0.1])
    ref = q.copy()
    ref[5] = 2 * np.pi - 0.5
    w = robot.wrap_near(q, ref)
    assert w[5] == pytest.approx(-0.1 + 2 * np.pi)  # a full turn closer to the current configuration
    ref = q.copy()
    ref[5] = 2 * np.pi - 0.5
    q2 = q.copy()
    q2[5] = 0.1
    assert robot.wrap_near(q2, ref)[5] == pytest.approx(0.1)  # 0.1 + 2*pi would leave the +-2*pi limits
    q3 = q.copy()
    q3[2] = -3.0
    ref3 = q.copy()
    ref3[2] = 3.0
    assert robot.wrap_near(q3, ref3)[2] == pytest.approx(-3.0)  # the elbow is limited to +-pi: no wrap


def test_unreachable_pose_has_no_ik(planner, home):
    T = trans(2.0, 0.0, 0.0) @ planner.robot.fk_tcp(home)
    assert planner.robot.ik(T, home).q is None


def test_wrap_near_rows_is_wrap_near_row_by_row(planner):
    """The batched wrap (ik_all, the release-pose cache) gives wrap_near's values row by row (rows do not mix),
    None where it does, and each value is q turned by whole turns into the limits, nearest `ref`."""
    robot = planner.robot
    rng = np.random.default_rng(3)
    Q = rng.uniform(-9.0, 9.0, size=(400, 6))  # outside the limits too: turned in by 2*pi
    for ref in (np.zeros(6), rng.uniform(-3.0, 3.0, 6)):
        rows = robot.wrap_near_rows(Q, ref)
        turned = 0
        for q, got in zip(Q, rows):
            want = robot.wrap_near(q, ref)
            assert (got is None) == (want is None)
            if want is not None:
                assert np.array_equal(got, want)
                turned += not np.array_equal(got, q)
                # what it means, checked on its own: whole turns away from q, inside the limits, nearest ref
                k = (got - q) / (2 * np.pi)
                assert np.allclose(k, np.round(k), atol=1e-9)
                assert np.all(got >= robot.lower - 1e-9) and np.all(got <= robot.upper + 1e-9)
                for d in (-2 * np.pi, 2 * np.pi):
                    other = got + d
                    inside = (other >= robot.lower - 1e-9) & (other <= robot.upper + 1e-9)
                    assert np.all(np.abs(other - ref)[inside] >= np.abs(got - ref)[inside] - 1e-9)
        assert turned > 100


def test_wrap_near_is_wrap_near_rows_bitwise_at_the_edges(planner):
    """wrap_near (Python floats, one row) against wrap_near_rows (numpy): the same values bitwise or None on rows
    built at the edges: half-turn ties (round half to even, the first of equal distances), values at the limits
    and 1e-9 beyond them, references far outside them, tiny offsets."""
    robot = planner.robot
    rng = np.random.default_rng(7)
    lo, hi = robot.lower, robot.upper
    rows, refs = [], []
    for _ in range(600):
        ref = rng.choice([0.0, np.pi, -np.pi, 2 * np.pi, 5.0, -7.5, 20.0], 6) + rng.choice([0.0, 1e-12, -1e-12], 6)
        kind = rng.integers(4)
        if kind == 0:  # half-turn ties: q - ref an odd multiple of pi
            q = ref + np.pi * rng.choice([-3.0, -1.0, 1.0, 3.0], 6)
        elif kind == 1:  # at the limits and just beyond
            q = np.where(rng.random(6) < 0.5, lo, hi) + rng.choice([0.0, 1e-9, -1e-9, 2e-9, -2e-9, 2 * np.pi], 6)
        elif kind == 2:
            q = rng.uniform(-12.0, 12.0, 6)
        else:
            q = ref + rng.normal(0, 1e-9, 6)
        rows.append(q)
        refs.append(ref)
    nones = 0
    for q, ref in zip(rows, refs):
        want = robot.wrap_near_rows(q[None, :], ref)[0]
        got = robot.wrap_near(q, ref)
        assert (got is None) == (want is None), (q, ref)
        if want is None:
            nones += 1
        else:
            assert got.dtype == want.dtype and np.array_equal(got.view(np.int64), want.view(np.int64)), (q, ref)
    assert 0 < nones < len(rows)


def test_ik_all_batch_gives_ik_all_per_pose(planner, home):
    """Grasp selection solves every candidate's IK in one batch (RobotModel.ik_all_batch): per pose the branches
    ik_all gives (the same number, in the same order, each within 1e-9 rad), none for poses out of reach."""
    robot = planner.robot
    rng = np.random.default_rng(11)
    Q = np.clip(home + rng.uniform(-1.5, 1.5, (120, 6)), robot.lower, robot.upper)
    T = np.array([robot.fk_tcp(q) for q in Q] + [trans(2.0, 0.0, 0.0) @ robot.fk_tcp(home)])
    ref = home + rng.uniform(-0.3, 0.3, 6)
    got = robot.ik_all_batch(T, ref)
    assert len(got) == len(T)
    assert got[-1] == [] and robot.ik_all(T[-1], ref) == []
    for Tk, sols in zip(T[:-1], got[:-1]):
        want = robot.ik_all(Tk, ref)
        assert len(sols) == len(want) >= 1
        for a, b in zip(sols, want):
            np.testing.assert_allclose(a, b, atol=1e-9)
    assert robot.ik_all_batch(np.zeros((0, 4, 4)), ref) == []


def test_wrap_round_trip_rows_is_wrap_round_trip_row_by_row(planner):
    """The batched round-trip wrap of grasp selection gives wrap_round_trip's values bitwise, row by row."""
    robot = planner.robot
    rng = np.random.default_rng(12)
    Q = np.clip(rng.uniform(-7.0, 7.0, (300, 6)), robot.lower, robot.upper)
    for ref, rest in ((np.zeros(6), np.zeros(6)), (rng.uniform(-3, 3, 6), rng.uniform(-3, 3, 6))):
        rows = robot.wrap_round_trip_rows(Q, ref, rest)
        for q, got in zip(Q, rows):
            assert np.array_equal(got, robot.wrap_round_trip(q, ref, rest))
