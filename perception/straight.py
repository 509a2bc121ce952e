"""Is a tall vessel's pose a straight cylinder taken for it? (`straightness`: the verification part `straight`.)

A drink can or a bottle's body is a straight cylinder; a cup or a glass widens towards its rim (the glass by ~7
mm over its height, the cup by ~13 mm). At a noisy camera's fine tolerance a glass fitted to a can lies on the
can's side over most of its length, and where the cameras see one side only the fit leans the glass by its
half-angle so that the side it sees is straight: a change of radius judged along the pose's own axis is then
hidden (the twenty-ninth session's `taper`, docs/perception_measurements.md "fp29").

So the wall is judged against the best other explanation of the same points, each fitted with the same freedom:
the vessel's own outer profile (its axis moved and tilted, slid along itself: a cone of the model's slope where
the model is a cone) and a straight cylinder (its axis moved and tilted, any radius). Each fit's mean cost of the
points' distances to it (soft L1: the square for small distances, linear for stray points; one scale for both,
the points' spread about the cylinder); what the straight cylinder saves over the vessel's profile, over what it
would lose on the vessel's own surface seen where the points are (the same directions and heights, no noise):
    straight = (cost_vessel - cost_cylinder) / cost_cylinder_on_the_vessel
about -1 for the vessel itself (its profile fits to the noise, the cylinder misses the taper), about +1 for a
straight cylinder fitted by the vessel. The last term also says how much the points can tell: seen from one side
over a short height, a cylinder leaned by the half-angle misses the vessel by little, and the pose is not judged.

Judged on the pose's own points no other pose claims that lie on its outer wall (normals facing out from the
axis, within a band of the model's wall, between a tenth of the height from either end) and lie outside every
neighbouring pose's envelope: in a stack of nested cups the lower cup's wall goes on under the upper cup's
points, and a middle cup's segment holds the wall of the cup it is nested in (wider at each height, where its own
model is narrower). Those points are the neighbour's to explain, not evidence of this pose's shape.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from kitchenbot.perception.database import ModelEntry
from kitchenbot.perception.verify import medians_per_bin
from kitchenbot.transforms import inv

# Wall points: normal facing out from the axis (cos over STRAIGHT_OUTWARD with the radial direction), within
# STRAIGHT_BAND (metres) of the model's outer wall, between STRAIGHT_END of the height from either end; the model's
# profile in slices of STRAIGHT_SLICE (metres). Under STRAIGHT_MIN_POINTS such points: not judged.
STRAIGHT_OUTWARD = 0.7
STRAIGHT_BAND = 0.012
STRAIGHT_END = 0.1
STRAIGHT_SLICE = 0.005
STRAIGHT_MIN_POINTS = 80
# Where a straight cylinder misses the vessel's own surface (seen where the points are) by under this RMS (metres),
# the points cannot tell the two apart: not judged (a mug is nearly straight; a rim band of a few centimetres).
STRAIGHT_MIN_MISS = 0.0002
# A model whose outer radius changes by under this (metres) between the judged heights is not judged: nothing to
# tell from a straight cylinder (a mug, ~2 mm; the glass ~5.5 mm, the cup ~12 mm).
STRAIGHT_MIN_CHANGE = 0.0035
# Judged only where what the cylinder saves over the vessel, point by point, has a mean this many standard errors
# from 0.
STRAIGHT_Z = 3.0
# ... and only where the points lie on one surface at the sensor's precision: their spread about the straight
# cylinder (1.4826 x the median absolute deviation) under this share of the fine tolerance (two items' walls, a
# cup's and the wall of the cup it is nested in, spread over millimetres).
STRAIGHT_SPREAD = 0.5
# A point within this distance (metres) outside a neighbouring pose's envelope (its largest radius at each height
# from its axis, over its height) counts as inside it (the neighbour's fit is a few millimetres off).
NEST_MARGIN = 0.005
# The fits' freedom (object frame of the pose): the axis moved across itself by up to STRAIGHT_SHIFT (metres),
# tilted by up to STRAIGHT_TILT (radians), the vessel slid along it by up to STRAIGHT_SLIDE (metres: as free as the
# cylinder's radius is; a pose 1-2 cm off along its axis is still the vessel's, its profile must be allowed there);
# the fits' robust scale STRAIGHT_SCALE (metres).
STRAIGHT_SHIFT = 0.012
STRAIGHT_TILT = 0.15
STRAIGHT_SLIDE = 0.03
STRAIGHT_SCALE = 0.001
# The costs' scale is at least this (metres; see `straightness`).
STRAIGHT_MIN_SCALE = 0.0003


def outer_profile(dense_points: np.ndarray, dense_normals: np.ndarray,
                  slice_h: float = STRAIGHT_SLICE) -> tuple[np.ndarray, np.ndarray]:
    """The outer wall of a surface of revolution about z (object frame, the model's points and normals): heights
    (slice centres) and the median radius there of the points whose normal faces out from the axis (a mug's handle
    is a small share of a slice). Slices without outer wall (a base) are left out."""
    axis = np.median(dense_points[:, :2], axis=0)
    xy = dense_points[:, :2] - axis
    r = np.linalg.norm(xy, axis=1)
    out = np.einsum("ij,ij->i", dense_normals[:, :2], xy) > STRAIGHT_OUTWARD * np.maximum(r, 1e-9)
    z0 = dense_points[:, 2].min()
    b = np.floor((dense_points[out, 2] - z0) / slice_h).astype(int)
    ks, b = np.unique(b, return_inverse=True)
    return z0 + (ks + 0.5) * slice_h, medians_per_bin(r[out], b.ravel(), len(ks))


def envelope(dense_points: np.ndarray, slice_h: float = STRAIGHT_SLICE) -> tuple[np.ndarray, np.ndarray]:
    """A model's largest radius from its z axis (through the median of its points across it) per slice of height:
    heights (slice centres) and radii, object frame."""
    axis = np.median(dense_points[:, :2], axis=0)
    r = np.linalg.norm(dense_points[:, :2] - axis, axis=1)
    z0 = dense_points[:, 2].min()
    b = np.floor((dense_points[:, 2] - z0) / slice_h).astype(int)
    rmax = np.zeros(b.max() + 1)
    np.maximum.at(rmax, b, r)
    return z0 + (np.arange(len(rmax)) + 0.5) * slice_h, rmax


def inside_envelopes(points: np.ndarray, others: list[tuple[ModelEntry, np.ndarray]],
                     margin: float = NEST_MARGIN) -> np.ndarray:
    """Which points (base frame) lie inside a neighbouring pose's envelope (`others`: (entry, T_base_obj); its
    largest radius at each height, over its height, with `margin`)."""
    inside = np.zeros(len(points), bool)
    for e, T in others:
        Ti = inv(T)
        q = points @ Ti[:3, :3].T + Ti[:3, 3]
        zs, rmax = envelope(e.dense_points)
        axis = np.median(e.dense_points[:, :2], axis=0)
        z0, z1 = e.dense_points[:, 2].min(), e.dense_points[:, 2].max()
        r = np.linalg.norm(q[:, :2] - axis, axis=1)
        inside |= (q[:, 2] > z0 - margin) & (q[:, 2] < z1 + margin) & (r < np.interp(q[:, 2], zs, rmax) + margin)
    return inside


def _radial(q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For the axis of parameters `p` = (x, y, tilt x, tilt y, ...) (through (x, y, 0), direction (tx, ty, 1)
    normalised): each point's height along it, its distance from it, the axis point and direction."""
    c = np.array([p[0], p[1], 0.0])
    d = np.array([p[2], p[3], 1.0])
    d /= np.linalg.norm(d)
    w = q - c
    h = w @ d
    return h, np.linalg.norm(w - np.outer(h, d), axis=1), c, d


