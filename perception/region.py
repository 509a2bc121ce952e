"""Incremental perception: re-perceive one region of a scene from one view, keep the rest.

After a pick, what may have changed lies around the pick spot (the item left; what rested or leaned on it may have
moved). Instead of a new three-view scan, one view of that region is perceived and merged into what was known:

    region = Region.around([(picked.T_base_obj[:3, 3], r), ...])
    upd = update_region(perceiver, map_points, known_poses, view, region)
    if upd.rescan is None: poses, map_points = upd.poses, upd.map_points   # else: a full scan decides

- **poses**: a known pose whose origin lies outside the region is kept as it was; those inside are replaced by
  what the view perceives in the region (a pose found there whose origin is inside; one that is the same item
  as a kept pose outside, an item straddling the border, is left to the kept pose).
- **the map**: known points outside the region stay; inside, a known point stays only where the view could not
  see it (out of the image, no depth there, or behind something nearer): where the view sees it, or sees past
  it, the view's own points replace it. So free space is only claimed where the view saw it.
- **rescan** (why one view does not settle it, else None): the view does not cover the region
  (`min_coverage` of the region's floor measured); a known item in the region is not found there again (it
  moved out of the view, or the one view cannot make it out: occluded, a stack seen from above).
- **moved**: a known item found again where it was (within pose tracking's tolerances, perception/track.py)
  keeps its known pose, the same object (fitted from the scan's several views, not this one); one found farther
  off is listed in `moved` with the view's pose: whether one view's fit is good enough for it is the caller's
  decision (the executive re-scans).

Every known item in the region must be found again, by class; items the view finds besides (uncovered by the
pick, or a dropped item) are added. One view confirms less of an item than a scan's views, and a pick can
only uncover what stays: an item found again keeps the larger of its two visible fractions. Base frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kitchenbot.perception.track import moved as _moved
from kitchenbot.perception.types import ObjectPose, View
from kitchenbot.world.same_item import same_item

#: m: a known map point whose depth the view measures within this of its own is seen (not behind something)
SEEN_TOL = 0.015


@dataclass(frozen=True)
class Region:
    """Upright cylinders (xy centre, radius), unbounded in z: where a pick may have changed the scene."""

    centres: np.ndarray  # (k, 2)
    radii: np.ndarray  # (k,)

    def __post_init__(self):
        c, r = np.asarray(self.centres, float).reshape(-1, 2), np.asarray(self.radii, float).reshape(-1)
        if len(c) != len(r) or not len(c):
            raise ValueError(f"Region: need as many radii as centres, at least one (got {len(c)} and {len(r)})")
        if np.any(~np.isfinite(c)) or np.any(~(r > 0)):
            raise ValueError("Region: centres must be finite and radii positive")
        object.__setattr__(self, "centres", c)
        object.__setattr__(self, "radii", r)

    @classmethod
    def around(cls, discs: list[tuple[np.ndarray, float]]) -> "Region":
        """One cylinder per (point, radius)."""
        return cls(np.array([np.asarray(p, float)[:2] for p, _ in discs]), np.array([float(r) for _, r in discs]))

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Which of the (N, 3) or (N, 2) points lie in it."""
        P = np.asarray(points, float).reshape(len(points), -1)[:, :2]
        d = np.linalg.norm(P[:, None, :] - self.centres[None], axis=2)
        return np.any(d <= self.radii[None], axis=1)

    def grid(self, z: float, step: float = 0.01) -> np.ndarray:
        """Points `step` apart filling its cross-section at height `z`."""
        out = []
        for c, r in zip(self.centres, self.radii):
            g = np.arange(-r, r + 1e-9, step)
            X, Y = np.meshgrid(g, g)
            xy = np.c_[X.ravel(), Y.ravel()]
            xy = xy[np.hypot(xy[:, 0], xy[:, 1]) <= r] + c
            out.append(np.c_[xy, np.full(len(xy), z)])
        return np.concatenate(out)


@dataclass
class RegionUpdate:
    poses: list[ObjectPose]  # the merged poses: kept outside, perceived inside
    map_points: np.ndarray  # the merged map
    kept: list[ObjectPose] = field(default_factory=list)  # known, outside the region
    found: list[ObjectPose] = field(default_factory=list)  # perceived in the region
    replaced: list[ObjectPose] = field(default_factory=list)  # known in the region (replaced by `found`)
    appeared: list[ObjectPose] = field(default_factory=list)  # of `found`, matched by no known item
    coverage: float = 0.0  # share of the region's floor the view measured
    rescan: str | None = None  # why one view does not settle it; None when it does
    # (known, found) pairs whose found pose is off the known one by more than tracking's tolerances
    moved: list[tuple[ObjectPose, ObjectPose]] = field(default_factory=list)


