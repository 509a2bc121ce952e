"""Time parameterisation of joint paths within velocity and acceleration limits.

Two profiles, both written here because they are a few lines each and keep the executed path exactly on the
collision-checked polyline (a blended/smoothed profile such as TOPP-RA on a spline would cut corners that were
never checked; toppra is also not installed and would be one more compiled dependency):

- ``stop_at_vertices``: each polyline segment gets a synchronised trapezoidal profile (all joints start and
  stop together, the slowest joint sets the pace) and the arm comes to rest at every vertex. Used for the few
  vertices of a simplified RRT-Connect path.
- ``along_path``: over a dense polyline (straight Cartesian approach, retreat and lift segments whose joint path
  is smooth), first the fastest path speed that may vary along the path (planning/path_speed.py), else one
  trapezoid in the path parameter, slowed until the finite-difference check passes.
- ``blended``: the vertices of a joint polyline are passed without stopping: straight segments at constant
  joint velocity joined by parabolic blends (the linear-segments-with-parabolic-blends scheme for via points,
  Craig, *Introduction to Robotics*, ch. 7). A blend cuts its corner (by at most |dv| * b / 8 per joint), so
  the blended path is not the checked polyline: the caller must prove it free (``free``) and otherwise falls
  back to ``stop_at_vertices``. Start and end are at rest on the first / last segment's line (no corner cut).
  For the TCP speed limit each segment is first slowed on its own (``segment_tcp_times``: a long reach swinging
  the TCP fast does not slow the wrist's turn beside it); slowing the whole profile is the fallback.

Every profile also keeps the TCP within ``SafetyLimits.max_tcp_speed`` (checked on the samples as the safety
layer checks it): a stop-at-vertices segment whose TCP would run faster is slowed on its own (the same segment
f times slower: joint speeds / f, accelerations / f^2), a smooth profile as a whole.

Samples are uniform in time (``dt``; a profile slowed for the TCP: ``f * dt``); in the stop-at-vertices profile each segment lasts a whole number of
samples, so every vertex is a sample and linear interpolation between samples never leaves the polyline.
The result is verified with ``SafetyLimits.check_trajectory`` (the same check the Arm applies) before it is
returned.
"""

from __future__ import annotations

import numpy as np

from kitchenbot.drivers.errors import LimitViolation
from kitchenbot.drivers.safety import SafetyLimits
from kitchenbot.drivers.ur_kinematics import URModel, fk_flange_batch
from kitchenbot.planning.path_speed import path_speed_profile
from kitchenbot.planning.types import Trajectory

DT = 0.008  # s between samples (125 Hz: the Arm streams or resamples; dense enough for finite differences)
TCP_HEADROOM = 1.01  # a profile slowed for the TCP speed limit is slowed this much more (sampling, rounding to dt)


def tcp_speed_ratio(limits: SafetyLimits, ur: URModel, times: np.ndarray, q: np.ndarray) -> float:
    """The samples' peak TCP speed (finite differences, as ``SafetyLimits.check_trajectory`` estimates it) over
    the limit ``limits.max_tcp_speed``: above 1 the trajectory must be that many times slower."""
    q = np.asarray(q, float)
    if len(q) < 2:
        return 0.0
    p = (fk_flange_batch(ur, q) @ np.asarray(limits.T_flange_tcp, float)[:, 3])[:, :3]
    v = np.linalg.norm(np.diff(p, axis=0), axis=1) / np.diff(np.asarray(times, float))
    return float(v.max()) / limits.max_tcp_speed


def _slowed_for_tcp(times: np.ndarray, q: np.ndarray, ratio: float) -> np.ndarray:
    """The same samples f = ratio times slower (velocities / f, accelerations / f^2) when the TCP is too fast."""
    return times * (ratio * TCP_HEADROOM) if ratio > 1.0 else times


