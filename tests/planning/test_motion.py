"""Motion: a 5 mm wall cannot be passed through, planned paths re-check clean (coal dense + independent FCL),
timing stays within the safety limits, typed failures for colliding start/goal."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.planning.fcl_check import FclChecker
from kitchenbot.planning.motion import (
    cartesian_line,
    check_segment,
    densify,
    plan_joint_path,
    point_step,
    reach_bounds,
)
from kitchenbot.planning.timing import time_parameterise
from kitchenbot.planning.types import GoalInCollision, StartInCollision
from kitchenbot.transforms import make_T, trans
from kitchenbot.world.cell import Box


def _q_at(planner, home, xyz):
    T = make_T(np.diag([1.0, -1.0, -1.0]), xyz)  # TCP pointing down
    q = planner.robot.ik_q(T, home)
    assert q is not None
    return q


@pytest.fixture(scope="module")
def wall_case(planner, home):
    """Two TCP positions above the counter on either side of a 5 mm wall between them."""
    qa = _q_at(planner, home, (0.45, 0.30, 0.25))
    qb = _q_at(planner, home, (0.45, -0.10, 0.25))
    wall = Box("thin_wall", "wall", np.array([0.15, 0.1, 0.0]), np.array([0.80, 0.105, 0.45]), (1.0, 0.0, 0.0))
    scene = planner.world.scene(boxes=[wall])
    return qa, qb, wall, scene


def test_straight_line_through_the_wall_is_rejected(planner, wall_case):
    qa, qb, wall, scene = wall_case
    assert scene.valid(qa) and scene.valid(qb)
    r = reach_bounds(scene)
    # the straight joint line passes through the wall: the planner's resolution and the dense check see it
    assert check_segment(scene, np.vstack([qa, qb]), r, planner.planning_resolution) >= 0
    assert check_segment(scene, np.vstack([qa, qb]), r, 0.004) >= 0
    # ... and so does the independent checker
    chk = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
    assert not chk.check_path(np.vstack([qa, qb]), boxes=[wall], step=0.004).ok


def test_planned_path_goes_around_the_wall(planner, wall_case):
    qa, qb, wall, scene = wall_case
    res = plan_joint_path(scene, qa, qb, planning_resolution=planner.planning_resolution, max_iterations=2000, seed=0)
    assert not hasattr(res, "kind"), res
    path = res.path
    np.testing.assert_allclose(path[0], qa)
    np.testing.assert_allclose(path[-1], qb)
    r = reach_bounds(scene)
    assert check_segment(scene, path, r, 0.004) < 0
    chk = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
    res_fcl = chk.check_path(path, boxes=[wall], step=0.003)
    assert res_fcl.ok, str(res_fcl)


def test_reach_bounds_bound_the_point_travel(planner, home):
    """No geometry point moves farther than sum_j r_j |dq_j| (checked on the capsule end points and TCP)."""
    scene = planner.world.scene()
    r = reach_bounds(scene)
    rng = np.random.default_rng(6)
    for _ in range(50):
        q0 = home + rng.uniform(-1, 1, 6)
        dq = rng.uniform(-0.05, 0.05, 6)
        P0, P1 = scene.placements(q0), scene.placements(q0 + dq)
        moved = max(np.linalg.norm(P0[k][:3, 3] - P1[k][:3, 3]) for k in P0)
        moved = max(moved, np.linalg.norm(planner.robot.fk_tcp(q0)[:3, 3] - planner.robot.fk_tcp(q0 + dq)[:3, 3]))
        assert moved <= point_step(r, dq) + 1e-9
    Q = densify(np.vstack([home, home + 0.5]), r, 0.004)
    assert max(point_step(r, b - a) for a, b in zip(Q[:-1], Q[1:])) <= 0.004 + 1e-12


def test_colliding_start_and_goal_are_typed_failures(planner, home):
    scene = planner.world.scene()
    bad = home.copy()
    bad[2] = 3.1  # folded elbow
    assert isinstance(plan_joint_path(scene, bad, home), StartInCollision)
    assert isinstance(plan_joint_path(scene, home, bad), GoalInCollision)


def test_timing_within_safety_limits(planner, home):
    Q = np.vstack([home, home + [0.6, -0.2, 0.3, 0.1, 0.4, -1.0], home + [0.2, 0.1, 0.0, 0.0, 0.0, 0.5]])
    line = cartesian_line(planner.robot, planner.world.scene(), home, trans(0.0, 0.0, -0.1) @ planner.robot.fk_tcp(home))
    assert not hasattr(line, "kind"), line
    for mode, P in (("stop_at_vertices", Q), ("along_path", line), ("along_path", Q)):
        traj = time_parameterise(P, planner.limits, planner.robot.ur, mode=mode)
        planner.limits.check_trajectory(planner.robot.ur, traj.times, traj.q)  # raises on a violation
        np.testing.assert_allclose(traj.q[0], P[0])
        np.testing.assert_allclose(traj.q[-1], P[-1])
    traj = time_parameterise(Q, planner.limits, planner.robot.ur, mode="stop_at_vertices")
    for v in Q:  # every vertex is a sample: linear interpolation never leaves the checked polyline
        assert np.min(np.max(np.abs(traj.q - v), axis=1)) < 1e-12
    # faster limits give a shorter trajectory; the joint speed limit is reached but not exceeded
    vel = np.abs(np.diff(traj.q, axis=0) / np.diff(traj.times)[:, None])
    assert vel.max() <= planner.limits.max_joint_speed.max() * 1.02


def test_a_work_budget_and_seed_make_a_plan_independent_of_load_and_history(planner, wall_case):
    qa, qb, wall, scene = wall_case
    kw = dict(planning_resolution=planner.planning_resolution, max_iterations=2000, seed=3)
    first = plan_joint_path(scene, qa, qb, **kw)
    assert not hasattr(first, "kind"), first
    plan_joint_path(scene, qb, qa, planning_resolution=planner.planning_resolution, max_iterations=2000, seed=11)
    again = plan_joint_path(scene, qa, qb, **kw)  # another query (other samples drawn) in between
    np.testing.assert_array_equal(first.path, again.path)


def test_an_exhausted_iteration_budget_is_a_planner_timeout_naming_it(planner, wall_case):
    from kitchenbot.planning.types import InvalidInput, PlannerTimeout

    qa, qb, wall, scene = wall_case
    fails = [plan_joint_path(scene, qa, qb, planning_resolution=planner.planning_resolution, max_iterations=1, seed=s)
             for s in range(4)]
    failed = [f for f in fails if isinstance(f, PlannerTimeout)]
    assert failed and all("in 1 iterations" in str(f) for f in failed)
    assert isinstance(plan_joint_path(scene, qa, qb, max_iterations=0), InvalidInput)


def test_planner_work_budget_settings_come_from_the_config_or_the_environment(monkeypatch):
    from pydantic import ValidationError

    from kitchenbot.planning.settings import PlanningSettings

    monkeypatch.setenv("KITCHENBOT_PLANNER_MAX_ITERATIONS", "300")
    monkeypatch.setenv("KITCHENBOT_PLANNER_SEED", "4")
    s = PlanningSettings()
    assert (s.planner_max_iterations, s.planner_seed) == (300, 4)
    assert PlanningSettings(planner_max_iterations=50).planner_max_iterations == 50  # the config file wins
    monkeypatch.delenv("KITCHENBOT_PLANNER_MAX_ITERATIONS")
    monkeypatch.delenv("KITCHENBOT_PLANNER_SEED")
    assert PlanningSettings().planner_max_iterations is None  # default: the wall-clock budget
    with pytest.raises(ValidationError, match="planner_max_iterations"):
        PlanningSettings(planner_max_iterations=0)
    monkeypatch.setenv("KITCHENBOT_PLANNER_SEED", "soon")
    with pytest.raises(ValueError, match="KITCHENBOT_PLANNER_SEED='soon': expected an integer"):
        PlanningSettings()


def test_blended_timing_passes_vertices_without_stopping_only_where_proven_free(planner, home):
    """mode="blended": faster than stopping at each vertex, within the limits, at rest at both ends; the caller's
    collision proof decides, and without it the vertices are stopped at (the checked polyline)."""
    Q = np.vstack([home, home + [0.6, -0.2, 0.3, 0.1, 0.4, -1.0], home + [0.2, 0.1, 0.0, 0.0, 0.0, 0.5],
                   home + [-0.3, 0.1, 0.2, 0.0, 0.3, 0.2]])
    kw = dict(velocity_scale=0.5, acceleration_scale=0.5)
    stop = time_parameterise(Q, planner.limits, planner.robot.ur, mode="stop_at_vertices", **kw)
    seen = []

    def free(q):
        seen.append(q)
        return True

    blend = time_parameterise(Q, planner.limits, planner.robot.ur, mode="blended", free=free, **kw)
    assert len(seen) == 1 and seen[0] is blend.q  # the proof was asked for exactly the path returned
    planner.limits.check_trajectory(planner.robot.ur, blend.times, blend.q)
    assert blend.duration < 0.9 * stop.duration
    np.testing.assert_allclose(blend.q[0], Q[0])
    np.testing.assert_allclose(blend.q[-1], Q[-1])
    vmax = planner.limits.max_joint_speed * 0.5
    vel = np.diff(blend.q, axis=0) / np.diff(blend.times)[:, None]
    assert np.all(np.abs(vel) <= vmax * 1.001)
    assert np.abs(vel[0]).max() < 0.05 and np.abs(vel[-1]).max() < 0.05  # at rest at both ends
    # the blend leaves the polyline near the inner vertices (the reason for the proof) ...
    assert np.min(np.max(np.abs(blend.q - Q[1]), axis=1)) > 1e-3
    # ... and when the proof fails, the trajectory stops at every vertex, as the polyline was checked
    refused = time_parameterise(Q, planner.limits, planner.robot.ur, mode="blended", free=lambda q: False, **kw)
    np.testing.assert_array_equal(refused.q, stop.q)
    with pytest.raises(ValueError, match="free="):
        time_parameterise(Q, planner.limits, planner.robot.ur, mode="blended")


def test_planned_transfers_blend_only_along_a_free_path(planner, wall_case):
    """Around the wall: the planner's path blended where the dense re-check passes on the blended samples."""
    qa, qb, wall, scene = wall_case
    timings: dict = {}
    traj = planner._joint_motion(scene, qa, qb, "move", timings)
    assert not hasattr(traj, "kind"), traj
    r = reach_bounds(scene)
    assert check_segment(scene, traj.q, r, 0.004) < 0  # what is executed is free, blended or not
    assert timings["move_blended"] in (0.0, 1.0)


