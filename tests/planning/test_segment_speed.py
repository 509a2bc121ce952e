"""Free joint motions resting at their vertices: each straight segment at its fastest path speed
(timing.segments_at_path_speed), on the checked polyline itself, within every limit, the TCP's included."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.planning.timing import (
    segments_at_path_speed,
    stop_at_vertices,
    tcp_speed_ratio,
    tcp_warped,
    time_parameterise,
    within,
)


def _on_polyline(Q: np.ndarray, q: np.ndarray, tol: float = 1e-9) -> bool:
    """Every sample of q lies on a segment of the polyline Q, in order."""
    k = 0
    for x in q:
        while k < len(Q) - 1:
            a, b = Q[k], Q[k + 1]
            d = b - a
            s = float(np.dot(x - a, d) / np.dot(d, d))
            if -tol <= s <= 1 + tol and np.linalg.norm(a + s * d - x) < tol:
                break
            k += 1
        else:
            return False
    return True


def test_a_segment_the_tcp_limits_in_part_runs_at_the_joints_limits_elsewhere(planner, home):
    """From folded (the TCP near the base axis) to stretched out while the base turns: the TCP's speed limit binds
    at the stretched end only. The synchronised trapezoid, even warped for the TCP where it runs fast, spends its
    ramps and cruise at the pace the whole segment allows; the path speed along the segment runs the folded part
    at the joints' limits. The same straight joint segment (samples on it, its ends at rest), within every limit,
    and faster than the warped trapezoid that was kept before."""
    lim, ur = planner.limits, planner.robot.ur
    vmax, amax = lim.max_joint_speed, lim.max_joint_accel
    folded = home + np.array([0.0, -0.3, 1.0, 0.0, 0.0, 0.0])
    stretched = home + np.array([1.5, 0.5, -0.8, 0.0, 0.0, 0.0])
    Q = np.vstack([folded, stretched])
    t_raw, q_raw = stop_at_vertices(Q, vmax, amax)
    assert tcp_speed_ratio(lim, ur, t_raw, q_raw) > 1.3  # the TCP limit binds somewhere
    t_w = tcp_warped(t_raw, q_raw, vmax, amax, lim, ur)
    times, q = segments_at_path_speed(Q, vmax, amax, lim, ur)
    lim.check_trajectory(ur, times, q)
    assert within(times, q, vmax, amax) and tcp_speed_ratio(lim, ur, times, q) <= 1.0
    assert _on_polyline(Q, q)
    np.testing.assert_array_equal(q[0], folded)
    np.testing.assert_array_equal(q[-1], stretched)
    assert times[-1] < 0.9 * t_w[-1]
    traj = time_parameterise(Q, lim, ur, mode="stop_at_vertices")  # the planner's timing keeps the faster
    assert traj.duration == pytest.approx(times[-1])


def test_a_path_whose_blend_is_not_free_rests_at_its_vertex_at_the_path_speed(planner, home):
    """A two-segment path (a base turn out to a stretched arm, then a wrist turn): where the blended corner is not
    proven free, the motion stops at the vertex, on the checked polyline; each segment at its own path speed, so it
    is faster than the trapezoids that stop there. Where the blend is free and faster, the blend is kept."""
    lim, ur = planner.limits, planner.robot.ur
    mid = home + np.array([1.2, 0.4, -0.6, 0.0, 0.0, 0.0])
    Q = np.vstack([home + np.array([0.0, -0.3, 0.9, 0.0, 0.0, 0.0]), mid, mid + np.array([0.0, 0.0, 0.0, 0.6, 0.8, 1.0])])
    asked = []

    def not_free(q):
        asked.append(q)
        return False

    stop = time_parameterise(Q, lim, ur, mode="blended", free=not_free)
    lim.check_trajectory(ur, stop.times, stop.q)
    assert _on_polyline(Q, stop.q)
    assert np.min(np.linalg.norm(stop.q - mid, axis=1)) == 0.0  # the vertex is a sample: it rests there
    t_trap, q_trap = stop_at_vertices(Q, lim.max_joint_speed, lim.max_joint_accel)
    assert stop.duration < tcp_warped(t_trap, q_trap, lim.max_joint_speed, lim.max_joint_accel, lim, ur)[-1]
    assert asked  # the blend is faster here than resting at the vertex, so its proof was asked for
    blend = time_parameterise(Q, lim, ur, mode="blended", free=lambda q: True)  # proven free: the blend is kept
    assert blend.duration < stop.duration and not _on_polyline(Q, blend.q, tol=1e-6)