def tcp_warped(times: np.ndarray, q: np.ndarray, vmax: np.ndarray, amax: np.ndarray, limits: SafetyLimits,
               ur: URModel) -> np.ndarray:
    """New times for the same samples `q`, slowed only where the TCP runs faster than its limit: each sample
    interval k lasts h_k / r_k with a rate r_k <= 1 (a time warp; the path, and the polyline through the samples,
    stay as they are). r_k <= the TCP's own cap on that interval; between neighbouring intervals r changes no
    faster than the acceleration the profile leaves free there: at a sample with acceleration A the velocity
    v r changes by A H r + v dr (H the mean interval), within amax H where |dr| <= H (amax - |A|) / |v| (each
    joint; the intervals only lengthen, so H grows and this is sufficient). The rate is limited forward (speeding up)
    and backward (slowing down in time for a cap), the classic two passes of a time-optimal parameterisation
    (planning/path_speed.py), here as running minima. A stretch where the profile already uses all the
    acceleration (a blend) keeps its rate. Against slowing the whole motion by its peak TCP speed
    (``_slowed_for_tcp``), only the fast stretches (a long reach, a base turn) pay."""
    times = np.asarray(times, float)
    q = np.asarray(q, float)
    h = np.diff(times)  # (m,)
    if len(q) < 3:
        return times
    p = (fk_flange_batch(ur, q) @ np.asarray(limits.T_flange_tcp, float)[:, 3])[:, :3]
    v = np.diff(q, axis=0) / h[:, None]  # (m, 6)
    vp = np.linalg.norm(np.diff(p, axis=0), axis=1) / h
    cap = np.minimum(1.0, limits.max_tcp_speed / TCP_HEADROOM / np.maximum(vp, 1e-12))
    H = (h[1:] + h[:-1]) / 2.0  # (m-1,) at the inner samples
    A = np.abs(np.diff(v, axis=0)) / H[:, None]
    room = np.maximum(amax - A, 0.0) * H[:, None]  # (m-1, 6)
    with np.errstate(divide="ignore", invalid="ignore"):
        up = np.min(np.where(np.abs(v[1:]) > 1e-9, room / np.abs(v[1:]), np.inf), axis=1)  # r_i - r_{i-1} <= up
        down = np.min(np.where(np.abs(v[:-1]) > 1e-9, room / np.abs(v[:-1]), np.inf), axis=1)  # r_{i-1} - r_i <= down
    up, down = np.minimum(up, 1.0), np.minimum(down, 1.0)
    # forward: r_i = min(cap_i, r_{i-1} + up_i) = S_i + min_{j<=i}(cap_j - S_j), S the running sum of up
    S = np.r_[0.0, np.cumsum(up)]
    r = S + np.minimum.accumulate(cap - S)
    # backward: r_{i-1} = min(r_{i-1}, r_i + down_i) = min_{j>=i}(r_j + R_j) - R_i, R the running sum of down
    R = np.r_[0.0, np.cumsum(down)]
    r = np.minimum.accumulate((r + R)[::-1])[::-1] - R
    r = np.clip(r, 1e-6, 1.0)
    return np.r_[0.0, np.cumsum(h / r)]


def _trapezoid_s(T: float, v: float, a: float, t: np.ndarray) -> np.ndarray:
    """Normalised trapezoid s(t) in [0, 1] with peak speed v and acceleration a lasting T (T = 1/v + v/a)."""
    ta = v / a
    s = np.empty_like(t)
    m1 = t < ta
    m3 = t > T - ta
    m2 = ~(m1 | m3)
    s[m1] = 0.5 * a * t[m1] ** 2
    s[m2] = 0.5 * a * ta**2 + v * (t[m2] - ta)
    tr = T - t[m3]
    s[m3] = 1.0 - 0.5 * a * tr**2
    return np.clip(s, 0.0, 1.0)


def _segment_profile(dq: np.ndarray, vmax: np.ndarray, amax: np.ndarray, dt: float) -> tuple[int, float, float]:
    """(number of samples n, peak s-speed v, s-acceleration a) of the synchronised trapezoid over dq,
    stretched so that its duration is exactly n * dt."""
    ad = np.abs(dq)
    nz = ad > 1e-12
    if not np.any(nz):
        return 0, 0.0, 0.0
    v = float(np.min(vmax[nz] / ad[nz]))
    a = float(np.min(amax[nz] / ad[nz]))
    if v * v / a > 1.0:  # triangle: never reaches v
        v = float(np.sqrt(a))
    T = 1.0 / v + v / a
    n = max(2, int(np.ceil(T / dt - 1e-9)))
    Tn = n * dt
    # lower peak speed so that 1/v + v/a = Tn: v^2 - a Tn v + a = 0 (smaller root); Tn >= 2/sqrt(a) holds
    disc = max(a * a * Tn * Tn - 4.0 * a, 0.0)
    v = (a * Tn - np.sqrt(disc)) / 2.0
    return n, float(v), a


