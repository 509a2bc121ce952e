"""Pose tracking across re-scans: an item whose previous pose still explains its segment keeps it.

After a pick the executive scans the sink again and hands perception the poses it believed
(`Perceiver.perceive(views, priors=...)`; perception does not know the executive). Most items did not move, and a
full estimate of each (hypothesis screening over the top-K CAD candidates, then ICP: ~0.4 s) found them where
they were. Per segment instead:

- `best_prior`: the prior, not yet taken, that puts the most of the segment's points on its surface (1.5 voxels),
  if at least PRIOR_SHARE of the segment's points within its reach (it may be only part of a blob: a stack);
- the pose is refined by a few ICP iterations from the prior (register.refine(local=True)), scored against this
  scan's depth and verified like any pose (Perceiver._accepted: overlap both ways, depth render-and-compare,
  verify.py; the fine check follows for all poses alike);
- `moved`: a refined pose more than MOVE_TOL / TURN_TOL from its prior is an item that moved (knocked, settled
  after its neighbour left): the global search decides, not a local fit.

A segment no prior explains (an item uncovered or dropped, one that moved away, one whose tracked pose fails the
checks) gets the full estimate, and so does what a tracked pose leaves of its segment (pipeline: the remainder is
fitted again as after any pose).

Kept as it was (`unchanged`): where the caller also hands the map the priors were perceived on
(`perceive(prior_map=)`), a prior whose surroundings (the map points within its model's diameter of its origin:
what its own checks and its neighbours' read) are the same points as then, within the sensor's noise both ways,
is the same item in the same scene: its pose, score and verification are kept as they were, with no refinement
and no fine check (the fine check of every pose was most of a re-scan's pose stage). A pick, a slip or a knock
near it changes those points (an item gone leaves a hole, one moved or added puts points where there were none),
and then the prior is tracked and checked as above. One change is not counted: new points that lie on the
surface of a known neighbour still seen where it was (`MapChange.count_revealed`: the surface a picked item hid, of the
plate it stood on or the glass beside it; the caller's map has the picked item's points taken out already): what
the prior's checks read of them is explained by that neighbour, and the prior's own view did not change. For the
neighbour whose surface they are, they are a change (it is seen more: its visible fraction and checks are made
again); new points no such prior explains (an item uncovered that no prior knows, one moved or put there) still
count. Which points of either map are still there is computed once
per scan (`MapChange`), and each prior's surroundings are judged by counting. Base frame, metres.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from kitchenbot.perception.database import CadDatabase
from kitchenbot.perception.register import on_surface
from kitchenbot.perception.types import ObjectPose

#: of the segment's points within a prior's reach, the share on its surface for it to be tried
PRIOR_SHARE = 0.5
#: m / rad: a refined pose farther than this from its prior is an item that moved
MOVE_TOL = 0.01
TURN_TOL = np.radians(8.0)
#: m: a point of one scan's map "is still there" in the other's when one lies this close (stereo noise ~1-2 mm)
KEEP_TOL = 0.004
#: share of the surroundings' points, each way, that must still be there for a prior to be kept as it was
KEEP_SHARE = 0.95
#: fewest map points around a prior for the comparison to mean anything
KEEP_MIN_POINTS = 50


def best_prior(points: np.ndarray, priors: list[ObjectPose], database: CadDatabase, used: set[int],
               tol: float) -> int | None:
    """Index of the prior (not in `used`) that puts the most of `points` on its surface within `tol`, if that is
    at least PRIOR_SHARE of the points within its reach; else None."""
    best, best_n = None, 0
    for k, p in enumerate(priors):
        if k in used:
            continue
        entry = database[p.obj_id]
        within = np.sum((points - p.T_base_obj[:3, 3]) ** 2, axis=1) <= (entry.reach + tol) ** 2
        n_within = int(within.sum())
        if n_within == 0:
            continue
        n = int(on_surface(points[within], None, entry, p.T_base_obj, tol).sum())
        if n >= PRIOR_SHARE * n_within and n > best_n:
            best, best_n = k, n
    return best


def moved(T_prior: np.ndarray, T_now: np.ndarray, symmetric: bool) -> bool:
    """Whether the pose went more than MOVE_TOL or turned more than TURN_TOL from the prior (for a model
    symmetric about its z axis, only the axis' turn counts)."""
    if np.linalg.norm(T_now[:3, 3] - T_prior[:3, 3]) > MOVE_TOL:
        return True
    if symmetric:
        c = float(np.clip(T_now[:3, 2] @ T_prior[:3, 2], -1.0, 1.0))
    else:
        c = float(np.clip((np.trace(T_prior[:3, :3].T @ T_now[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
    return bool(np.arccos(c) > TURN_TOL)


class MapChange:
    """Which points of this scan's map (`now`) and of the map the priors were perceived on (`before`) are still
    there: a point of one map is when one of the other's lies within `tol` (both ways: a hole where an item was
    taken away and points where one came both count); after `count_revealed`, a new point on the surface of a
    prior still seen where it was counts as still there for the other priors. Computed once per scan (one KD-tree and one query each
    way); `unchanged` then asks it about each prior's surroundings by counting. Before, each prior built the
    trees of both maps' points within its reach and queried them (a fifth of a second per prior on a sink map
    of 40 000 points, the diameter of a dinner plate covering most of the sink); a point within the radius has
    all its neighbours within `tol` inside the radius plus `tol`, so the counts are those the per-prior trees
    gave."""

    def __init__(self, now: np.ndarray, before: np.ndarray, tol: float = KEEP_TOL):
        self.now = np.asarray(now, float).reshape(-1, 3)
        self.before = np.asarray(before, float).reshape(-1, 3)
        self.tol = tol
        self._new = None  # `count_revealed`: the new points, which known priors put on their surface
        self.now_tree = cKDTree(self.now) if len(self.now) else None
        self.now_kept = self._there(self.now, cKDTree(self.before) if len(self.before) else None)
        self.before_kept = self._there(self.before, self.now_tree)

    def _there(self, P: np.ndarray, tree: cKDTree | None) -> np.ndarray:
        if len(P) == 0 or tree is None:
            return np.zeros(len(P), bool)
        return np.isfinite(tree.query(P, distance_upper_bound=self.tol)[0])

    def still_seen(self, points: np.ndarray) -> float:
        """Share of `points` (a prior's own points, from the map it was perceived on) with a point of this scan's
        map within the tolerance: the item is still where it was seen (a picked item's share is ~0)."""
        P = np.asarray(points, float).reshape(-1, 3)
        return float(self._there(P, self.now_tree).mean()) if len(P) else 0.0

    def count_revealed(self, priors: list[ObjectPose], database: CadDatabase, tol: float) -> int:
        """Points new in this scan's map that lie on the surface (within `tol`) of a prior still seen where it was
        (`still_seen` at least KEEP_SHARE) count as still there for `unchanged` asked about another prior: surface
        that an item taken away hid, of a known neighbour (the plate a mug was picked off, the side of the glass
        beside it). For the prior whose own surface they lie on they are a change: it is seen more than when it
        was perceived (its visible fraction, what grasp selection reads of how buried it is, and its checks are
        made again). New points no such prior puts on its surface (an item uncovered that no prior knows, one
        moved or put there) count as a change for all. Returns how many new points lie on such a surface."""
        self._new = np.nonzero(~self.now_kept)[0]
        self._database, self._tol = database, tol
        self._on_known = np.zeros(len(self._new), bool)
        self._on_prior = {}
        if len(self._new) == 0:
            return 0
        for p in priors:
            if self.still_seen(p.points) >= KEEP_SHARE:
                on = on_surface(self.now[self._new], None, database[p.obj_id], p.T_base_obj, tol)
                self._on_prior[id(p)] = on
                self._on_known |= on
        return int(self._on_known.sum())

    def _now_kept_for(self, prior: ObjectPose | None) -> np.ndarray:
        """`now_kept`, with the new points on a known neighbour's surface (`count_revealed`) counted as still
        there for `prior` unless they lie on its own surface too."""
        if prior is None or getattr(self, "_new", None) is None or len(self._new) == 0:
            return self.now_kept
        own = self._on_prior.get(id(prior))
        if own is None:
            own = on_surface(self.now[self._new], None, self._database[prior.obj_id], prior.T_base_obj, self._tol)
        kept = self.now_kept.copy()
        kept[self._new[self._on_known & ~own]] = True
        return kept

    def unchanged(self, centre: np.ndarray, radius: float, share: float = KEEP_SHARE,
                  prior: ObjectPose | None = None) -> bool:
        """Whether the map points within `radius` of `centre` are the same in both maps: at least `share` of each
        side's points there are still there in the other (for `prior`, after `count_revealed`: new points on a
        known neighbour's surface, not on its own, count as still there)."""
        flags = []
        for P, kept in ((self.now, self._now_kept_for(prior)), (self.before, self.before_kept)):
            inside = np.sum((P - centre) ** 2, axis=1) <= radius ** 2
            if np.count_nonzero(inside) < KEEP_MIN_POINTS:
                return False
            flags.append(kept[inside])
        return all(f.mean() >= share for f in flags)


def unchanged(now: np.ndarray, before: np.ndarray, centre: np.ndarray, radius: float,
              tol: float = KEEP_TOL, share: float = KEEP_SHARE) -> bool:
    """Whether the map points within `radius` of `centre` are the same in this scan's map (`now`) as in the map
    the prior was perceived on (`before`): at least `share` of each side's points have one of the other's within
    `tol` (`MapChange`, for one question)."""
    return MapChange(now, before, tol).unchanged(centre, radius, share)
