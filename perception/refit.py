"""A pose that leaves part of its own item unexplained is fitted again with that part.

A pose can be wrong and still pass every check: in a pile the visible part of an item is small, and a fit a
centimetre or two off (inside the item under it) still puts most of that part on its surface at the splitting
tolerance (1.5 voxels) and at the sensor's precision. The rest of the item's points (its far end, its handle)
then lie beyond the pose's surface: they are left over, no model explains them alone (a fragment of a mug), the
instance is rejected and its points become an "unrecognised thing" the planner must avoid, right beside a pose
every lift of which runs into them. Pose tracking keeps that pose scan after scan (a prior whose surroundings did
not change is kept as it was, perception/track.py), so nothing ever corrects it.

So after the poses of a scan are final (kept, tracked or estimated alike), the map points no pose explains are
clustered (DBSCAN, as for any remainder), and a cluster that lies within a pose's reach (its model's bounding
sphere round its origin: it could be part of that item) is fitted together with that pose's own points by the
full estimate (`Perceiver.estimate`, the other poses as stacking starts). The new fit replaces the pose only where
it explains clearly more of those points (at least REFIT_GAIN of the cluster more) and passes the checks every pose
passes (the fine check, with the other poses as neighbours), and is not a second fit of another pose. A right pose
beside an item of its own that no model explains (a distractor, a hidden item's fragment) keeps its pose: a fit
stretched over both does not explain the two at the sensor's precision. Base frame, metres.

A re-fit that failed is remembered (`RefitMemo`, one per Perceiver): on a re-scan where the pose is where it was
and its own points and the cluster's are the same points (pose tracking's test for unchanged surroundings), the pair
is not fitted again (the same fits of the same points would fail the same way; before, the clusters beside poses
that nothing in the scene changed were fitted again on every scan). Nor is a cluster fitted of which no fit of the
pose's model that keeps its own points could take the gain asked: most of it on the pose's surface already, too
little of it within the item's size of the pose's points (`_within_one_item`; only that part is fitted), or no ball
of the model's size holding both (`_in_one_ball`). The full estimate searches the pose's own model only.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from kitchenbot.perception.map import InstanceMap
from kitchenbot.perception.register import Scorer, refine
from kitchenbot.perception.track import KEEP_SHARE, KEEP_TOL
from kitchenbot.perception.types import View

#: fewest points of a left-over cluster for it to be part of an item (as a remainder is fitted again: 60)
REFIT_MIN_POINTS = 60
#: share of the cluster's points (REFIT_MIN_POINTS at least) the new fit must put on its surface (3 mm) beyond
#: what the pose puts there
REFIT_GAIN = 0.1
#: share of what the pose puts of its own points on its surface (3 mm) that the new fit must keep: the same item
#: fitted better, not a fit that leaves it for the cluster
REFIT_KEEP_OWN = 0.9
#: m / rad: a pose within this of the one whose re-fit failed is the same pose (a prior kept as it was: exactly)
MEMO_MOVE = 0.001
MEMO_TURN = np.radians(1.0)
#: m: the grid on which `_within_one_item` bounds what a fit can take of a cluster
ROOM_GRID = 0.01
#: m: the grid of ball centres (and of points) on which `_in_one_ball` looks for room for the pose's points and
#: the cluster's
BALL_GRID = 0.02
#: failed re-fits remembered (the latest first): a scan's few clusters beside poses, over a few scans
MEMO_SIZE = 32


class RefitMemo:
    """The (pose, cluster) pairs whose re-fit failed, latest first: a pose (model and pose), its own points and
    the cluster's."""

    def __init__(self, size: int = MEMO_SIZE):
        self.size = size
        #: (model, symmetric, T_base_obj, own points, cluster points)
        self.entries: list[tuple[int, bool, np.ndarray, np.ndarray, np.ndarray]] = []

    def failed_before(self, obj_id: int, symmetric: bool, T_base_obj: np.ndarray, own: np.ndarray,
                      cluster: np.ndarray) -> bool:
        """Whether the re-fit of this pose with this cluster failed before: the same model, the pose within
        MEMO_MOVE / MEMO_TURN (only the axis for a model symmetric about it), and the same own points and the same
        cluster points, each set compared on its own (`_same_points`: a small cluster that moved is not hidden by
        the pose's many own points). A hit is remembered again as the latest."""
        for k, (oid, sym, T, P_own, P_c) in enumerate(self.entries):
            if oid != obj_id or np.linalg.norm(T[:3, 3] - T_base_obj[:3, 3]) > MEMO_MOVE:
                continue
            if sym:
                c = float(T[:3, 2] @ T_base_obj[:3, 2])
            else:
                c = (float(np.trace(T[:3, :3].T @ T_base_obj[:3, :3])) - 1.0) / 2.0
            if np.arccos(np.clip(c, -1.0, 1.0)) > MEMO_TURN or not _same_points(P_c, cluster) or \
                    not _same_points(P_own, own):
                continue
            self.entries.insert(0, self.entries.pop(k))
            return True
        return False

    def remember(self, obj_id: int, symmetric: bool, T_base_obj: np.ndarray, own: np.ndarray,
                 cluster: np.ndarray) -> None:
        """Remember a failed re-fit (the oldest forgotten past `size`)."""
        self.entries.insert(0, (obj_id, symmetric, T_base_obj.copy(), own.copy(), cluster.copy()))
        del self.entries[self.size:]