def stop_at_vertices(Q: np.ndarray, vmax: np.ndarray, amax: np.ndarray, dt: float = DT,
                     tcp_ratio=None) -> tuple[np.ndarray, np.ndarray]:
    """Rest-to-rest synchronised trapezoids between consecutive rows of Q. Returns (times, q).
    `tcp_ratio(times, q)`: the samples' peak TCP speed over its limit; a segment above 1 is slowed by that factor
    (speeds / f, accelerations / f^2: the same segment f times slower), each segment on its own."""
    Q = np.asarray(Q, float)
    times = [0.0]
    qs = [Q[0]]
    t0 = 0.0
    for k in range(len(Q) - 1):
        dq = Q[k + 1] - Q[k]
        slow = 1.0
        for _ in range(4):
            n, v, a = _segment_profile(dq, vmax / slow, amax / slow**2, dt)
            if n == 0:
                break
            t = np.arange(1, n + 1) * dt
            s = _trapezoid_s(n * dt, v, a, t)
            s[-1] = 1.0
            f = 1.0 if tcp_ratio is None else tcp_ratio(np.r_[0.0, t], np.vstack([Q[k], Q[k] + s[:, None] * dq]))
            if f <= 1.0:
                break
            slow *= f * TCP_HEADROOM
        if n == 0:
            continue
        qs.extend(Q[k] + s[:, None] * dq)
        times.extend(t0 + t)
        t0 += n * dt
    if len(qs) == 1:  # no motion: a 2-sample hold so the trajectory is well formed
        qs.append(Q[0])
        times.append(dt)
    return np.asarray(times), np.asarray(qs)


# Path-speed profiles along straight joint segments: the share of the acceleration kept for the path's curvature.
# A straight joint segment has none (its pieces' direction changes only by rounding), so nearly all goes to the
# path speed; a little is kept so that rounding noise never bounds the speed.
STRAIGHT_CURVE_SHARE = 0.02
SEGMENT_PIECE = 0.01  # rad: the largest joint change of one piece of a segment cut for its path-speed profile


def segments_at_path_speed(Q: np.ndarray, vmax: np.ndarray, amax: np.ndarray, limits: SafetyLimits, ur: URModel,
                           dt: float = DT) -> tuple[np.ndarray, np.ndarray] | None:
    """Rest at every vertex of the joint polyline Q, as ``stop_at_vertices``, but each straight segment at the
    fastest path speed its joints' speed and acceleration and the TCP's speed allow (planning/path_speed.py on the
    segment cut in pieces of at most SEGMENT_PIECE rad, the TCP position at each cut): where the TCP's speed
    bounds a stretch (the arm stretched out while the base turns), only that stretch is slow, and the rest runs at
    the joints' limits; a synchronised trapezoid slowed for its fastest TCP stretch, even warped
    (``tcp_warped``), leaves time there. The samples lie on the segments (each vertex is a sample), so the path is
    the checked polyline itself: no collision proof beyond the polyline's is needed. Returns (times, q), or None
    where no profile passes the finite-difference limits (the caller keeps its other profiles)."""
    Q = np.asarray(Q, float)
    keep = np.r_[True, np.any(np.abs(np.diff(Q, axis=0)) > 1e-12, axis=1)]
    Q = Q[keep]
    if len(Q) < 2:
        return None
    T_ft = np.asarray(limits.T_flange_tcp, float)[:, 3]
    for slow in (1.0, 1.05, 1.15, 1.3):
        times, qs = [np.zeros(1)], [Q[:1]]
        for a, b in zip(Q[:-1], Q[1:]):
            n = max(2, int(np.ceil(np.max(np.abs(b - a)) / SEGMENT_PIECE)))
            D = a + (np.arange(n + 1)[:, None] / n) * (b - a)
            P = (fk_flange_batch(ur, D) @ T_ft)[:, :3]
            t, q = path_speed_profile(D, vmax / slow, amax / slow**2, dt, P=P,
                                      vtcp=limits.max_tcp_speed / TCP_HEADROOM / slow,
                                      curve_share=STRAIGHT_CURVE_SHARE)
            times.append(times[-1][-1] + t[1:])
            qs.append(q[1:])
        t_all, q_all = np.concatenate(times), np.vstack(qs)
        if within(t_all, q_all, vmax, amax) and tcp_speed_ratio(limits, ur, t_all, q_all) <= 1.0:
            return t_all, q_all
    return None