def _fit(q: np.ndarray, residual, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares (robust: soft L1 at STRAIGHT_SCALE) of `residual(p, q)` from `x0` within bounds; the
    parameters and the residuals."""
    sol = least_squares(residual, x0, args=(q,), bounds=(lo, hi), loss="soft_l1", f_scale=STRAIGHT_SCALE,
                        x_scale=np.array([0.01, 0.01, 0.1, 0.1, 0.01]), max_nfev=100)
    return sol.x, residual(sol.x, q)


def _fit_both(q: np.ndarray, zs: np.ndarray, rs: np.ndarray,
              cylinder_only: bool = False) -> tuple[np.ndarray | None, np.ndarray, np.ndarray | None]:
    """The vessel's profile (`zs`, `rs`) and a straight cylinder, each fitted to the points `q` (object frame):
    the residuals of each (the vessel's None with `cylinder_only`) and the vessel fit's parameters."""
    def vessel(p, q):
        h, r, _, _ = _radial(q, p)
        return r - np.interp(h + p[4], zs, rs)

    def cylinder(p, q):
        return _radial(q, p)[1] - p[4]

    s, t, a = STRAIGHT_SHIFT, STRAIGHT_TILT, STRAIGHT_SLIDE
    lo, hi = np.array([-s, -s, -t, -t, -a]), np.array([s, s, t, t, a])
    r0 = float(np.median(_radial(q, np.zeros(5))[1]))
    pc, res_c = _fit(q, cylinder, np.array([0.0, 0.0, 0.0, 0.0, r0]), np.r_[lo[:4], 0.5 * r0],
                     np.r_[hi[:4], 2.0 * r0])
    if cylinder_only:
        return None, res_c, None
    # The profile is not convex in its parameters: started at the pose and at the cylinder's axis (slid to where
    # the profile's radius is the cylinder's, within bounds); the better fit is the vessel's.
    slide = float(np.clip(zs[np.argmin(np.abs(rs - pc[4]))] - np.median(_radial(q, pc)[0]), -a, a))
    pv, res_v = None, None
    for x0 in (np.zeros(5), np.r_[pc[:4], 0.0], np.r_[pc[:4], slide]):
        p, res = _fit(q, vessel, np.clip(x0, lo, hi), lo, hi)
        if res_v is None or _costs(res, STRAIGHT_SCALE).sum() < _costs(res_v, STRAIGHT_SCALE).sum():
            pv, res_v = p, res
    return res_v, res_c, pv


def _costs(res: np.ndarray, scale: float) -> np.ndarray:
    """Soft-L1 cost of each residual at `scale`: its square where it is small against the scale, growing only
    linearly past it (a stray point from a neighbour counts as one point, not as its distance squared)."""
    return 2.0 * scale ** 2 * (np.sqrt(1.0 + (res / scale) ** 2) - 1.0)


def wall_points(points: np.ndarray, normals: np.ndarray, entry: ModelEntry, T_base_obj: np.ndarray) -> np.ndarray:
    """The points (base frame; camera-facing `normals`, NaN rows: no direction) on the posed model's outer wall, in
    its object frame: normal facing out from the axis, within STRAIGHT_BAND of the wall, between STRAIGHT_END of the
    height from either end."""
    Ti = inv(T_base_obj)
    q = points @ Ti[:3, :3].T + Ti[:3, 3]
    nq = normals @ Ti[:3, :3].T
    P = entry.dense_points
    axis = np.median(P[:, :2], axis=0)
    z0, z1 = P[:, 2].min(), P[:, 2].max()
    h = z1 - z0
    xy = q[:, :2] - axis
    r = np.linalg.norm(xy, axis=1)
    ok = np.isfinite(nq).all(axis=1)
    ok &= np.einsum("ij,ij->i", np.nan_to_num(nq[:, :2]), xy) > STRAIGHT_OUTWARD * np.maximum(r, 1e-9)
    ok &= (q[:, 2] > z0 + STRAIGHT_END * h) & (q[:, 2] < z1 - STRAIGHT_END * h)
    zs, rs = outer_profile(P, entry.dense_normals)
    ok &= np.abs(r - np.interp(q[:, 2], zs, rs)) < STRAIGHT_BAND
    return q[ok] - np.array([axis[0], axis[1], 0.0])


def straightness(points: np.ndarray, normals: np.ndarray, entry: ModelEntry, T_base_obj: np.ndarray, tol: float,
                 others: list[tuple[ModelEntry, np.ndarray]] = ()) -> float:
    """The `straight` part of a pose of a tall vessel (`entry`, a surface of revolution about its z axis, posed at
    `T_base_obj`) on its own points (base frame; camera-facing `normals`, NaN rows: no direction), less those
    inside a neighbouring pose's envelope (`others`: (entry, T_base_obj)): what a straight cylinder saves over the
    vessel's profile in mean cost per point, over what it loses on the vessel's own surface where the points are
    (see the module's doc); `tol` the fine tolerance (verify.fine_tolerance). Near -1: the vessel; near +1: a
    straight cylinder. 0 (not judged) with under
    STRAIGHT_MIN_POINTS wall points or where the cylinder misses the vessel by under STRAIGHT_MIN_MISS."""
    P = entry.dense_points
    zs, rs = outer_profile(P - np.array([*np.median(P[:, :2], axis=0), 0.0]), entry.dense_normals)
    z0, z1 = P[:, 2].min(), P[:, 2].max()
    ends = np.interp([z0 + STRAIGHT_END * (z1 - z0), z1 - STRAIGHT_END * (z1 - z0)], zs, rs)
    if len(points) == 0 or abs(ends[1] - ends[0]) < STRAIGHT_MIN_CHANGE:
        return 0.0
    if others:
        keep = ~inside_envelopes(points, others)
        points, normals = points[keep], normals[keep]
    q = wall_points(points, normals, entry, T_base_obj)
    if len(q) < STRAIGHT_MIN_POINTS:
        return 0.0
    if len(q) > 3000:  # evenly over the item (map points come in pixel order)
        q = q[:: int(np.ceil(len(q) / 3000))]
    res_v, res_c, pv = _fit_both(q, zs, rs)
    # The scale of the costs: the spread of the points about the straight cylinder (the depth noise, and the taper
    # where there is one), the same for both fits and for the miss.
    scale = max(STRAIGHT_MIN_SCALE, 1.4826 * float(np.median(np.abs(res_c - np.median(res_c)))))
    # The vessel's own surface where the points are: each point moved along its direction from the fitted axis
    # onto the fitted profile; the straight cylinder fitted to that.
    h, r, c, d = _radial(q, pv)
    radial = q - c - np.outer(h, d)
    ideal = c + np.outer(h, d) + radial / np.maximum(r, 1e-9)[:, None] * np.interp(h + pv[4], zs, rs)[:, None]
    miss = float(_costs(_fit_both(ideal, zs, rs, cylinder_only=True)[1], scale).mean())
    # What the cylinder saves, point by point: judged only where its mean stands out of its own spread (a segment
    # holding two items' walls, or seen at a noisy camera over a few hundred points, tells nothing either way).
    saved = _costs(res_v, scale) - _costs(res_c, scale)
    if scale > STRAIGHT_SPREAD * tol or miss < STRAIGHT_MIN_MISS ** 2 or abs(saved.mean()) < STRAIGHT_Z * saved.std() / np.sqrt(len(saved)):
        return 0.0
    return float(np.clip(saved.mean() / miss, -2.0, 2.0))
