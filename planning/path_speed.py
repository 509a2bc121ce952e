"""The fastest timing along a dense joint polyline (a straight Cartesian line, a two-leg lift) within joint speed,
joint acceleration and TCP speed limits: the path speed may vary along the path, so one stretch that needs a joint
to move fast (near a wrist singularity, a corner between two legs) slows only that stretch, not the whole path as
one trapezoid does (``timing.along_path``).

The classic phase-plane scheme of time-optimal path parameterisation (Bobrow et al. 1985; Pham's TOPP-RA solves
the same problem more generally), in the discrete form a polyline of many short segments needs, written here
because it is ~60 lines and keeps the executed path exactly on the collision-checked polyline (toppra fits a
spline through the waypoints, which leaves it):

- path parameter u, vertex k at u = k; segment k has the constant joint derivative D_k = Q[k+1] - Q[k];
- the path speed u' on segment k is bounded by every joint's speed limit (vmax / |D_k|) and by the TCP speed
  limit (vtcp / |P[k+1] - P[k]|); at a vertex the direction changes by C_k = D_k - D_{k-1}, which the sampled
  trajectory sees as the acceleration |C_k| u' max(u', 1/dt) (the velocity jumps within one sample interval
  when a segment lasts longer than dt): bounded by `curve_share` of the acceleration limit;
- a forward and a backward pass limit the change of u'^2 over each segment by twice the rest of the
  acceleration limit over |D_k| (constant path acceleration on each segment), at rest at both ends;
- the result is sampled uniformly in time (<= dt) by linear interpolation on the polyline.

The caller verifies the samples (finite differences, the safety check) and slows down if they fail.
"""

from __future__ import annotations

import numpy as np


def path_speed_profile(Q: np.ndarray, vmax: np.ndarray, amax: np.ndarray, dt: float, *, P: np.ndarray | None = None,
                       vtcp: float | None = None, curve_share: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Times and samples (times, q) along the polyline Q (N >= 3 rows) at the fastest path speed the limits allow.
    `P` (N, 3): the TCP position at each vertex, with `vtcp` its speed limit."""
    Q = np.asarray(Q, float)
    D = np.diff(Q, axis=0)  # (N-1, 6) per unit u
    absD = np.maximum(np.abs(D), 1e-12)
    seg_v = np.min(vmax / absD, axis=1)  # path speed bound per segment
    if P is not None and vtcp is not None:
        seg_v = np.minimum(seg_v, vtcp / np.maximum(np.linalg.norm(np.diff(P, axis=0), axis=1), 1e-12))
    a_curve = curve_share * amax
    a_tan = np.min((1.0 - curve_share) * amax / absD, axis=1)  # path acceleration bound per segment
    n_v = len(Q)
    vcap = np.empty(n_v)
    vcap[0] = vcap[-1] = 0.0
    vcap[1:-1] = np.minimum(seg_v[:-1], seg_v[1:])
    C = np.abs(D[1:] - D[:-1])  # (N-2, 6) direction change at the inner vertices
    with np.errstate(divide="ignore"):
        # |C| u'^2 <= a_curve where u' >= 1/dt; |C| u' / dt <= a_curve below it
        fast = np.min(np.sqrt(a_curve / np.maximum(C, 1e-300)), axis=1)
        slow = np.min(a_curve * dt / np.maximum(C, 1e-300), axis=1)
    curve_v = np.where(slow <= 1.0 / dt, slow, np.maximum(fast, 1.0 / dt))
    vcap[1:-1] = np.minimum(vcap[1:-1], curve_v)
    v = vcap.copy()
    for k in range(n_v - 1):  # forward: accelerate no faster than the segment allows
        v[k + 1] = min(v[k + 1], np.sqrt(v[k] ** 2 + 2.0 * a_tan[k]))
    for k in range(n_v - 2, -1, -1):  # backward: decelerate in time for what follows
        v[k] = min(v[k], np.sqrt(v[k + 1] ** 2 + 2.0 * a_tan[k]))
    seg_t = 2.0 / np.maximum(v[:-1] + v[1:], 1e-12)  # constant path acceleration on each segment
    knots = np.r_[0.0, np.cumsum(seg_t)]
    T = float(knots[-1])
    n = max(2, int(np.ceil(T / dt - 1e-9)))
    t = np.linspace(0.0, T, n + 1)
    k = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(D) - 1)
    tau = t - knots[k]
    acc = (v[k + 1] ** 2 - v[k] ** 2) / 2.0  # u'' on the segment (its length in u is 1)
    f = np.clip(v[k] * tau + 0.5 * acc * tau**2, 0.0, 1.0)
    q = Q[k] + f[:, None] * D[k]
    q[0], q[-1] = Q[0], Q[-1]
    return t, q