def test_straight_lines_use_more_of_the_acceleration_within_the_scaled_limits(planner, home):
    """A short Cartesian line (an approach, a lift) is timed with more of the scaled acceleration than the half
    share kept for curvature, only where its finite differences stay within the scaled limits."""
    from kitchenbot.planning.timing import along_path, within

    line = cartesian_line(planner.robot, planner.world.scene(), home, trans(0.0, 0.0, -0.1) @ planner.robot.fk_tcp(home))
    assert not hasattr(line, "kind"), line
    vmax, amax = planner.limits.max_joint_speed * 0.5, planner.limits.max_joint_accel * 0.5
    half_t, _ = along_path(line, vmax, amax, accel_share=0.5)
    traj = time_parameterise(line, planner.limits, planner.robot.ur, velocity_scale=0.5, acceleration_scale=0.5,
                             mode="along_path")
    assert traj.duration < 0.9 * half_t[-1]
    assert within(traj.times, traj.q, vmax, amax)
    planner.limits.check_trajectory(planner.robot.ur, traj.times, traj.q)
    np.testing.assert_allclose(traj.q[-1], line[-1])
    # a share that the path's curvature would push over the scaled limits is not kept
    full_t, full_q = along_path(line, vmax, amax, accel_share=1.0)
    assert not within(full_t, full_q, vmax, amax) or traj.duration <= full_t[-1] + 1e-9