def _blend_schedule(Q: np.ndarray, vmax: np.ndarray, amax: np.ndarray, max_rounds: int = 60,
                    min_T: np.ndarray | None = None):
    """Segment durations T (knot to knot), segment velocities V and blend durations B (one per vertex, the ends
    included) such that every joint stays within vmax / amax and neighbouring blends do not overlap.
    `min_T` (n,): a least duration per segment (the TCP speed limit on that segment)."""
    D = np.diff(Q, axis=0)  # (n, 6)
    T = np.max(np.abs(D) / vmax, axis=1)  # fastest: the slowest joint at full speed
    if min_T is not None:
        T = np.maximum(T, min_T)
    T = np.maximum(T, 1e-3)
    for _ in range(max_rounds):
        V = D / T[:, None]
        Vx = np.vstack([np.zeros((1, Q.shape[1])), V, np.zeros((1, Q.shape[1]))])  # at rest before and after
        B = np.max(np.abs(np.diff(Vx, axis=0)) / amax, axis=1)  # (n + 1,) per vertex
        over = B[:-1] / 2 + B[1:] / 2 > T + 1e-12  # the blends at both ends of a segment overlap
        if not over.any():
            return T, V, B
        T = np.where(over, T * 1.15, T)
    raise LimitViolation("blended profile: the blends could not be separated")


def segment_tcp_times(Q: np.ndarray, limits: SafetyLimits, ur: URModel, step: float = 0.02) -> np.ndarray:
    """Per segment of the joint polyline Q, the least duration at constant joint velocity that keeps the TCP
    within ``limits.max_tcp_speed`` (its largest speed along the segment, sampled every `step` rad of the
    largest joint change)."""
    Q = np.asarray(Q, float)
    T_ft = np.asarray(limits.T_flange_tcp, float)[:, 3]
    out = np.zeros(len(Q) - 1)
    for k, (a, b) in enumerate(zip(Q[:-1], Q[1:])):
        m = max(4, int(np.ceil(np.max(np.abs(b - a)) / step)))
        s = np.linspace(0.0, 1.0, m + 1)[:, None]
        P = (fk_flange_batch(ur, a + s * (b - a)) @ T_ft)[:, :3]
        out[k] = float(np.max(np.linalg.norm(np.diff(P, axis=0), axis=1))) * m / limits.max_tcp_speed
    return out


def blended(Q: np.ndarray, vmax: np.ndarray, amax: np.ndarray, dt: float = DT,
            segment_times=None) -> tuple[np.ndarray, np.ndarray]:
    """Through the vertices of Q without stopping: constant-velocity segments joined by parabolic blends of
    bounded acceleration, at rest at both ends. Returns (times, q), uniform in time (``dt``).
    `segment_times(Q) -> (n,)`: least durations of the segments of the (deduplicated) polyline, e.g. for the TCP
    speed limit (``segment_tcp_times``): each segment slowed only as much as it needs itself."""
    Q = np.asarray(Q, float)
    keep = np.r_[True, np.any(np.abs(np.diff(Q, axis=0)) > 1e-12, axis=1)]
    Q = Q[keep]
    if len(Q) < 3:
        return stop_at_vertices(Q if len(Q) > 1 else np.vstack([Q, Q]), vmax, amax, dt)
    T, V, B = _blend_schedule(Q, vmax, amax, min_T=None if segment_times is None else segment_times(Q))
    knots = np.r_[0.0, np.cumsum(T)]  # when the straight lines pass the vertices
    t_end = knots[-1] + B[-1] / 2
    t0 = -B[0] / 2
    n = max(2, int(np.ceil((t_end - t0) / dt - 1e-9)))
    # n samples dt apart over the profile's duration: slightly slower than the schedule (never faster)
    t = t0 + np.arange(n + 1) * ((t_end - t0) / n)
    Vx = np.vstack([np.zeros((1, Q.shape[1])), V, np.zeros((1, Q.shape[1]))])
    q = np.empty((len(t), Q.shape[1]))
    k = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(T) - 1)  # segment whose knot interval holds t
    for i, (ti, ki) in enumerate(zip(t, k)):
        # inside the blend of the vertex at either end of segment ki: the parabola; else segment ki's line
        j = ki if abs(ti - knots[ki]) <= B[ki] / 2 else ki + 1
        if abs(ti - knots[j]) <= B[j] / 2 and B[j] > 0:
            v_in, v_out, tau = Vx[j], Vx[j + 1], ti - knots[j] + B[j] / 2
            q[i] = Q[j] + v_in * (ti - knots[j]) + (v_out - v_in) / (2 * B[j]) * tau**2
        else:
            q[i] = Q[ki] + V[ki] * (ti - knots[ki])
    q[0], q[-1] = Q[0], Q[-1]
    return np.arange(n + 1) * dt, q


