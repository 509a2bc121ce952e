"""Support surfaces and walls found in the scan itself, so that perception needs no cell description.

The views are fused (base frame, gravity = base z) and planes are taken out one by one with RANSAC
(perception/ransac.py): horizontal ones (counter, basin floor, table top, shelf) are supports, vertical ones
(splashback, basin sides, walls) are walls; tilted planes and small ones are left alone (a plate's flat
centre is not structure). Each surface keeps its footprint, the 2 cm grid cells of its plane its inliers
cover (closed, small holes such as a drain or the floor under a cup filled), so a plane removes only the
surface it was found on, not everything that happens to lie at its height.

Background = points near a surface (within the margin) or behind it, inside its footprint. What a basin's
rounded corners and bevels leave (a strip in the crease between a floor and a wall) is recognised per
segment by `SurfaceMap.is_crease`. Objects are what stands on a support, up to `max_height` above it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from kitchenbot.perception.features import voxel_keys
from kitchenbot.perception.ransac import segment_plane
from kitchenbot.perception.rgbd import point_map
from kitchenbot.perception.types import View


# Metres: a wall whose lowest footprint cell is within this of a support's plane rises from it (the basin's sides
# from its floor; the fused cloud's cells are 2 cm, the wall's foot may be hidden by an item a few cm high) ...
WALL_FOOT = 0.06
# ... and bounds it when its foot is within this of the support's footprint (the floor hidden under items along
# the side: a dinner plate leaning there is 27 cm across).
WALL_REACH = 0.30


@dataclass
class SurfaceConfig:
    voxel: float = 0.01  # m: the fused cloud's resolution for the plane search
    stride: int = 4  # pixels: every 4th row / column of each view
    max_range: float = 2.0  # m from the camera
    ransac_distance: float = 0.005  # m: plane inliers (depth noise at 0.5-1 m is 1-3 mm)
    ransac_iterations: int = 300
    max_planes: int = 10
    min_inliers: int = 250  # fused points (1 cm voxels: 0.025 m^2) for a plane to be looked at
    min_extent: float = 0.32  # m along the footprint's longer side: more than any dish (a dinner plate: 27 cm)
    max_tilt: float = np.radians(5)  # support: normal within this of up; wall: within this of horizontal
    min_area: float = 0.03  # m^2 of footprint
    max_overlap: float = 0.3  # a support over this share of another, lower support's footprint rests on it
    cell: float = 0.02  # m: footprint grid
    max_hole: float = 0.03  # m^2: footprint holes up to this are filled (a drain, an item's shadow), not the sink
    margin: float = 0.004  # m: points this close to a surface (or behind it) are the surface
    max_height: float = 0.30  # m above a support: what stands on it
    crease: float = 0.05  # m: a segment within this of two surfaces (all of it) is a fillet, not an object
    max_seen_through: float = 0.2  # points seen > 2 cm behind a plane through its footprint, per inlier: no surface


@dataclass
class Surface:
    kind: str  # "support" (horizontal, facing up) | "wall" (vertical)
    normal: np.ndarray  # unit, towards the free side (the cameras)
    offset: float  # p . normal + offset = 0 on the plane
    u: np.ndarray  # in-plane basis
    v: np.ndarray
    origin: np.ndarray  # (2,) plane coordinates of the footprint grid's corner
    cell: float
    footprint: np.ndarray  # (nu, nv) bool, small holes filled
    inliers: int = 0
    # (nu, nv) bool: cells over which the scan measured something more than 2 cm behind the plane (a sink's
    # opening, a drain, the floor past a table's edge), and the cells off the footprint joined to those (the
    # rest of an opening, hidden under a pile); None: not known (every cell open)
    opened: np.ndarray | None = None
    # (K, 3) points on the plane where walls rising from this support meet it (`_wall_feet`): where the
    # support reaches although the items on it hide it; None: none
    feet: np.ndarray | None = None

    def height(self, P: np.ndarray) -> np.ndarray:
        """Signed distance of points (..., 3) from the plane, positive on the free side."""
        return P @ self.normal + self.offset

    def covers(self, P: np.ndarray, grow: int = 0) -> np.ndarray:
        """Whether points (N, 3) project into the footprint (grown by `grow` grid cells)."""
        if grow == 0:
            fp = self.footprint
        else:  # grown footprints are asked for per view and per segment: made once
            cache = self.__dict__.setdefault("_grown", {})
            if grow not in cache:
                cache[grow] = ndimage.binary_dilation(self.footprint, iterations=grow)
            fp = cache[grow]
        i = np.floor((P @ self.u - self.origin[0]) / self.cell).astype(np.int64)
        j = np.floor((P @ self.v - self.origin[1]) / self.cell).astype(np.int64)
        ok = (i >= 0) & (i < fp.shape[0]) & (j >= 0) & (j < fp.shape[1])
        out = np.zeros(len(P), bool)
        out[ok] = fp[i[ok], j[ok]]
        return out

    def seen_through(self, P: np.ndarray, cam: np.ndarray, grow: int = 0) -> np.ndarray:
        """Which points (behind the plane) the camera at `cam` sees through the footprint: where the ray to
        them crosses the plane."""
        hc = float(self.height(cam[None])[0])
        hp = self.height(P)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = hc / (hc - hp)
        ok = (hc > 0) & (hp < 0) & (t > 0) & (t < 1)
        X = cam + t[:, None] * (P - cam)
        out = np.zeros(len(P), bool)
        idx = np.nonzero(ok)[0]
        out[idx] = self.covers(X[idx], grow)
        return out

    def hull(self) -> np.ndarray | None:
        """The convex hull of the footprint (grown by one cell) and of the feet of the walls rising from it, as
        half-planes in plane coordinates."""
        if not hasattr(self, "_hull"):
            corners = _cell_centres(self, ndimage.binary_dilation(self.footprint))
            if self.feet is not None and len(self.feet):
                corners = np.concatenate([corners, self.feet])
            self._hull = _hull_of(corners, self)
            self._disc = _inner_disc(self._hull, corners, self)
        return self._hull

    def under_hull(self, P: np.ndarray) -> np.ndarray:
        """Which points (N, 3) project into the convex hull of the footprint (grown by one cell). Points inside
        a disc within the hull are inside without testing every edge of the hull: the objects on a table stand
        mostly well inside its footprint, and the test of every point against every edge was a third of the
        segmentation of a table scan."""
        eq = self.hull()
        if eq is None or len(P) == 0:
            return _in(eq, P, self)
        (cu, cv), r = self._disc
        inner = (P @ self.u - cu) ** 2 + (P @ self.v - cv) ** 2 < r * r
        rest = np.nonzero(~inner)[0]
        inner[rest] = _in(eq, P[rest], self)
        return inner

    def closed(self, P: np.ndarray) -> np.ndarray:
        """Which points (N, 3) project into the footprint, or into a hole of it within its hull that the scan
        never saw through (`opened`): the surface hidden there by what stands on it (a pile's shadow), not an
        opening."""
        out = self.covers(P)
        rest = np.nonzero(~out)[0]
        if len(rest) == 0 or self.opened is None:
            return out
        rest = rest[self.under_hull(P[rest])]
        i = np.floor((P[rest] @ self.u - self.origin[0]) / self.cell).astype(np.int64)
        j = np.floor((P[rest] @ self.v - self.origin[1]) / self.cell).astype(np.int64)
        ok = (i >= 0) & (i < self.opened.shape[0]) & (j >= 0) & (j < self.opened.shape[1])
        shut = np.ones(len(rest), bool)
        shut[ok] = ~self.opened[i[ok], j[ok]]
        out[rest[shut]] = True
        return out

    def seen_below(self, P: np.ndarray) -> np.ndarray:
        """Which points (N, 3) project into a cell of the grid over which the scan saw something more than 2 cm
        behind the plane (`opened`; False where not known)."""
        out = np.zeros(len(P), bool)
        if self.opened is None or len(P) == 0:
            return out
        i = np.floor((P @ self.u - self.origin[0]) / self.cell).astype(np.int64)
        j = np.floor((P @ self.v - self.origin[1]) / self.cell).astype(np.int64)
        ok = (i >= 0) & (i < self.opened.shape[0]) & (j >= 0) & (j < self.opened.shape[1])
        out[ok] = self.opened[i[ok], j[ok]]
        return out

    @property
    def area(self) -> float:
        return float(self.footprint.sum()) * self.cell**2


@dataclass
class SurfaceMap:
    """The surfaces of one scan, base frame."""

    surfaces: list[Surface]
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    cfg: SurfaceConfig = field(default_factory=SurfaceConfig)

    @property
    def supports(self) -> list[Surface]:
        return [s for s in self.surfaces if s.kind == "support"]

    @property
    def walls(self) -> list[Surface]:
        return [s for s in self.surfaces if s.kind == "wall"]

    def background(self, P: np.ndarray, cam: np.ndarray, margin: float | None = None) -> np.ndarray:
        """Which points (N, 3), seen from camera centre `cam`, are a surface: within `margin` of one inside its
        footprint, or seen through it (behind it, the ray crossing its footprint: a drain, a gap at an edge)."""
        margin = self.cfg.margin if margin is None else margin
        out = np.zeros(len(P), bool)
        for s in self.surfaces:
            h = s.height(P)
            near = ~out & (np.abs(h) < margin)
            if near.any():  # the footprint grown by a cell: a counter's narrow strip beside the basin
                idx = np.nonzero(near)[0]
                out[idx[s.covers(P[idx], grow=1)]] = True
            behind = ~out & (h <= -margin)
            if behind.any():
                idx = np.nonzero(behind)[0]
                out[idx[s.seen_through(P[idx], cam)]] = True
        return out

    def on_support(self, P: np.ndarray) -> np.ndarray:
        """Which points stand over a support (the convex hull of its footprint: the floor under a pile of items
        is hidden), less than max_height above it."""
        out = np.zeros(len(P), bool)
        for s in self.supports:
            h = s.height(P)
            cand = ~out & (h > 0) & (h < self.cfg.max_height)
            if cand.any():
                idx = np.nonzero(cand)[0]
                out[idx[s.under_hull(P[idx])]] = True
        return out

    def foreground(self, pts: np.ndarray, cam: np.ndarray) -> np.ndarray:
        """(H, W) mask of a point map's pixels (seen from camera centre `cam`) that are not a surface and stand
        on a support."""
        shape = pts.shape[:2]
        P = pts.reshape(-1, 3)
        ok = np.all(np.isfinite(P), axis=1)
        idx = np.nonzero(ok)[0]
        Q = P[idx].astype(np.float64)
        keep = ~self.background(Q, cam)
        keep[keep] = self.on_support(Q[keep])
        out = np.zeros(len(P), bool)
        out[idx[keep]] = True
        return out.reshape(shape)

    def is_crease(self, P: np.ndarray, share: float = 0.8) -> bool:
        """Whether a segment lies in the crease between two surfaces (within `crease` of a support and of a
        wall, or of two walls, for `share` of its points): a basin's rounded corner or bevel, no object."""
        if len(P) == 0 or len(self.surfaces) < 2:
            return False
        near = np.zeros(len(P), np.int64)
        for s in self.surfaces:
            near += (np.abs(s.height(P)) < self.cfg.crease) & s.covers(P, grow=2)
        return bool(np.mean(near >= 2) >= share)

    def is_wall_remnant(self, P: np.ndarray) -> bool:
        """Whether a segment is a piece of structure too little seen to be found as a surface: a flat sheet (95 %
        of it within 4 mm of its plane), either level and in a found support's plane (within half the margin:
        a plate's flat centre lies one wall, 4.5 mm, above the floor; a counter's strip seen apart), or plumb at the edge of a support (its lower part within 3 cm of the hull's boundary, or outside
        it: a basin side hidden behind a leaning plate)."""
        if len(P) < 50 or not self.supports:
            return False
        c = P.mean(axis=0)
        n = np.linalg.svd(P - c, full_matrices=False)[2][2]
        if np.mean(np.abs((P - c) @ n) < 0.004) < 0.95:
            return False  # not a flat sheet
        if abs(n @ self.up) >= np.cos(self.cfg.max_tilt):
            # Level: a strip of a found support seen apart from it (a counter's edge behind the basin).
            return any(abs(float(s.height(c[None])[0])) < 0.5 * self.cfg.margin for s in self.supports)
        if abs(n @ self.up) > np.sin(self.cfg.max_tilt):
            return False
        low = P[(P - c) @ self.up < 0]
        for s in self.supports:
            h = s.height(low)
            if np.median(h) > 0.05:
                continue  # not standing on this support
            if np.median(hull_depth(s.hull(), low, s)) < 0.03:
                return True
        return False

    def inside_solid(self, P: np.ndarray, depth: float = 0.01, supports_only: bool = False) -> np.ndarray:
        """Points more than `depth` behind a surface, inside its footprint (a pose may not put a model there);
        behind a support also in the holes of its footprint that were never seen through (`Surface.closed`:
        a glass was fitted sunk into a table, in the board's hole under a pile, only its base above it).
        `supports_only`: behind the supports only, not the walls."""
        out = np.zeros(len(P), bool)
        for s in self.surfaces:
            if supports_only and s.kind != "support":
                continue
            cand = ~out & (s.height(P) < -depth)
            if cand.any():
                idx = np.nonzero(cand)[0]
                if s.kind == "support":
                    # Not where the scan saw below the plane: the footprint's 2 cm cells along a counter's edge
                    # reach over the basin (its side is seen below them), and an item's top at the counter's
                    # height (an upside-down bowl's base, a glass's rim) joins the footprint; the items under
                    # and beside them were taken for solid and their right poses scored down.
                    Q = P[idx]
                    out[idx[s.closed(Q) & ~s.seen_below(Q)]] = True
                else:
                    out[idx[s.covers(P[idx])]] = True
        return out


def _basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, ref)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def _footprint(I: np.ndarray, n: np.ndarray, cfg: SurfaceConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """(u, v, grid origin, footprint) of inlier points I on a plane with normal n: the grid cells they cover,
    closed (gaps of one cell) and with holes up to max_hole filled, keeping only connected parts wider than
    min_extent; None when no part is."""
    u, v = _basis(n)
    a, b = I @ u, I @ v
    origin = np.array([a.min() - 2 * cfg.cell, b.min() - 2 * cfg.cell])
    i = ((a - origin[0]) / cfg.cell).astype(np.int64)
    j = ((b - origin[1]) / cfg.cell).astype(np.int64)
    grid = np.zeros((i.max() + 3, j.max() + 3), bool)
    grid[i, j] = True
    grid = ndimage.binary_closing(grid, iterations=1) | grid
    # Fill small holes only: the sink opening in a counter is a hole too, and must stay one.
    holes = ndimage.binary_fill_holes(grid) & ~grid
    lab, n_holes = ndimage.label(holes)
    if n_holes:
        sizes = ndimage.sum(holes, lab, index=np.arange(1, n_holes + 1)) * cfg.cell**2
        grid |= np.isin(lab, 1 + np.nonzero(sizes <= cfg.max_hole)[0])
    keep = _long_parts(grid, cfg)
    if not keep.any():
        return None
    return u, v, origin, keep


def find_surfaces(views: list[View], up: np.ndarray | None = None, cfg: SurfaceConfig | None = None) -> SurfaceMap:
    """The supports and walls of a scan (views with base-frame poses; `up` = gravity's opposite, base z)."""
    cfg = cfg or SurfaceConfig()
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, float) / np.linalg.norm(up)
    pts, src = [], []
    for k, v in enumerate(views):
        p = point_map(v, cfg.stride).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1)]
        p = p[np.linalg.norm(p - v.T_base_cam[:3, 3], axis=1) < cfg.max_range]
        pts.append(p)
        src.append(np.full(len(p), k))
    P = np.concatenate(pts).astype(np.float64) if pts else np.zeros((0, 3))
    S = np.concatenate(src) if src else np.zeros(0, np.int64)
    cams = np.array([v.T_base_cam[:3, 3] for v in views]).mean(axis=0) if views else np.zeros(3)
    # 1 cm voxels, one point (and its camera) per voxel.
    _, first = np.unique(voxel_keys(P, cfg.voxel), return_index=True)
    S = S[first]
    V = P[first]  # the whole fused cloud, 1 cm voxels
    rest = V.copy()
    surfaces: list[Surface] = []
    for _ in range(cfg.max_planes):
        if len(rest) < cfg.min_inliers:
            break
        # RANSAC on at most 4000 of the points (the plane is then refitted on all of them, below).
        sub = rest[:: max(1, len(rest) // 4000)]
        plane, _ = segment_plane(sub, cfg.ransac_distance, cfg.ransac_iterations)
        n = np.asarray(plane[:3], float)
        n /= np.linalg.norm(n)
        inl = np.nonzero(np.abs(rest @ n + plane[3] / np.linalg.norm(plane[:3])) < cfg.ransac_distance)[0]
        if len(inl) < cfg.min_inliers:
            break
        if n @ (cams - rest[inl].mean(axis=0)) < 0:
            n = -n
        cos_up = float(n @ up)
        if cos_up >= np.cos(cfg.max_tilt):
            kind = "support"
        elif abs(cos_up) <= np.sin(cfg.max_tilt):
            kind = "wall"
        else:
            rest = np.delete(rest, inl, axis=0)
            continue  # tilted: a leaning plate, a ramp; not structure
        # RANSAC's plane comes from three points and may tilt across a floor and an item lying on it. Level
        # (support) or plumb (wall) it at the inliers' median, take the points near that, and fit them by least
        # squares (the scan's own small tilt from pose errors stays); its inliers are those near the fit.
        n0 = up if kind == "support" else (n - (n @ up) * up) / np.linalg.norm(n - (n @ up) * up)
        h0 = rest @ n0
        band = np.abs(h0 - np.median(h0[inl])) < cfg.ransac_distance
        if band.sum() < 3:
            rest = np.delete(rest, inl, axis=0)
            continue
        c = rest[band].mean(axis=0)
        n = np.linalg.svd(rest[band] - c, full_matrices=False)[2][2]
        n = n if n @ n0 > 0 else -n
        d = -float(n @ c)
        sel = np.abs(rest @ n + d) < cfg.ransac_distance
        I = rest[sel]
        inl = np.nonzero(sel)[0]
        rest = rest[~sel]
        if len(I) < cfg.min_inliers or float(n @ n0) < np.cos(cfg.max_tilt):
            continue
        fp = _footprint(I, n, cfg)
        if fp is None:
            continue  # a small flat patch (a plate's centre, a box's top)
        u, v, origin, grid = fp
        if grid.sum() * cfg.cell**2 < cfg.min_area:
            continue
        s = Surface(kind, n, d, u, v, origin, cfg.cell, grid, len(inl))
        # A surface cannot be seen through: a plane that cuts across items (their rims at one height) has
        # the floor and the items' lower parts behind it. Counted inside the footprint less its border cells
        # (under a counter's edge the basin wall drops away).
        inner = Surface(kind, n, d, u, v, origin, cfg.cell, ndimage.binary_erosion(grid), len(inl))
        behind = np.nonzero(s.height(V) < -0.02)[0]
        seen = sum(int(inner.seen_through(V[behind[S[behind] == k]], v.T_base_cam[:3, 3]).sum())
                   for k, v in enumerate(views))
        if seen > cfg.max_seen_through * len(inl):
            continue
        surfaces.append(s)
    # What of a support lies over a lower support is no structure: the top of a plate stack, rims of items at one
    # height, or such rims caught in the counter's plane across the sink's opening (a glass standing on the
    # basin floor reaches the counter's height). Those cells leave its footprint; what is left must still have
    # a part longer than min_extent. A dish rack beside the sink is kept.
    supports = [s for s in surfaces if s.kind == "support"]
    out = []
    for s in surfaces:
        if s.kind == "support":
            i, j = np.nonzero(s.footprint)
            cells = _cell_centres(s)
            over = np.zeros(len(cells), bool)
            for t in supports:
                if t is not s and -t.offset < -s.offset - 0.02:
                    over |= _in(_hull_of(_cell_centres(t), t), cells, t)
            if over.any():
                fp = s.footprint.copy()
                fp[i[over], j[over]] = False
                s.footprint = _long_parts(fp, cfg)
                s.__dict__.pop("_grown", None)
                s.__dict__.pop("_hull", None)
            if not s.footprint.any() or s.footprint.sum() * cfg.cell**2 < cfg.min_area:
                continue
        out.append(s)
    for s in out:
        if s.kind == "support":
            s.opened = _opened(s, V)
            s.feet = _wall_feet(s, [w for w in out if w.kind == "wall"])
    return SurfaceMap(out, up, cfg)


def _wall_feet(s: Surface, walls: list[Surface]) -> np.ndarray | None:
    """Where the walls that rise from support `s` meet its plane: their footprint cells projected onto it, for
    walls whose lowest cell lies within `WALL_FOOT` of the plane and whose foot lies within `WALL_REACH` of the
    support's footprint. A basin floor is seen only between the items on it: items leaning against the sides
    hide it along them, and its footprint's hull stopped short of the sides, so that what stood there (a plate
    leaning against a side) was not "standing on a support" and was lost as background. The sides show where
    the floor goes."""
    out = []
    eq = _hull_of(_cell_centres(s, ndimage.binary_dilation(s.footprint)), s)
    for w in walls:
        C = _cell_centres(w)
        h = s.height(C)
        if len(C) == 0 or not -WALL_FOOT < h.min() < WALL_FOOT or h.max() < WALL_FOOT:
            continue  # not standing on this support (a basin side under the counter, a splashback over the floor)
        F = C[h > -WALL_FOOT] - h[h > -WALL_FOOT, None] * s.normal
        F = F[hull_depth(eq, F, s) > -WALL_REACH]
        if len(F):
            out.append(F)
    return np.concatenate(out) if out else None


def _opened(s: Surface, V: np.ndarray) -> np.ndarray:
    """The cells of a support's footprint grid over which points V (the fused scan) lie more than 2 cm behind
    its plane (where the scan saw through it), and the cells off the footprint joined to those."""
    B = V[s.height(V) < -0.02]
    i = np.floor((B @ s.u - s.origin[0]) / s.cell).astype(np.int64)
    j = np.floor((B @ s.v - s.origin[1]) / s.cell).astype(np.int64)
    ok = (i >= 0) & (i < s.footprint.shape[0]) & (j >= 0) & (j < s.footprint.shape[1])
    opened = np.zeros(s.footprint.shape, bool)
    opened[i[ok], j[ok]] = True
    # The rest of an opening counts as seen through: cells off the footprint joined to such cells by cells off
    # the footprint. A pile in a sink reaching over the counter's height hides the basin under it from every
    # camera; those cells, never seen through, made the items under the pile "solid" (their right poses
    # scored down). A hole the footprint closes all round (a board's, under a box on it) stays shut.
    lab, _ = ndimage.label(~s.footprint)
    joined = np.unique(lab[opened & ~s.footprint])
    return opened | np.isin(lab, joined[joined > 0])


def _long_parts(grid: np.ndarray, cfg: SurfaceConfig) -> np.ndarray:
    """The connected parts of a footprint grid longer than min_extent (along the grid's axes)."""
    lab, _ = ndimage.label(grid, structure=np.ones((3, 3)))
    keep = np.zeros_like(grid)
    for k, sl in enumerate(ndimage.find_objects(lab), start=1):
        if max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start) * cfg.cell >= cfg.min_extent:
            keep |= lab == k
    return keep


def _hull_of(corners: np.ndarray, s: Surface) -> np.ndarray | None:
    """The convex hull of points (N, 3) in a surface's plane coordinates, as half-planes (K, 3): a x + b y + c
    <= 0 inside (None when degenerate)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return ConvexHull(np.stack([corners @ s.u, corners @ s.v], axis=1)).equations
    except (QhullError, ValueError):
        return None


def _inner_disc(eq: np.ndarray | None, corners: np.ndarray, s: Surface) -> tuple[tuple[float, float], float]:
    """A disc (centre in plane coordinates, radius) inside the convex hull `eq` of `corners`: around the corners'
    mean (inside their hull), as wide as its distance to the nearest edge (Qhull's edge normals are unit), less a
    micrometre so that rounding never puts a point of the disc outside the hull. Radius 0: no disc."""
    if eq is None or len(corners) == 0:
        return (0.0, 0.0), 0.0
    c = corners.mean(axis=0)
    cu, cv = float(c @ s.u), float(c @ s.v)
    r = float(-np.max(eq[:, 0] * cu + eq[:, 1] * cv + eq[:, 2])) - 1e-6
    return (cu, cv), max(r, 0.0)


def hull_depth(eq: np.ndarray | None, P: np.ndarray, s: Surface) -> np.ndarray:
    """How far inside the hull (plane coordinates, m) points (N, 3) project; negative outside."""
    if eq is None or len(P) == 0:
        return np.full(len(P), -np.inf)
    uv = np.stack([P @ s.u, P @ s.v], axis=1)
    return -np.max(uv @ eq[:, :2].T + eq[:, 2], axis=1)


def _in(eq, P: np.ndarray, s: Surface) -> np.ndarray:
    return hull_depth(eq, P, s) >= 0


def _in_hull(corners: np.ndarray, P: np.ndarray, s: Surface) -> np.ndarray:
    """Which points (N, 3) project into the convex hull of `corners` in a surface's plane (what lies under the
    items on a floor counts as floor, even where the items hide its edge)."""
    return _in(_hull_of(corners, s), P, s)


def _cell_centres(s: Surface, cells: np.ndarray | None = None) -> np.ndarray:
    """Base-frame centres of a surface's footprint cells (or of `cells`, a mask of its grid)."""
    i, j = np.nonzero(s.footprint if cells is None else cells)
    a = s.origin[0] + (i + 0.5) * s.cell
    b = s.origin[1] + (j + 0.5) * s.cell
    return a[:, None] * s.u + b[:, None] * s.v - s.offset * s.normal