def test_a_work_budget_grows_with_the_time_budget(planner, home, monkeypatch):
    """With max_iterations set (repeatable searches), a move planned again after a timeout gets more iterations,
    not the same search again."""
    import kitchenbot.planning.pick_place as pp

    seen = []
    real = pp.plan_joint_path

    def spy(*a, **kw):
        seen.append(kw["max_iterations"])
        return real(*a, **kw)

    monkeypatch.setattr(pp, "plan_joint_path", spy)
    monkeypatch.setattr(planner.settings, "planner_max_iterations", 200)
    q1 = home + np.array([0.4, 0.0, 0.0, 0.0, 0.0, 0.0])
    planner.plan_move(home, q1)
    planner.plan_move(home, q1, timeout_scale=4.0)
    assert seen == [200, 800]


def test_timing_keeps_the_tcp_within_its_speed_limit(planner, home):
    """A base turn at the full joint speed would swing the TCP faster than max_tcp_speed: every profile slows
    down for it (a stop-at-vertices segment on its own), and a slow segment keeps its joint-limited pace."""
    from kitchenbot.planning.timing import stop_at_vertices, tcp_speed_ratio

    lim, ur = planner.limits, planner.robot.ur
    turn = home + np.array([1.2, 0.0, 0.0, 0.0, 0.0, 0.0])  # the base: the TCP far from its axis moves fast
    wrist = turn + np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])  # the last wrist joint: the TCP hardly moves
    Q = np.vstack([home, turn, wrist])
    t_raw, q_raw = stop_at_vertices(Q, lim.max_joint_speed, lim.max_joint_accel)
    assert tcp_speed_ratio(lim, ur, t_raw, q_raw) > 1.1  # too fast without the TCP limit
    for mode in ("stop_at_vertices", "along_path", "blended"):
        traj = time_parameterise(Q, lim, ur, mode=mode, free=lambda q: True)
        lim.check_trajectory(ur, traj.times, traj.q)
        assert tcp_speed_ratio(lim, ur, traj.times, traj.q) <= 1.02
        np.testing.assert_allclose(traj.q[-1], Q[-1])
    stop = time_parameterise(Q, lim, ur, mode="stop_at_vertices")
    # the wrist segment is not slowed with the base turn: it lasts as long as its own joint limits make it
    k = int(np.argmin(np.max(np.abs(stop.q - turn), axis=1)))
    t_wrist, _ = stop_at_vertices(Q[1:], lim.max_joint_speed, lim.max_joint_accel)
    assert stop.duration - stop.times[k] == pytest.approx(t_wrist[-1], abs=0.02)