def along_path(Q: np.ndarray, vmax: np.ndarray, amax: np.ndarray, dt: float = DT,
               accel_share: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """One trapezoid in the polyline parameter u (vertex k at u = k) over a dense, smooth joint path.
    `accel_share` of the acceleration goes to the trapezoid; the rest is left for the path's own curvature."""
    Q = np.asarray(Q, float)
    if len(Q) < 2:
        return stop_at_vertices(np.vstack([Q, Q]), vmax, amax, dt)
    D = np.abs(np.diff(Q, axis=0))  # (N-1, 6) joint change per unit u
    Dm = np.maximum(D.max(axis=0), 1e-12)
    L = float(len(Q) - 1)
    v = float(np.min(vmax / Dm))
    a = float(np.min(amax / Dm)) * accel_share
    if v * v / a > L:
        v = float(np.sqrt(a * L))
    T = L / v + v / a
    n = max(2, int(np.ceil(T / dt)))
    t = np.arange(n + 1) * (T / n)
    ta = v / a
    u = np.where(t < ta, 0.5 * a * t**2, np.where(t > T - ta, L - 0.5 * a * (T - t) ** 2, 0.5 * a * ta**2 + v * (t - ta)))
    u = np.clip(u, 0.0, L)
    u[-1] = L
    k = np.minimum(np.floor(u).astype(int), len(Q) - 2)
    f = (u - k)[:, None]
    q = Q[k] * (1 - f) + Q[k + 1] * f
    return t, q


def within(times: np.ndarray, q: np.ndarray, vmax: np.ndarray, amax: np.ndarray, tol: float = 1.02) -> bool:
    """Finite-difference joint velocities and accelerations within `vmax` / `amax` (as the safety check
    estimates them, with its 2 % tolerance)."""
    dt = np.diff(times)
    vel = np.diff(q, axis=0) / dt[:, None]
    if np.any(np.abs(vel) > vmax * tol):
        return False
    if len(q) < 3:
        return True
    acc = np.diff(vel, axis=0) / ((dt[1:] + dt[:-1]) / 2)[:, None]
    return not np.any(np.abs(acc) > amax * tol)


def time_parameterise(
    Q: np.ndarray,
    limits: SafetyLimits,
    ur: URModel,
    *,
    velocity_scale: float = 1.0,
    acceleration_scale: float = 1.0,
    mode: str = "stop_at_vertices",
    name: str = "",
    dt: float = DT,
    free=None,
) -> Trajectory:
    """A Trajectory through the joint polyline Q that passes ``limits.check_trajectory``.

    Scales are fractions of the configured limits (PlanningSettings.velocity_scale / acceleration_scale).
    ``mode="blended"`` needs ``free(q_samples) -> bool``, the proof that the blended path is collision-free;
    where it is not (or the blends cannot be timed), the vertices are stopped at.
    Raises LimitViolation only if a waypoint itself is outside the joint limits or workspace.
    """
    vmax = np.asarray(limits.max_joint_speed, float) * velocity_scale
    amax = np.asarray(limits.max_joint_accel, float) * acceleration_scale

    def ratio(times: np.ndarray, q: np.ndarray) -> float:
        return tcp_speed_ratio(limits, ur, times, q)

    def tcp_slowed(times: np.ndarray, q: np.ndarray) -> np.ndarray:
        # a smooth profile (one trapezoid, or blends) slowed where the TCP runs too fast: only there (the time
        # warp) where that stays within the limits, else as a whole
        f = ratio(times, q)
        if f <= 1.0:
            return times
        whole = _slowed_for_tcp(times, q, f)
        warped = tcp_warped(times, q, vmax, amax, limits, ur)
        if warped[-1] < whole[-1] and within(warped, q, vmax, amax) and ratio(warped, q) <= 1.0:
            return warped
        return whole

    kept: list = []

    def at_path_speed() -> tuple[np.ndarray, np.ndarray] | None:
        # resting at each vertex, each segment at its fastest path speed (on the checked polyline: no proof needed);
        # made once per call
        if not kept:
            found = segments_at_path_speed(Q, vmax, amax, limits, ur, dt)
            if found is not None:
                try:
                    limits.check_trajectory(ur, *found)
                except LimitViolation:
                    found = None
            kept.append(found)
        return kept[0]

    if mode == "blended":
        if free is None:
            raise ValueError("time_parameterise(mode='blended'): needs free=, the collision check of the blended path")
        # Two candidates, the faster first: each segment slowed for the TCP only as much as it needs itself (a
        # long reach slows only its own segments; the blends between them are then checked on the samples and,
        # where they still run too fast, the whole slowed by what is left), and the whole profile slowed as one.
        # The collision proof is asked for the candidate returned (its blends cut the corners differently).
        found = []
        for seg in (lambda P: segment_tcp_times(P, limits, ur), None):
            try:
                times, q = blended(Q, vmax, amax, dt, segment_times=seg)
                times = tcp_slowed(times, q)
                limits.check_trajectory(ur, times, q)
                found.append((times, q))
            except LimitViolation:
                pass
        # Resting at the vertices at the path speed is on the checked polyline; a blend is asked for its proof only
        # where it is faster than that. Else the vertices are rested at (below: the fastest such profile).
        stops = at_path_speed()
        for times, q in sorted(found, key=lambda c: c[0][-1]):
            if stops is not None and stops[0][-1] <= times[-1]:
                break
            if free(q):
                return Trajectory(times, q, name)
        mode = "stop_at_vertices"
    if mode == "along_path":
        # Two candidates, the faster kept: the path speed free to vary along the path (planning/path_speed.py:
        # a corner or a fast-turning stretch slows only itself), and one trapezoid in the path parameter with more
        # of the acceleration for it (a straight line's joint path curves little, and a short line never reaches
        # full speed, so its duration goes with 1 / sqrt(acceleration)). Each kept only where its samples stay
        # within the limits (finite differences, the safety check).
        found: list[tuple[np.ndarray, np.ndarray]] = []
        if len(Q) >= 3:
            P = (fk_flange_batch(ur, np.asarray(Q, float)) @ np.asarray(limits.T_flange_tcp, float)[:, 3])[:, :3]
            for slow in (1.0, 1.15, 1.3, 1.5):
                times, q = path_speed_profile(Q, vmax / slow, amax / slow**2, dt, P=P,
                                              vtcp=limits.max_tcp_speed / slow)
                if within(times, q, vmax, amax):
                    found.append((tcp_slowed(times, q), q))
                    break
        for share in (1.0, 0.85, 0.7):
            times, q = along_path(Q, vmax, amax, dt, accel_share=share)
            if within(times, q, vmax, amax):
                found.append((tcp_slowed(times, q), q))
                break
        for times, q in sorted(found, key=lambda c: c[0][-1]):
            try:
                limits.check_trajectory(ur, times, q)
                return Trajectory(times, q, name)
            except LimitViolation:
                continue
    slow = 1.0
    last: LimitViolation | None = None
    for attempt in range(16):
        if attempt == 10 and mode != "stop_at_vertices":  # a corner the smooth profile cannot take: stop there
            mode, slow = "stop_at_vertices", 1.0
        if mode == "stop_at_vertices":
            times, q = stop_at_vertices(Q, vmax / slow, amax / slow**2, dt, tcp_ratio=ratio)
            if attempt == 0:
                # beside each segment slowed as a whole for the TCP: the time warp that slows only where it runs
                # fast, and each segment at its fastest path speed; the fastest that passes is kept
                t_raw, q_raw = stop_at_vertices(Q, vmax, amax, dt)
                t_w = tcp_slowed(t_raw, q_raw)
                try:
                    limits.check_trajectory(ur, t_w, q_raw)
                    warped = (t_w, q_raw)
                except LimitViolation:
                    warped = None
                faster = [c for c in (warped, at_path_speed()) if c is not None and c[0][-1] < times[-1]]
                if faster:
                    return Trajectory(*min(faster, key=lambda c: c[0][-1]), name)
        else:
            times, q = along_path(Q, vmax / slow, amax / slow**2, dt)
            times = tcp_slowed(times, q)
        try:
            limits.check_trajectory(ur, times, q)
            return Trajectory(times, q, name)
        except LimitViolation as e:
            msg = str(e)
            if "speed" not in msg and "acceleration" not in msg:
                raise
            last = e
            slow *= 1.3
    raise last if last is not None else LimitViolation(f"trajectory {name!r}: could not be timed within limits")