def project(view: View, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel (row, col) of each base-frame point, its depth along the optical axis, and whether it lies in the
    image in front of the camera."""
    T = np.linalg.inv(view.T_base_cam)
    Pc = P @ T[:3, :3].T + T[:3, 3]
    z = Pc[:, 2]
    ok = z > 0.05
    uv = np.zeros((len(P), 2))
    uv[ok] = (Pc[ok] @ view.K.T)[:, :2] / z[ok, None]
    h, w = view.depth.shape
    col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    ok &= (col >= 0) & (col < w) & (row >= 0) & (row < h)
    return np.c_[np.where(ok, row, 0), np.where(ok, col, 0)], z, ok


def measured_depth(view: View, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the view's depth where each point projects, the point's own depth); NaN where the view has none there."""
    px, z, ok = project(view, P)
    d = np.full(len(P), np.nan)
    d[ok] = view.depth[px[ok, 0], px[ok, 1]]
    d[~(d > 0)] = np.nan
    return d, z


def coverage(view: View, region: Region, z_floor: float) -> float:
    """Share of the region's cross-section at `z_floor` (its support) that the view measures: in the image with
    depth there, whatever stands on it."""
    d, _ = measured_depth(view, region.grid(z_floor))
    return float(np.mean(np.isfinite(d))) if len(d) else 0.0


def merge_map(known: np.ndarray | None, seen: np.ndarray | None, view: View, region: Region,
              tol: float = SEEN_TOL) -> np.ndarray:
    """Known points outside `region`, known points inside it that the view could not see (out of the image, no
    depth there, or behind a nearer surface), and the view's own points inside it."""
    known = np.zeros((0, 3)) if known is None else np.asarray(known, float)
    seen = np.zeros((0, 3)) if seen is None else np.asarray(seen, float)
    inside = region.contains(known) if len(known) else np.zeros(0, bool)
    K_in = known[inside]
    d, z = measured_depth(view, K_in)
    hidden = ~np.isfinite(d) | (d < z - tol)  # nothing measured there, or something nearer in front of it
    new_in = seen[region.contains(seen)] if len(seen) else seen
    return np.vstack([known[~inside], K_in[hidden], new_in])


def match_known(known_in: list[ObjectPose], found: list[ObjectPose]) \
        -> tuple[list[tuple[ObjectPose, ObjectPose]], list[ObjectPose], list[ObjectPose]]:
    """Pair each known item with a found item of its class, nearest first. Returns ((known, found) pairs, known
    items not found again, found items matched by none)."""
    cands = sorted(((float(np.linalg.norm(k.T_base_obj[:3, 3] - f.T_base_obj[:3, 3])), i, j)
                    for i, k in enumerate(known_in) for j, f in enumerate(found) if k.cls == f.cls))
    pairs: dict[int, int] = {}
    for _, i, j in cands:
        if i not in pairs and j not in pairs.values():
            pairs[i] = j
    return ([(known_in[i], found[j]) for i, j in pairs.items()],
            [k for i, k in enumerate(known_in) if i not in pairs],
            [f for j, f in enumerate(found) if j not in pairs.values()])


def update_region(perceiver, map_points: np.ndarray | None, known: list[ObjectPose], view: View, region: Region,
                  z_floor: float, min_coverage: float = 0.8, symmetric=None) -> RegionUpdate:
    """Re-perceive `region` from `view` with `perceiver` and merge it into the known poses and map (module doc).
    `z_floor`: the height of the support the region's items stand on (for the coverage check). `symmetric`:
    ObjectPose -> whether its model is symmetric about its z axis (only the axis' turn counts as moving); None:
    none is. A pipeline
    Perceiver estimates poses only for the instances in the region (the rest of the view is segmented, not
    fitted; a known pose that still explains its instance is tracked, perception/track.py); any other perceiver (the oracle) is asked for the whole view and filtered."""
    from kitchenbot.perception.pipeline import Perceiver

    cov = coverage(view, region, z_floor)
    kept = [p for p in known if not region.contains(p.T_base_obj[None, :3, 3])[0]]
    replaced = [p for p in known if region.contains(p.T_base_obj[None, :3, 3])[0]]
    if cov < min_coverage:
        return RegionUpdate(list(known), map_points, kept, [], replaced, [], cov,
                            f"the view measures {cov:.0%} of the region (< {min_coverage:.0%})")
    if isinstance(perceiver, Perceiver):
        res = perceiver.perceive([view], region=region.contains, priors=list(known))  # unmoved items: tracked
    else:
        res = perceiver.perceive([view])
    found = [p for p in res.poses if region.contains(p.T_base_obj[None, :3, 3])[0]
             and not any(same_item(p.cls, p.T_base_obj[:3, 3], k.cls, k.T_base_obj[:3, 3]) for k in kept)]
    pairs, lost, appeared = match_known(replaced, found)
    moved, poses = [], list(kept)
    for k, f in pairs:
        # One view confirms less of an item than the scan's views did; a pick only uncovers what stays: the
        # item is seen at least as fully as the scan saw it (what the grasp filter's occlusion test reads).
        f.visible_fraction = max(f.visible_fraction, k.visible_fraction)
        if _moved(k.T_base_obj, f.T_base_obj, bool(symmetric and symmetric(k))):
            moved.append((k, f))
            poses.append(f)
        else:  # where it was: the scan's pose (several views) stays, the same object
            k.visible_fraction = f.visible_fraction
            poses.append(k)
    poses += appeared
    seen = getattr(res, "map_points", None)
    merged = merge_map(map_points, seen, view, region) if seen is not None else map_points
    why = None
    if lost:
        why = "not found again in the region's view: " + ", ".join(
            f"{p.cls} at {np.round(p.T_base_obj[:3, 3], 3).tolist()}" for p in lost)
    return RegionUpdate(poses, merged, kept, found, replaced, appeared, cov, why, moved)