def _same_points(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two point sets are the same points re-scanned: KEEP_SHARE of each one's points have one of the
    other's within KEEP_TOL (as pose tracking compares a prior's surroundings, perception/track.py)."""
    if min(len(a), len(b)) < KEEP_SHARE * max(len(a), len(b)):
        return False
    for P, Q in ((a, b), (b, a)):
        if np.isfinite(cKDTree(Q).query(P, distance_upper_bound=KEEP_TOL)[0]).mean() < KEEP_SHARE:
            return False
    return True


def refit_beside_unexplained(per, m: InstanceMap, views: list[View], kept: list[list]) -> int:
    """Re-fit, in place, each pose of `kept` ([hyp, iid, own map indices]) that has a cluster of map points no
    pose takes as its own within its reach, where a fit of its own points with the cluster (the pose refined from
    where it is, else the full estimate) puts clearly more of them on its surface and passes the checks.
    `per`: the Perceiver. Returns the number of poses replaced."""
    if not kept:
        return 0
    vox = per.settings.voxel_size
    thr = per.settings.verify_threshold
    owned = np.zeros(len(m.points), bool)
    for _, _, own in kept:
        owned[own] = True
    idx = np.nonzero((m.ids >= 0) & ~owned)[0]
    if len(idx) < REFIT_MIN_POINTS:
        return 0
    from kitchenbot.perception.pipeline import SURFACE_TOL, _clusters  # pipeline imports this module

    clusters = [idx[c] for c in _clusters(m.points[idx], 1.5 * vox, REFIT_MIN_POINTS, vox / 2)]
    replaced = 0
    for C in clusters:
        j = _owner(per, m, kept, C)
        if j is None:
            continue
        hyp, iid, own = kept[j]
        sel = np.union1d(own, C)
        model = per.inventory[hyp.obj_id]
        on_c = per._explained(hyp, m.points[C], SURFACE_TOL).sum()
        on_own = per._explained(hyp, m.points[own], SURFACE_TOL).sum()
        # what a new fit must take of the cluster; the cluster's points a fit of this model that keeps its own
        # points could take at all (a large cluster reaching past the item, a thing beside it, is fitted only
        # with its part within the item's size)
        gain = on_c + max(REFIT_MIN_POINTS, REFIT_GAIN * len(C))
        if len(C) < gain:
            continue
        room = _within_one_item(m.points[own], m.points[C], REFIT_KEEP_OWN * on_own,
                                model.diameter + 2 * SURFACE_TOL * vox + vox)
        if room.sum() < gain or not _in_one_ball(m.points[own], m.points[C[room]], REFIT_KEEP_OWN * on_own, gain,
                                                 _enclosing_radius(per.database[hyp.obj_id].dense_points) +
                                                 SURFACE_TOL * vox):
            continue
        if per.refit_memo.failed_before(hyp.obj_id, model.is_rotationally_symmetric, hyp.T_base_obj, m.points[own],
                                        m.points[C]):
            continue
        others = [k for i, k in enumerate(kept) if i != j]
        for new in _fits(per, m.select(np.union1d(own, C[room])), views, hyp, [k[0] for k in others]):
            # the same item fitted better: its own points kept, clearly more of the cluster's taken
            if per._explained(new, m.points[own], SURFACE_TOL).sum() < REFIT_KEEP_OWN * on_own or \
                    per._explained(new, m.points[C], SURFACE_TOL).sum() < gain or \
                    any(per._same_place(k[0], new) for k in others):
                continue
            tree, tol = per._fine_context(m)  # the scan's map tree and fine tolerance, made once per map
            own_new = sel[per._explained(new, m.points[sel])]
            per._fine_parts(m, tree, tol, new, own_new, others + [[new, iid, own_new]])
            if new.verification is not None and new.verification.score >= thr:
                kept[j] = [new, iid, own_new]
                replaced += 1
                break
        else:
            per.refit_memo.remember(hyp.obj_id, model.is_rotationally_symmetric, hyp.T_base_obj, m.points[own],
                                    m.points[C])
    return replaced


def _within_one_item(own: np.ndarray, cluster: np.ndarray, keep: float, diameter: float) -> np.ndarray:
    """Which of the `cluster` points a fit of an item of this `diameter` (the farthest two points on it can be
    apart, the surface tolerance included) could put on its surface while it keeps `keep` of its `own` points
    there: a cluster point it takes has that many own points within the diameter. Judged on 1 cm voxels,
    generously (every own point of a voxel that could be within reach counts): no point such a fit can take is
    left out; the far part of a large thing beside the item, and a cluster across the sink from it, are."""
    s = ROOM_GRID
    k_own, n_own = np.unique(np.floor(own / s).astype(np.int64), axis=0, return_counts=True)
    k_c, inv_c = np.unique(np.floor(cluster / s).astype(np.int64), axis=0, return_inverse=True)
    n_c = np.bincount(inv_c.ravel(), minlength=len(k_c))
    # two points in voxels whose centres are d apart are at least d - s sqrt(3) apart
    near = cdist(k_c * s, k_own * s) <= diameter + s * np.sqrt(3.0)
    room = near @ n_own >= keep
    return room[inv_c.ravel()]


def _enclosing_radius(points: np.ndarray) -> float:
    """Radius of a ball that holds all of a model's surface `points` (about its box's centre or its centroid,
    the smaller): no fit of the model puts on its surface points farther apart than this ball allows."""
    P = np.asarray(points, float)
    return float(min(np.sqrt(((P - c) ** 2).sum(axis=1).max())
                     for c in (0.5 * (P.min(axis=0) + P.max(axis=0)), P.mean(axis=0))))


def _in_one_ball(own: np.ndarray, cluster: np.ndarray, keep: float, gain: float, radius: float) -> bool:
    """Whether some ball of `radius` (the model's enclosing ball, the surface tolerance included) could hold
    `keep` of the `own` points and `gain` of the `cluster` points: else no fit of the model keeps its own points
    and takes that much of the cluster (a thing 10 cm beyond a plate's rim is within the plate's diameter of
    most of its points, but no plate-sized ball holds both). Ball centres and points on a 2 cm grid, the
    radius grown by both (generous: a ball that could hold them is never missed)."""
    s = g = BALL_GRID
    k_own, n_own = np.unique(np.floor(own / s).astype(np.int64), axis=0, return_counts=True)
    k_c, n_c = np.unique(np.floor(cluster / s).astype(np.int64), axis=0, return_counts=True)
    c_own, c_c = (k_own + 0.5) * s, (k_c + 0.5) * s
    r = radius + 0.5 * np.sqrt(3.0) * (s + g)
    lo, hi = c_own.min(axis=0) - radius, c_own.max(axis=0) + radius
    axes = [np.arange(a, b + g, g) for a, b in zip(lo, hi)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    holds_own = (cdist(centres, c_own) <= r) @ n_own >= keep
    if not holds_own.any():
        return False
    return bool(((cdist(centres[holds_own], c_c) <= r) @ n_c >= gain).any())


def _owner(per, m: InstanceMap, kept: list[list], C: np.ndarray) -> int | None:
    """Index of the pose the cluster `C` could be part of: of the poses within whose reach (bounding sphere) part
    of it lies, the one that puts the most of it on its surface at the splitting tolerance (1.5 voxels)."""
    best, best_n = None, -1
    for j, (hyp, _, _) in enumerate(kept):
        d = np.linalg.norm(m.points[C] - hyp.T_base_obj[:3, 3], axis=1)
        if d.min() > per.database[hyp.obj_id].reach:
            continue
        n = int(per._explained(hyp, m.points[C]).sum())
        if n > best_n:
            best, best_n = j, n
    return best


def _fits(per, inst: InstanceMap, views: list[View], hyp, found: list):
    """Fits of `inst` (a pose's points and a cluster beside it), cheapest first: the pose refined from where it is
    (as a tracked prior is), then the full estimate."""
    query = per._query(inst, views, point_features=False)
    if len(query.points) >= 8:
        entry = per.database[hyp.obj_id]
        scorer = Scorer(entry, query.points, views, per.settings.voxel_size,
                        inside_solid=per._inside_solid(per._up()), depths=per._depths)
        h = refine(query, entry, scorer, hyp.T_base_obj, per.reg_cfg, "refit",
                   symmetric=per.inventory[hyp.obj_id].is_rotationally_symmetric, local=True)
        h.score *= per._colour_weight(query, h, 1.0)
        h = per._accepted(query, h, scorer)
        if h is not None:
            yield h
    h, _query = per.estimate(inst, views, found, model=hyp.obj_id)
    if h is not None:
        yield h