def test_a_two_leg_line_is_timed_through_its_corner_without_stopping_at_every_sample(planner, home):
    """A lift in two straight legs (level, then up) is one dense polyline with a corner: one trapezoid cannot take
    the corner within the limits, and stopping at each of its many vertices is slow. The path speed varying along
    the path (planning/path_speed.py) slows down for the corner only; the samples stay on the polyline."""
    from kitchenbot.planning.path_speed import path_speed_profile
    from kitchenbot.planning.timing import stop_at_vertices, tcp_speed_ratio, within

    lim, ur, sc = planner.limits, planner.robot.ur, planner.world.scene()
    leg1 = cartesian_line(planner.robot, sc, home, trans(0.05, 0.0, 0.0) @ planner.robot.fk_tcp(home))
    leg2 = cartesian_line(planner.robot, sc, leg1[-1], trans(0.0, 0.0, 0.15) @ planner.robot.fk_tcp(leg1[-1]))
    assert not hasattr(leg1, "kind") and not hasattr(leg2, "kind")
    Q = np.vstack([leg1, leg2[1:]])
    traj = time_parameterise(Q, lim, ur, mode="along_path")
    lim.check_trajectory(ur, traj.times, traj.q)
    assert within(traj.times, traj.q, lim.max_joint_speed, lim.max_joint_accel)
    assert tcp_speed_ratio(lim, ur, traj.times, traj.q) <= 1.02
    t_stop, _ = stop_at_vertices(Q, lim.max_joint_speed, lim.max_joint_accel)
    assert traj.duration < 0.5 * t_stop[-1]
    # every sample lies on the polyline: on the segment between two consecutive vertices
    t, q = path_speed_profile(Q, lim.max_joint_speed, lim.max_joint_accel, 0.008)
    D = np.diff(Q, axis=0)
    for x in q[:: max(1, len(q) // 25)]:
        f = np.clip(np.einsum("ij,ij->i", x - Q[:-1], D) / np.maximum(np.einsum("ij,ij->i", D, D), 1e-300), 0, 1)
        assert np.min(np.linalg.norm(Q[:-1] + f[:, None] * D - x, axis=1)) < 1e-9
    np.testing.assert_allclose(q[0], Q[0])
    np.testing.assert_allclose(q[-1], Q[-1])


def test_blended_timing_slows_for_the_tcp_only_the_segments_that_swing_it_fast(planner, home):
    """A base turn (the TCP far from the axis: held by the TCP speed limit) then a wrist turn (the TCP hardly
    moves): the blended profile slows the base turn's segment for the TCP, not the wrist's, so the whole is
    faster than one profile slowed as a whole, within every limit, the TCP's included."""
    from kitchenbot.planning.timing import blended, segment_tcp_times, tcp_speed_ratio

    lim, ur = planner.limits, planner.robot.ur
    vmax, amax = lim.max_joint_speed, lim.max_joint_accel
    reach = home + np.array([0.0, 0.5, -0.8, 0.0, 0.0, 0.0])  # the arm stretched out
    turn = reach + np.array([1.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    mid = turn + np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.5])
    Q = np.vstack([reach, turn, mid, mid + np.array([0.0, 0.0, 0.0, 0.0, 0.3, 1.5])])
    t_raw, q_raw = blended(Q, vmax, amax)
    whole = tcp_speed_ratio(lim, ur, t_raw, q_raw)
    assert whole > 1.5  # the base turn at full joint speed swings the TCP too fast
    seg = segment_tcp_times(Q, lim, ur)
    assert seg[0] > 1.5 * np.max(np.abs(Q[1] - Q[0]) / vmax)  # held by the TCP
    assert seg[1] < np.max(np.abs(Q[2] - Q[1]) / vmax)  # the wrist's turn: by its joint
    traj = time_parameterise(Q, lim, ur, mode="blended", free=lambda q: True)
    lim.check_trajectory(ur, traj.times, traj.q)
    assert tcp_speed_ratio(lim, ur, traj.times, traj.q) <= 1.02
    np.testing.assert_allclose(traj.q[-1], Q[-1])
    assert traj.duration < 0.75 * t_raw[-1] * whole  # faster than the whole slowed by the base turn's ratio
    # the wrist's segments keep their joint-limited pace: some joint runs at (nearly) its full speed there
    vel = np.abs(np.diff(traj.q, axis=0)) / np.diff(traj.times)[:, None]
    assert np.max(vel[:, 5]) > 0.95 * vmax[5]


def test_the_tcp_limit_slows_a_motion_only_where_the_tcp_runs_fast(planner, home):
    """One joint segment from the arm folded (the TCP near the base axis: slow) to stretched out while the base
    turns (the TCP far out: too fast at the joints' full speed). The time warp slows the stretched end only:
    the same samples (so the same checked path), later times, within every limit, the TCP's included, and
    faster than the segment slowed as a whole by its peak TCP speed."""
    from kitchenbot.planning.timing import stop_at_vertices, tcp_speed_ratio, tcp_warped, within

    lim, ur = planner.limits, planner.robot.ur
    vmax, amax = lim.max_joint_speed, lim.max_joint_accel
    folded = home + np.array([0.0, -0.3, 1.0, 0.0, 0.0, 0.0])
    stretched = home + np.array([1.5, 0.5, -0.8, 0.0, 0.0, 0.0])
    Q = np.vstack([folded, stretched])

    def ratio(t, q):
        return tcp_speed_ratio(lim, ur, t, q)

    t_raw, q_raw = stop_at_vertices(Q, vmax, amax)
    assert ratio(t_raw, q_raw) > 1.3  # too fast at the joints' full speed
    t_whole, q_whole = stop_at_vertices(Q, vmax, amax, tcp_ratio=ratio)  # the segment slowed as a whole
    t_w = tcp_warped(t_raw, q_raw, vmax, amax, lim, ur)
    assert ratio(t_w, q_raw) <= 1.0
    assert within(t_w, q_raw, vmax, amax)
    lim.check_trajectory(ur, t_w, q_raw)
    assert t_w[-1] < 0.92 * t_whole[-1]
    # slowed more where it runs fast: the stretched end more than the folded start (not uniformly), never sped up
    slowed = np.diff(t_w) / np.diff(t_raw)
    assert slowed[0] < 0.85 * slowed[-1]
    assert np.all(slowed >= 1.0 - 1e-12)
    traj = time_parameterise(Q, lim, ur, mode="stop_at_vertices")  # the warp, or faster (test_segment_speed.py)
    assert traj.duration <= t_w[-1] + 1e-9


def test_the_batched_motion_check_answers_as_ompls_discrete_check(planner, wall_case):
    """RRT-Connect's motion check in one batch (`_BatchMotionValidator`): the same answer as OMPL's own
    DiscreteMotionValidator calling the per-state checker, on motions that cross the wall, graze it or stay
    clear, and the same interpolated states (bitwise) as the state space's interpolate."""
    from ompl import base as ob

    from kitchenbot.planning.motion import _BatchMotionValidator, _bisection_order

    qa, qb, wall, scene = wall_case
    r = reach_bounds(scene)
    space = ob.RealVectorStateSpace(6)
    bounds = ob.RealVectorBounds(6)
    for i in range(6):
        bounds.setLow(i, float(planner.robot.lower[i]))
        bounds.setHigh(i, float(planner.robot.upper[i]))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)
    si.setStateValidityChecker(lambda s: scene.valid(np.array([s[i] for i in range(6)])))
    si.setStateValidityCheckingResolution(planner.planning_resolution / float(np.linalg.norm(r)) / space.getMaximumExtent())
    si.setup()
    ours = _BatchMotionValidator(si, space, scene)
    rng = np.random.default_rng(0)
    s1, s2, out = space.allocState(), space.allocState(), space.allocState()
    answers = []
    for _ in range(60):
        a = qa + rng.normal(0, 0.05, 6)
        b = (qb if rng.random() < 0.5 else qa) + rng.normal(0, 0.3, 6)
        if not scene.valid(a):
            continue
        for i in range(6):
            s1[i], s2[i] = float(a[i]), float(b[i])
        theirs = si.checkMotion(s1, s2)  # OMPL's DiscreteMotionValidator (the default)
        assert ours.checkMotion(s1, s2) == theirs
        answers.append(theirs)
        nd = int(space.validSegmentCount(s1, s2))
        t = _bisection_order(nd)
        assert sorted(np.round(t * nd).astype(int).tolist()) == list(range(1, nd + 1))
        for tk in t[1:4]:
            space.interpolate(s1, s2, float(tk), out)
            np.testing.assert_array_equal(np.array([out[i] for i in range(6)]), a + (b - a) * tk)
    assert 10 <= sum(answers) <= len(answers) - 10  # both answers were asked


def test_all_valid_is_valid_batch_all(planner, wall_case):
    qa, qb, wall, scene = wall_case
    rng = np.random.default_rng(1)
    grasp = scene.for_grasp(None)
    for sc in (scene, grasp):
        for _ in range(20):
            Q = qa + (qb - qa) * rng.random((rng.integers(1, 40), 1)) + rng.normal(0, 0.05, 6)
            assert sc.all_valid(Q) == bool(sc.valid_batch(Q).all())
            v = sc.valid_batch(Q)  # first_invalid's batches stop at the first collision: the same first row
            assert sc.first_invalid(Q, chunk=7) == (-1 if v.all() else int(np.argmin(v)))


def test_a_straight_lines_ik_is_kept_and_each_scene_still_checks_it(planner, wall_case, monkeypatch):
    """The IK polyline of a straight line is solved once and reused in another scene (a retreat asked once per
    gripper opening): each scene's answer is the one a fresh solve gives, and a failure handed out can be
    renamed by its caller without changing the kept one."""
    import kitchenbot.planning.motion as motion

    qa, qb, wall, scene = wall_case
    free = planner.world.scene()
    T_b = planner.robot.fk_tcp(qb)
    calls = []
    solve = motion._solve_line_ik
    monkeypatch.setattr(motion, "_solve_line_ik", lambda *a: calls.append(1) or solve(*a))
    motion._line_ik_kept.clear()
    Q_free = cartesian_line(planner.robot, free, qa, T_b, step=0.004)
    assert isinstance(Q_free, np.ndarray) and len(Q_free) > 10
    Q_free[0, 0] += 1.0  # the caller's copy: the kept polyline is not touched
    hit = cartesian_line(planner.robot, scene, qa, T_b, step=0.004)  # the same line through the wall
    assert calls == [1]  # solved once
    assert getattr(hit, "kind", None) == "cartesian_path_failed" and "thin_wall" in hit.message
    again = cartesian_line(planner.robot, free, qa, T_b, step=0.004)
    np.testing.assert_array_equal(again, solve(planner.robot, qa, T_b, 0.004))
    # an IK failure is kept too, and each caller gets its own copy
    far = trans(2.0, 0.0, 0.0) @ T_b
    f1 = cartesian_line(planner.robot, free, qa, far, step=0.004)
    f1.message = "renamed"
    f2 = cartesian_line(planner.robot, free, qa, far, step=0.004)
    assert calls == [1, 1] and f2.kind == f1.kind and f2.message != "renamed"
