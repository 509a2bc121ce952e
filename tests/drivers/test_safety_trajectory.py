"""SafetyLimits.check_trajectory checks every waypoint's joints and TCP with forward kinematics vectorised over
the waypoints; the error still names the first bad waypoint, as the one-by-one check did."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.drivers.errors import LimitViolation
from kitchenbot.drivers.ur_kinematics import fk_flange, fk_flange_batch, ur_model
from kitchenbot.executive.config import CellConfig


@pytest.fixture(scope="module")
def setup():
    cfg = CellConfig()
    return cfg.safety_limits(), ur_model(cfg.robot.model), np.asarray(cfg.robot.home, float)


def test_batch_fk_matches_the_single_chain(setup):
    _, model, home = setup
    Q = home + np.random.default_rng(0).uniform(-2, 2, (50, 6))
    np.testing.assert_allclose(fk_flange_batch(model, Q), [fk_flange(model, q) for q in Q], atol=1e-12)


def _slow_line(home, n=200):
    return np.arange(n) * 0.05, home + np.linspace(0.0, 0.2, n)[:, None] * np.ones(6)


def test_a_trajectory_inside_the_limits_passes(setup):
    limits, model, home = setup
    t, Q = _slow_line(home)
    limits.check_trajectory(model, t, Q)


def test_the_first_bad_waypoint_is_named(setup):
    limits, model, home = setup
    t, Q = _slow_line(home)
    Q[150, 2] = 100.0  # outside the joint limits
    Q[120, 1] = np.nan
    with pytest.raises(LimitViolation, match="waypoint 120: joint values must be finite"):
        limits.check_trajectory(model, t, Q)
    Q[120, 1] = Q[119, 1]
    with pytest.raises(LimitViolation, match=r"waypoint 150: joint 2 = 100\.0000 rad is outside"):
        limits.check_trajectory(model, t, Q)


def test_a_waypoint_outside_the_workspace_is_refused(setup):
    limits, model, home = setup
    t, Q = _slow_line(home)
    p = (fk_flange(model, Q[80]) @ limits.T_flange_tcp)[:3, 3]
    lo = limits.workspace.lower.copy()
    lo[2] = p[2] + 0.001  # waypoint 80's TCP is now just below the workspace (the rows before it are not)
    shifted = type(limits.workspace)(lo, limits.workspace.upper)
    lim = type(limits)(**{**limits.__dict__, "workspace": shifted})
    zs = (fk_flange_batch(model, Q) @ limits.T_flange_tcp[:, 3])[:, 2]
    first = int(np.argmax(zs < lo[2]))
    with pytest.raises(LimitViolation, match=rf"waypoint {first} \(TCP\): position .* outside the workspace"):
        lim.check_trajectory(model, t, Q)


def test_a_trajectory_whose_tcp_runs_too_fast_is_refused(setup):
    """The TCP speed limit holds for timed trajectories too (finite differences of the waypoints' TCP), not only
    for linear moves: joint speeds within their limits can still swing the TCP faster than max_tcp_speed."""
    limits, model, home = setup
    n = 60
    Q = home + np.linspace(0.0, 1.0, n)[:, None] * np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # the base turns
    t = np.linspace(0.0, 1.0, n)  # 1 rad/s: within the joint speed limit, and the accelerations are 0
    p = (fk_flange_batch(model, Q) @ limits.T_flange_tcp[:, 3])[:, :3]
    tcp_speed = float(np.max(np.linalg.norm(np.diff(p, axis=0), axis=1) / np.diff(t)))
    slower = type(limits)(**{**limits.__dict__, "max_tcp_speed": 0.8 * tcp_speed})
    with pytest.raises(LimitViolation, match=r"trajectory segment \d+: TCP speed .* m/s exceeds"):
        slower.check_trajectory(model, t, Q)
    slower.check_trajectory(model, t * 1.3, Q)  # the same path 30 % slower passes
    type(limits)(**{**limits.__dict__, "max_tcp_speed": 1.01 * tcp_speed}).check_trajectory(model, t, Q)
