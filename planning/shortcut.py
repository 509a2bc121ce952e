"""Shortening a collision-free joint polyline for the time the arm takes along it (path shortcutting).

RRT-Connect's paths, even after OMPL's vertex reduction and one partial-shortcut pass, wander: a transfer from
the sink to the rack swings the TCP over 1.5 m where the straight joint line between its ends (which collides)
takes it 0.9 m. The arm's time along a path is set by its joint speeds and by the TCP speed limit, so the
shortcuts here are kept by an estimate of that time, not by the joint-space length OMPL shortens:

- :func:`path_time_estimate`: per straight segment, the larger of the slowest joint's travel over its speed and
  the TCP's travel (sampled along the segment) over the TCP speed limit; a segment's rest-to-rest ramps are
  left out (every candidate has them alike at its ends).
- :func:`shortcut_path`: first every vertex that can be skipped is (from each vertex, the farthest later
  vertex whose straight joint segment is free), then `rounds` random shortcuts between two points on the path
  (each anywhere along a segment, so a corner can be cut short of its vertex), each kept only where it makes the
  estimate smaller. A new segment is checked with :func:`kitchenbot.planning.motion.check_segment` at the
  resolution given (the planner's dense re-check: the same scene, checker and margins), so the path returned is
  free wherever the path given was; its points on the old path lie on segments already checked.

The random draws come from a generator seeded by the caller: the same inputs give the same path.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

# TCP samples per radian of the largest joint turn on a segment, for the TCP's travel along it
_TCP_SAMPLES_PER_RAD = 12


def path_time_estimate(Q: np.ndarray, vmax: np.ndarray, vtcp: float,
                       tcp_of: Callable[[np.ndarray], np.ndarray]) -> float:
    """Seconds along the joint polyline Q (K, 6) at constant speed per segment: each segment takes the larger of
    max_j |dq_j| / vmax_j and the TCP's travel along it over `vtcp`; `tcp_of` maps joint rows to TCP positions."""
    return float(np.sum(segment_times(Q, vmax, vtcp, tcp_of)))


def segment_times(Q: np.ndarray, vmax: np.ndarray, vtcp: float,
                  tcp_of: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """The per-segment terms of :func:`path_time_estimate` (K - 1,)."""
    Q = np.asarray(Q, float)
    if len(Q) < 2:
        return np.zeros(0)
    dQ = np.diff(Q, axis=0)
    joint = np.max(np.abs(dQ) / vmax, axis=1)
    n = np.maximum(2, np.ceil(np.max(np.abs(dQ), axis=1) * _TCP_SAMPLES_PER_RAD).astype(int))
    rows, owner = [], []
    for k, m in enumerate(n):
        s = np.linspace(0.0, 1.0, m + 1)[:, None]
        rows.append(Q[k] + s * dQ[k])
        owner.append(np.full(m + 1, k))
    P = tcp_of(np.vstack(rows))
    own = np.concatenate(owner)
    step = np.linalg.norm(np.diff(P, axis=0), axis=1)
    same = own[1:] == own[:-1]  # steps within one segment (not from one segment's end to the next's start)
    tcp = np.bincount(own[1:][same], weights=step[same], minlength=len(dQ))
    return np.maximum(joint, tcp / vtcp)


def _point_at(Q: np.ndarray, cum: np.ndarray, s: float) -> tuple[int, np.ndarray]:
    """(segment index k, point) at arc length s along Q (cum: cumulative joint-space lengths at the vertices)."""
    k = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(Q) - 2))
    seg = cum[k + 1] - cum[k]
    t = 0.0 if seg <= 0 else float(np.clip((s - cum[k]) / seg, 0.0, 1.0))
    return k, Q[k] + t * (Q[k + 1] - Q[k])


def shortcut_path(Q: np.ndarray, is_free: Callable[[np.ndarray], bool], vmax: np.ndarray, vtcp: float,
                  tcp_of: Callable[[np.ndarray], np.ndarray], *, rounds: int = 30,
                  rng: np.random.Generator | None = None, min_gain: float = 0.005) -> np.ndarray:
    """A path from Q[0] to Q[-1] no slower by :func:`path_time_estimate` than Q, every new segment `is_free`.

    `is_free(P)` answers whether the straight joint segments of the polyline P (2, 6) are collision-free (the
    caller's dense check). A shortcut is kept where it saves more than `min_gain` seconds of the estimate."""
    Q = np.asarray(Q, float)
    if len(Q) < 3:
        return Q.copy()
    rng = rng if rng is not None else np.random.default_rng(0)

    def cost(P: np.ndarray) -> float:
        return path_time_estimate(P, vmax, vtcp, tcp_of)

    # 1. skip vertices: from each kept vertex, the farthest later vertex reachable on a free straight segment
    out = [Q[0]]
    i = 0
    while i < len(Q) - 1:
        for j in range(len(Q) - 1, i, -1):
            if j == i + 1 or is_free(np.vstack([Q[i], Q[j]])):
                out.append(Q[j])
                i = j
                break
    P = np.asarray(out)
    best = cost(P)
    # 2. random shortcuts between two points anywhere on the path (corners cut short of their vertices)
    for _ in range(rounds):
        if len(P) < 3:
            break
        cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
        s1, s2 = np.sort(rng.uniform(0.0, cum[-1], 2))
        k1, a = _point_at(P, cum, s1)
        k2, b = _point_at(P, cum, s2)
        if k1 == k2:  # both on one straight segment: nothing to cut
            continue
        cand = np.vstack([P[: k1 + 1], a[None], b[None], P[k2 + 1:]])
        # drop points that repeat their neighbour (a or b at a vertex)
        keep = np.concatenate([[True], np.linalg.norm(np.diff(cand, axis=0), axis=1) > 1e-9])
        cand = cand[keep]
        c = cost(cand)
        if c < best - min_gain and is_free(np.vstack([a, b])):
            P, best = cand, c
    return P
