"""Does a pose explain its segment? One number per pose, one threshold (setting `verify_threshold`).

The checks, each a share in [0, 1]:
- seen: of the posed model's surface the views could see (facing a camera, not hidden behind measured depth),
  how much the depth confirms near the segment (the Scorer's model->query ratio);
- explained: of the segment's points, how many lie on the model (within one voxel);
- free space: of that visible model surface, how much lies clearly in front of the measured depth, where the
  camera saw through it (render-and-compare: the model says "surface here", the depth says "empty");
- normals: of the explained points, how many lie on a side of the model facing the same way (within ~60 deg);
- fine: of the segment's points that no other pose claims, how many lie on the model's surface, facing the same
  way, at the sensor's precision (`fine_tolerance`: 3 mm, more where the map's surfaces are rougher), the pose
  nudged first onto them by a short ICP (`fine_share`);
- continued (tall vessels: cups, mugs, glasses): measured points just past the model's ends (3 cm along its axis,
  within its radius) that neither it nor another pose puts on a surface, per point of its own (`continuation`):
  a bottle or a rolling pin lying there is longer than any cup, its surface goes on where the cup ends. A
  standing vessel's end is judged only where nothing past it reaches out across the axis (a plate over a rim, the
  support under a base): a standing bottle's body, shoulder and neck go on along it. An upright vessel's base end is
  not judged: what lies under it is what it stands on (a drink can, the glass it is nested in).

- intruded (cups, mugs, glasses whose opening faces down): other surfaces seen inside the model's cavity,
  i.e. passing through where its wall would be (`intruded`): a glass fitted upside down or lying over a drink
  can shorter than it reaches past the can's end, through the items the can rests on.
  Read at the pose `fine_fit` nudged onto the vessel's own points: one resting on its rim, fitted a few
  millimetres off, would otherwise put the surface it rests on inside its wall near the rim.
- overhang (cups, mugs, glasses not standing): measured points in the plane of the model's base just past its edge
  that no pose explains, per point of its own (`overhang`): a can's lid is wider than a glass's base; and the area
  they cover, over the base's area (`overhang_area`): a lid seen from a camera facing the base end covers the ring
  all round, however many points the can's side gives the pose.
- straight (cups, mugs, glasses, any way up): how much better a straight cylinder explains the pose's outer wall
  than the vessel's own profile does, each fitted to the same points with the same freedom, over what the cylinder
  would lose on the vessel's own surface there (perception/straight.py): a drink can or a bottle's body is
  straight where a cup or a glass tapers (not a share: about -1 for the vessel, +1 for a straight cylinder).
- sunk (every pose of a scan segmented with the surfaces found in it): the share of the posed model's surface more
  than 1 cm behind a support found in the data (perception/surfaces.py, `inside_solid` with `supports_only`): no
  item passes through the table it stands on. A glass fitted upside down on a drink can shorter than it puts its
  base on the can's lid and its rim through the table, where no camera sees it.

verification = min(1 - free / (seen + free), normals, fine / FINE_FULL, 1 - continued / CONTINUED_FULL,
1 - filled / FILLED_FULL, 1 - overhang / OVERHANG_FULL, 1 - overhang_area / OVERHANG_AREA_FULL,
1 - intruded / INTRUDED_FULL, 1 - max(0, straight) / STRAIGHT_FULL, 1 - sunk / SUNK_FULL). Coverage both ways at one
voxel (seen, explained) is gated before this by the registration's own thresholds (`min_overlap`, model->query >= 0.15,
query->model >= 0.2): at that point the segment may still hold several touching items, so a low `explained` is no
evidence against a pose, and a low `seen` is what an item half hidden under its neighbours looks like.

Two kinds of wrong pose are caught. Dishware put where the camera saw past a distractor (a bowl over a lying
bottle, a plate over a box's edge): free space. Dishware fitted to something of about its size and shape (a
drink can or a bottle taken for a cup or a glass, a piece of a box for a plate): at one voxel (1 cm) such a fit
"explains" its points, but a can is straight where a cup tapers, its lid is flat where a glass has a base ring,
a box's faces are flat where a bowl curves: millimetres off over much of the segment. Right poses put most of
their points within ~2 noise levels of the surface (the fits are refined to the millimetre); `fine` measures
that. Calibrated on generated scenes with distractors (`python -m kitchenbot.perception.calibrate_verify`,
docs/perception.md "Verification").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from kitchenbot.perception.database import ModelEntry
from kitchenbot.perception.register import icp_to_model, on_surface
from kitchenbot.transforms import inv

# The fine tolerance: at least this (metres; a model's facets and the fit's own error are ~1 mm, the depth
# quantisation 1 mm), and this many times the map's surface noise (`surface_noise`).
FINE_TOL_MIN = 0.003
FINE_TOL_NOISE = 4.0
# The fine share at which a pose counts as fully explained: right fits of items seen whole put 0.85-0.98 of
# their points within the tolerance, slivers of occluded ones (a nested cup's rim, a stacked plate's edge)
# 0.5-0.8 (their fits are a few millimetres off); drink cans and bottles fitted as cups and glasses 0.2-0.8,
# boxes fitted as mugs 0.1-0.5 (development scenes with distractors, docs/perception.md).
FINE_FULL = 0.6
# The fine fit's nudge (`fine_fit`) runs on at most about this many of the pose's own points (every k-th: map
# points come in pixel order, so evenly over the item); the share is read on all of them. A segment holds up to
# ~25 000 map points, and the nudge's ICP on all of them was a tenth of a scan's pose stage (the refinement's ICP
# runs on <= 600 voxel centres). On 2000 the final poses and verification scores of the development and fresh
# scans of the twenty-eighth session were the same (docs/perception_measurements.md, pose28).
FINE_FIT_POINTS = 2000
# The continued share at which a pose scores 0 (linear from 0 at none): right fits of lying cups, mugs and glasses
# have 0-0.06, cups fitted along a lying bottle 0-0.6, most over 0.15 (development scenes with distractors,
# docs/perception_measurements.md "A bottle is longer than a cup"); with the threshold 0.85 a pose is rejected
# above 0.15.
CONTINUED_FULL = 1.0
# Past each end of the model along its axis, this far, is where a longer object would continue.
CONTINUE_REACH = 0.03
# A standing vessel's end is judged for continuation only where the unexplained surface past it does not reach
# out across the axis: points in this ring (metres past the end's radius; clear of a bottle up to 1 cm wider than
# the end) at least this share of those within the end's radius + 1 cm mean something lies across or beside it.
ACROSS_RING = (0.02, 0.05)
ACROSS_SHARE = 0.25
# ... and only where it goes on around the axis: a body going on past the end (a bottle's body, shoulder and neck,
# a closed surface round the axis) is seen by the views over a wide arc of directions from the axis; what the
# unexplained points past an end cover, in bins of AROUND_BIN (degrees; a bin counts with at least AROUND_MIN of
# those points, 2 at least), under AROUND_SPAN is one side only: something leaning on the rim, a handle or
# cutlery poking out of the opening, a neighbour's edge. Not tuned: the first values tried.
AROUND_BIN = 15
AROUND_MIN = 0.02
AROUND_SPAN = 120
# A vessel's closed base counts as seen (`base_seen`; the end past it is then not judged for continuation) when
# this share of its disc (within BASE_INNER of its radius, in BASE_VOXEL squares) holds own points on its plane
# facing out (cos over BASE_FACING with the axis). Not tuned: the first values tried.
BASE_SEEN = 0.3
BASE_INNER = 0.8
BASE_VOXEL = 0.005
BASE_FACING = 0.8
# The filled share at which a pose scores 0 (linear from 0 at none; see `filled`): calibrated with
# perception/calibrate_verify.py on development scenes with distractors (docs/perception_measurements.md, "Speed
# and the lid of a can", "A can's lid is no opening").
FILLED_FULL = 1.0
# The overhang share at which a pose scores 0 (linear from 0 at none; see `overhang`): right poses of cups, mugs
# and glasses not standing have 0-0.11, upside-down glasses over drink cans and cups on bottles up to 0.23
# (development scenes with distractors, docs/perception_measurements.md, "Speed and the lid of a can").
OVERHANG_FULL = 1.0
# The band past the edge of the model's base (metres, radially: beyond the fit's error, within an item's reach)
# and the depth of its plane (the noise) where a surface going on counts as overhang.
OVERHANG_BAND = (0.004, 0.02)
OVERHANG_PLANE = 0.005
# The overhang area (see `overhang_area`: the base's plane covered in that band, in OVERHANG_VOXEL squares, over
# the base's area) at which a pose scores 0 (linear from 0 at none); with the threshold 0.85 a pose is rejected
# above 0.4. Right cups, mugs and glasses not standing: 0-0.32 (an upside-down cup with a neighbour's rim in the
# plane of its base); glasses fitted lying or upside down on drink cans 0.42-1.02, whose per-point overhang was
# 0.01-0.14 (the can's side gives thousands of own points, its lid, seen at a slant, a few hundred; development
# and reproduction scenes with distractors, docs/perception_measurements.md "twenty-sixth session: can26").
OVERHANG_AREA_FULL = 0.4 / 0.15
OVERHANG_VOXEL = 0.005
# Inside the wall by this much (metres; the wall's thickness and the fit's error) counts as the vessel's cavity.
CAVITY_MARGIN = 0.006
# What fills a vessel's cavity and rises more than CONTENT_OVER (metres) over its rim, joined in steps under
# CONTENT_LINK (about two map voxels of the fine map), is content, not a lid (`filled`). Not tuned: the first values.
CONTENT_OVER = 0.005
CONTENT_LINK = 0.006
# The intruded share (see `intruded`: the area of other surfaces inside the cavity over the opening's area) at
# which a pose scores 0 (linear from 0 at none); with the threshold 0.85 a pose is rejected above 0.02 (for the
# glass ~3 voxels of 5 mm). Right cups, mugs and glasses facing down: 0-0.004; glasses and a cup fitted over
# drink cans and a bottle 0.03-0.53 (development sink and table scenes with distractors, docs/perception.md
# "Through the wall").
INTRUDED_FULL = 0.13
# Inside the wall by this much (metres: the wall's own thickness, ~2 mm, and the fit's error) counts for
# `intruded`; points are binned in voxels of this size (metres) so that the area, not the point density, counts.
INTRUDE_MARGIN = 0.004
INTRUDE_VOXEL = 0.005
# The straight part (perception/straight.py: about -1 for the vessel's own wall, +1 for a straight cylinder) at
# which a pose scores 0 (linear from 0 at 0 and below); with the threshold 0.85 a pose is rejected above 0.3.
STRAIGHT_FULL = 0.3 / 0.15
# The sunk share (of the model's surface inside solid matter, see `sunk`) at which a pose scores 0 (linear from 0
# at none); with the threshold 0.85 a pose is rejected above 0.0075 (15 of 2000 surface points). Every pose of the
# development table scenes with distractors (surfaces from the data) read 0, right or wrong; a glass fitted upside
# down on a can, its rim 1.4-2 cm through the support, 0.025-0.04 (docs/perception_measurements.md, "thirty-first
# session: fp31").
SUNK_FULL = 0.05


@dataclass
class Verification:
    seen: float
    explained: float
    free_space: float
    normals: float
    fine: float = 1.0  # set by the pipeline on the final poses (fine_share)
    continued: float = 0.0  # set by the pipeline on the final poses of tall vessels (continuation)
    filled: float = 0.0  # set by the pipeline on the final poses of open vessels (filled)
    overhang: float = 0.0  # set by the pipeline on the final poses of tall vessels not standing (overhang)
    intruded: float = 0.0  # set by the pipeline on the final poses of tall vessels not facing up (intruded)
    overhang_area: float = 0.0  # set by the pipeline on the final poses of tall vessels not standing (overhang_area)
    straight: float = 0.0  # set by the pipeline on the final poses of tall vessels (straight.straightness)
    sunk: float = 0.0  # set by the pipeline on the final poses, with surfaces found in the data (sunk)
    normals_segment: float | None = None  # `normals` as judged on the whole segment (the pipeline's fine check
    # may raise `normals` to its value over the points no other pose explains: facing_unclaimed)

    def parts(self) -> dict[str, float]:
        return {"seen": self.seen, "explained": self.explained, "free_space": self.free_space, "normals": self.normals,
                "fine": self.fine, "continued": self.continued, "filled": self.filled, "overhang": self.overhang,
                "intruded": self.intruded, "overhang_area": self.overhang_area, "straight": self.straight,
                "sunk": self.sunk}

    @property
    def score(self) -> float:
        judged = self.seen + self.free_space
        through = self.free_space / judged if judged > 0 else 1.0
        return max(0.0, min(1.0 - through, self.normals, self.fine / FINE_FULL,
                            1.0 - self.continued / CONTINUED_FULL, 1.0 - self.filled / FILLED_FULL,
                            1.0 - self.overhang / OVERHANG_FULL, 1.0 - self.overhang_area / OVERHANG_AREA_FULL,
                            1.0 - self.intruded / INTRUDED_FULL, 1.0 - max(0.0, self.straight) / STRAIGHT_FULL,
                            1.0 - self.sunk / SUNK_FULL))


def verify(points: np.ndarray, normals: np.ndarray, entry: ModelEntry, T_base_obj: np.ndarray,
           seen: float, free_space: float, voxel: float) -> Verification:
    """The checks for a pose of `entry` against a segment (points and camera-facing normals, base frame);
    `seen` and `free_space` from the Scorer (model->query ratio and free-space share of the visible model)."""
    if len(points) == 0:
        return Verification(seen, 0.0, free_space, 0.0)
    near = on_surface(points, None, entry, T_base_obj, voxel)
    explained = float(near.mean())
    if not near.any():
        return Verification(seen, 0.0, free_space, 0.0)
    facing = on_surface(points[near], normals[near], entry, T_base_obj, voxel)
    return Verification(seen, explained, free_space, float(facing.mean()))


def surface_noise(points: np.ndarray, n: int = 300, radius: float = 0.008) -> float:
    """How rough the map's surfaces are: the median RMS distance of points to their local plane (neighbourhoods
    of `radius` around `n` sampled points; dishware, boxes and sinks are smooth at this scale, so what is left is
    the depth noise). Metres; 0 when there are too few points."""
    if len(points) < 50:
        return 0.0
    rng = np.random.default_rng(0)
    tree = cKDTree(points)
    rms = []
    for i in rng.choice(len(points), min(n, len(points)), replace=False):
        idx = tree.query_ball_point(points[i], radius)
        if len(idx) < 10:
            continue
        X = points[idx] - points[idx].mean(axis=0)
        rms.append(np.sqrt(max(np.linalg.eigvalsh(X.T @ X / len(X))[0], 0.0)))
    return float(np.median(rms)) if rms else 0.0


def fine_tolerance(noise: float) -> float:
    """Distance (metres) within which a point lies on a right pose's surface, given the map's surface noise."""
    return max(FINE_TOL_MIN, FINE_TOL_NOISE * noise)


def patch_normals(points: np.ndarray, cam_centres: np.ndarray, radius: float = 0.006,
                  flatness: float = 4.0) -> np.ndarray:
    """Normals of points (base frame) from their neighbours within `radius`, facing the camera that saw each
    (`cam_centres`, one per point). NaN where the neighbourhood has no surface direction: fewer than 5
    neighbours, or a strip rather than a patch (its middle spread under `flatness` x its smallest: a thin rim or
    an edge, whose normal is any direction across it)."""
    out = np.full(points.shape, np.nan)
    if len(points) < 5:
        return out
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc.estimate_covariances(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=16))
    C = np.asarray(pc.covariances)
    w, v = np.linalg.eigh(C)  # ascending
    n = v[:, :, 0]
    flip = np.einsum("ij,ij->i", n, cam_centres - points) < 0
    n[flip] *= -1
    ok = (w[:, 1] > flatness * np.maximum(w[:, 0], 1e-12)) & np.isfinite(w).all(axis=1)
    out[ok] = n[ok]
    return out


def _on(points: np.ndarray, normals: np.ndarray, entry: ModelEntry, T_base_obj: np.ndarray, tol: float) -> np.ndarray:
    """on_surface with a normal where there is one (NaN rows: by position only)."""
    has = np.isfinite(normals).all(axis=1)
    out = np.zeros(len(points), bool)
    if has.any():
        out[has] = on_surface(points[has], normals[has], entry, T_base_obj, tol)
    if (~has).any():
        out[~has] = on_surface(points[~has], None, entry, T_base_obj, tol)
    return out


def claimed_by(points: np.ndarray, normals: np.ndarray, tol: float,
               others: list[tuple[ModelEntry, np.ndarray]]) -> np.ndarray:
    """Which points (camera-facing `normals`, NaN rows by position only) another pose (`others`: (entry,
    T_base_obj)) has on its surface within `tol`."""
    claimed = np.zeros(len(points), bool)
    for e, T in others:
        claimed |= _on(points, normals, e, T, tol)
    return claimed


def facing_unclaimed(points: np.ndarray, normals: np.ndarray, entry: ModelEntry, T_base_obj: np.ndarray,
                     voxel: float, tol: float, others: list[tuple[ModelEntry, np.ndarray]],
                     claimed: np.ndarray | None = None) -> float | None:
    """The `normals` part over a pose's own points (camera-facing `normals`, NaN rows by position only) less those
    another pose (`others`) has on its surface within `tol`; None where no other pose has any. (A stacked item's
    segment, what the item on it left over, also holds the rim of the item under it, fitted later: those points
    lie within a voxel of its underside and face the other way.) `claimed`: `claimed_by(points, normals, tol,
    others)` where the caller has it already."""
    if claimed is None:
        claimed = claimed_by(points, normals, tol, others)
    if not claimed.any() or claimed.all():
        return None
    P, N = points[~claimed], normals[~claimed]
    near = on_surface(P, None, entry, T_base_obj, voxel)
    if not near.any():
        return None
    return float(_on(P[near], N[near], entry, T_base_obj, voxel).mean())


def fine_share(points: np.ndarray, normals: np.ndarray, entry: ModelEntry, T_base_obj: np.ndarray, tol: float,
               others: list[tuple[ModelEntry, np.ndarray]] = (), symmetric: bool = False) -> float:
    """Of the segment's points (camera-facing normals, NaN rows where there is no surface direction:
    `patch_normals`) that no other pose (`others`: (entry, T_base_obj)) has on its surface within `tol`, the
    share on this pose's surface within `tol`, facing the same way (`fine_fit`, which also gives the pose it
    was judged at)."""
    return fine_fit(points, normals, entry, T_base_obj, tol, others, symmetric)[0]


def fine_fit(points: np.ndarray, normals: np.ndarray, entry: ModelEntry, T_base_obj: np.ndarray, tol: float,
             others: list[tuple[ModelEntry, np.ndarray]] = (), symmetric: bool = False,
             claimed: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """`fine_share` and the pose it is read at. A neighbour's points in the segment (touching items) do not count
    against a pose.

    The pose is judged as the segment's best fit near it: refined first by a short point-to-plane ICP on those
    points (correspondences within 6 mm, then 3 mm; `symmetric`: a surface of revolution, no turn about its
    axis). An item seen as a sliver (a nested cup's rim) is registered a few millimetres off, which is right
    for grasping and within 0.1 diameter, but at 3 mm would read as a shape that does not fit; a can taken
    for a tapered cup stays off wherever it is slid. The refined pose is returned (the given one where there
    was nothing to refine on, or the refinement moved it by more than a centimetre). `claimed`:
    `claimed_by(points, normals, tol, others)` where the caller has it already."""
    if len(points) == 0:
        return 0.0, T_base_obj
    if claimed is None:
        claimed = claimed_by(points, normals, tol, others)
    mine = ~claimed | _on(points, normals, entry, T_base_obj, tol)
    if not mine.any():
        return 0.0, T_base_obj
    P, N = points[mine], normals[mine]
    T = T_base_obj
    has = np.isfinite(N).all(axis=1)
    if has.sum() >= 12:
        step = max(1, int(has.sum()) // FINE_FIT_POINTS)
        T = inv(icp_to_model(P[has][::step], entry, inv(T_base_obj), (2 * tol, tol), iters=8, qn=N[has][::step],
                             symmetric=symmetric))
        # a refinement is a nudge: one that moves the pose by more than a centimetre is no judgement of it
        if np.linalg.norm(T[:3, 3] - T_base_obj[:3, 3]) > 0.01:
            T = T_base_obj
    return float(_on(P, N, entry, T, tol).mean()), T


def _unexplained_along_axis(points: np.ndarray, model_points: np.ndarray, T_base_obj: np.ndarray,
                            explained: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """The unexplained `points` in the object frame of a surface of revolution about z (`model_points`), with the
    model's axis (x, y), each model point's radius from it, and the model's lowest and highest z."""
    Ti = inv(T_base_obj)
    q = points[~explained] @ Ti[:3, :3].T + Ti[:3, 3]
    axis = np.median(model_points[:, :2], axis=0)
    r_model = np.linalg.norm(model_points[:, :2] - axis, axis=1)
    return q, axis, r_model, model_points[:, 2].min(), model_points[:, 2].max()


def continuation(points: np.ndarray, model_points: np.ndarray, T_base_obj: np.ndarray, explained: np.ndarray,
                 n_own: int, reach: float = CONTINUE_REACH, only_along: bool = False, on_base: bool = False) -> float:
    """Of map points near a pose (`points`, base frame; `explained`: those this pose or another one puts on its
    surface), how many lie past the model's ends along its axis (up to `reach`) within that end's radius, per
    point of the pose's own (`n_own`). A model of a surface of revolution about its z axis (`model_points`,
    object frame). An item that ends where the model ends leaves nothing there but what its neighbours explain;
    a bottle fitted by a cup continues past the cup's rim or base.

    `only_along` (a standing vessel): an end past which the unexplained surface also reaches clearly wider than
    the end (`ACROSS_RING` radially past it, at least `ACROSS_SHARE` of what lies within it) is not judged:
    what lies there goes across the axis (a plate or a lying bottle over a cup's rim, the plate or the board a
    vessel stands on, a neighbour beside it), not along it. A bottle's body, shoulder and neck going on past an
    upright or upside-down cup or glass stay within the end's radius. Nor is an end judged where what lies past it
    within its radius covers under `AROUND_SPAN` degrees around the axis (`around_span`): one side only (a cup
    leaning on a mug's rim), not a body going on around the axis.

    `on_base` (a vessel standing on its base, upright, or one whose closed base the depth shows: `base_seen`): the
    end past its base (the model's lowest z) is not judged: what lies under a standing item within its footprint
    is what it stands on, however narrow (a drink can under a glass, the glass a glass is nested in, whose wall
    goes on under the upper one's base), and what lies on a seen base is another item resting on it. A longer object
    fitted by the vessel still goes on past its rim (a bottle's shoulder and neck) or through its opening
    (`filled`)."""
    if n_own == 0 or len(points) == 0:
        return 0.0
    q, axis, r_model, z0, z1 = _unexplained_along_axis(points, model_points, T_base_obj, explained)
    r_q = np.linalg.norm(q[:, :2] - axis, axis=1)
    # Past each end, within that end's own radius (1 cm more: a bottle a little wider than a cup's base; not the
    # reach of a mug's handle, beside which a neighbour may lie).
    n_past = 0
    ends = [(r_model[model_points[:, 2] > z1 - 0.005].max(), (q[:, 2] > z1) & (q[:, 2] < z1 + reach))]
    if not on_base:
        ends.append((r_model[model_points[:, 2] < z0 + 0.005].max(), (q[:, 2] < z0) & (q[:, 2] > z0 - reach)))
    for r_end, beyond in ends:
        inner = int(np.count_nonzero(beyond & (r_q < r_end + 0.01)))
        if only_along and inner:
            wide = np.count_nonzero(beyond & (r_q > r_end + ACROSS_RING[0]) & (r_q < r_end + ACROSS_RING[1]))
            if wide >= ACROSS_SHARE * inner:
                continue
            sel = beyond & (r_q < r_end + 0.01)
            if around_span(q[sel, :2] - axis) < AROUND_SPAN:
                continue
        n_past += inner
    return float(n_past / n_own)


def base_seen(points: np.ndarray, normals: np.ndarray, model_points: np.ndarray, T_base_obj: np.ndarray,
              tol: float, voxel: float = BASE_VOXEL) -> float:
    """How much of a vessel's closed base the depth shows as a closed surface: of the base disc's area (within
    `BASE_INNER` of its radius; `model_points` object frame, axis z, the base at the lowest z), the share of
    `voxel` squares that hold a point (`points`, base frame: the pose's own) within `tol` of the base's plane
    on its outer side and facing out along the axis (`normals`, facing the cameras; NaN: no direction).

    An item whose base is seen ends there: what lies past a seen base within its radius is another item resting
    on it (a sponge on an upside-down mug), not the same body going on (a bottle fitted by a cup continues
    through where the cup's base would be, and that disc is not seen: its wall, shoulder or neck is there)."""
    if len(points) == 0:
        return 0.0
    Ti = inv(T_base_obj)
    q = points @ Ti[:3, :3].T + Ti[:3, 3]
    nz = normals @ Ti[:3, :3].T
    axis = np.median(model_points[:, :2], axis=0)
    z0 = model_points[:, 2].min()
    r_model = np.linalg.norm(model_points[:, :2] - axis, axis=1)
    r_base = BASE_INNER * r_model[model_points[:, 2] < z0 + 0.005].max()
    xy = q[:, :2] - axis
    cap = (np.abs(q[:, 2] - z0) < tol) & (np.linalg.norm(xy, axis=1) < r_base) & (nz[:, 2] < -BASE_FACING)
    if not cap.any():
        return 0.0
    cells = {tuple(c) for c in np.floor(xy[cap] / voxel).astype(int)}
    g = np.arange(-r_base, r_base + voxel, voxel)
    gx, gy = np.meshgrid(g, g)
    disc = np.hypot(gx + 0.5 * voxel, gy + 0.5 * voxel) < r_base
    return float(min(1.0, len(cells) / max(1, int(disc.sum()))))


def around_span(xy: np.ndarray, bin_deg: float = AROUND_BIN, min_share: float = AROUND_MIN) -> float:
    """Degrees of directions around an axis that points cover (`xy`: offsets from the axis, across it): 360 less
    the longest run of empty `bin_deg` bins (a bin counts with at least `min_share` of the points, 2 at least)."""
    if len(xy) == 0:
        return 0.0
    nb = int(round(360 / bin_deg))
    b = (np.floor(np.degrees(np.arctan2(xy[:, 1], xy[:, 0])) % 360 / bin_deg).astype(int)) % nb
    full = np.bincount(b, minlength=nb) >= max(2, min_share * len(xy))
    if not full.any():
        return 0.0
    # the longest circular run of empty bins
    k = int(np.argmax(full))
    run = gap = 0
    for x in np.roll(~full, -k):
        run = run + 1 if x else 0
        gap = max(gap, run)
    return float(360 - gap * bin_deg)


def filled(points: np.ndarray, model_points: np.ndarray, T_base_obj: np.ndarray, explained: np.ndarray,
           n_own: int, margin: float = CAVITY_MARGIN) -> float:
    """Of map points near a pose of an open vessel (cup, mug, glass, bowl; `model_points` object frame, its axis
    z, opening at the top; `explained`: points this pose or another one puts on its surface), how many lie
    inside its cavity, per point of the pose's own (`n_own`): within the wall (the wall's radius at that
    height less `margin`) and between the base and the rim (3 mm over it). A real vessel's cavity shows its
    own inner wall and floor, or an item nested in it (another pose's points); a can or a closed box fitted
    by a cup or a glass puts its lid (flat, at the rim, across the opening) there."""
    if n_own == 0 or len(points) == 0:
        return 0.0
    q, axis, r_model, z0, z1 = _unexplained_along_axis(points, model_points, T_base_obj, explained)
    inside = (q[:, 2] > z0) & (q[:, 2] < z1 + 0.003)
    inside &= np.linalg.norm(q[:, :2] - axis, axis=1) < _wall_at(model_points, r_model, z0, z1, q[:, 2]) - margin
    inside &= ~_sticking_out(q, inside, axis, r_model[model_points[:, 2] > z1 - 0.005].max(), z1)
    return float(inside.sum() / n_own)


def _sticking_out(q: np.ndarray, inside: np.ndarray, axis: np.ndarray, r_rim: float, z1: float,
                  over: float = CONTENT_OVER, link: float = CONTENT_LINK) -> np.ndarray:
    """Which of the cavity points `inside` (`q`: unexplained points, object frame of a vessel with its rim at
    `z1`, radius `r_rim`) belong to a body that rises out of the opening: joined (steps under `link`) to
    unexplained points more than `over` above the rim within the opening's radius. Content (a scrap, a spoon
    standing in a mug) sticks out of a vessel; a can's lid across the opening of a cup fitted over the can ends
    at the rim (a can going on past the rim is `continued`)."""
    out = np.zeros(len(q), bool)
    top = (q[:, 2] > z1 + over) & (np.linalg.norm(q[:, :2] - axis, axis=1) < r_rim)
    if not inside.any() or not top.any():
        return out
    # the body: cavity points and points over the opening, grown from those above the rim
    body = np.nonzero(inside | ((q[:, 2] > z1 - 0.01) & (np.linalg.norm(q[:, :2] - axis, axis=1) < r_rim + link)))[0]
    tree = cKDTree(q[body])
    reached = np.isin(body, np.nonzero(top)[0])
    frontier = np.nonzero(reached)[0]
    while len(frontier):
        nxt = np.unique(np.concatenate([np.asarray(n, int) for n in tree.query_ball_point(q[body[frontier]], link)]
                                       + [np.zeros(0, int)]))
        nxt = nxt[~reached[nxt]]
        reached[nxt] = True
        frontier = nxt
    out[body[reached]] = True
    return out & inside


def _wall_at(model_points: np.ndarray, r_model: np.ndarray, z0: float, z1: float, z: np.ndarray) -> np.ndarray:
    """The wall's radius at heights `z` (object frame): per 5 mm of height from `z0` to `z1`, the median radius
    `r_model` of the model's points there (the wall's two sides; a mug's handle is a small share of a slice)."""
    edges = np.arange(z0, z1 + 0.005, 0.005)
    b_model = np.clip(np.digitize(model_points[:, 2], edges) - 1, 0, len(edges) - 1)
    wall = medians_per_bin(r_model, b_model, len(edges))
    return wall[np.clip(np.digitize(z, edges) - 1, 0, len(edges) - 1)]


def medians_per_bin(values: np.ndarray, bins: np.ndarray, n_bins: int) -> np.ndarray:
    """`np.median(values[bins == b])` for every bin b in range(n_bins) (0.0 for an empty bin), from one sort
    instead of a pass over the values per bin (the wall profile was a pass per 5 mm slice, at every check of
    every vessel pose). The same numbers: the middle value of each bin's sorted values, or the mean of the two
    middle ones, (a + b) / 2, as np.median takes them."""
    values = np.asarray(values, float)
    order = np.lexsort((values, bins))
    s = values[order]
    counts = np.bincount(bins, minlength=n_bins)[:n_bins]
    start = np.cumsum(counts) - counts
    out = np.zeros(n_bins)
    has = counts > 0
    hi = start[has] + counts[has] // 2
    lo = np.where(counts[has] % 2 == 1, hi, hi - 1)
    out[has] = (s[lo] + s[hi]) / 2.0
    return out


def overhang(points: np.ndarray, model_points: np.ndarray, T_base_obj: np.ndarray, explained: np.ndarray,
             n_own: int, band: tuple[float, float] = OVERHANG_BAND, plane: float = OVERHANG_PLANE) -> float:
    """Of map points near a pose of a vessel (`model_points` object frame, its axis z, its closed base at the
    lowest z; `explained`: points this pose or another one puts on its surface), how many lie in the plane of
    its base (within `plane`) just past the base's edge (`band`, radially), per point of the pose's own
    (`n_own`). A vessel's base ends at its edge: beside it is empty space or another item. A closed cylinder
    wider than the base fitted by the vessel upside down or lying (a drink can's lid under a glass's base) goes
    on past the edge in the same plane: the segment is wider there than the model."""
    if n_own == 0 or len(points) == 0:
        return 0.0
    return float(_overhang_ring(points, model_points, T_base_obj, explained, band, plane)[0].sum() / n_own)


def overhang_area(points: np.ndarray, model_points: np.ndarray, T_base_obj: np.ndarray, explained: np.ndarray,
                  band: tuple[float, float] = OVERHANG_BAND, plane: float = OVERHANG_PLANE,
                  voxel: float = OVERHANG_VOXEL) -> float:
    """The points `overhang` counts, as the area they cover in the base's plane (`voxel` squares across the
    axis), over the base's area. Per point of the pose's own, a drink can's lid wider than a glass's base is
    diluted by the can's side, which the glass explains (thousands of points), while the lid, seen at a slant
    from a camera facing the base end, gives a few hundred; but it covers the ring past the base's edge all
    round, where beside a real vessel's base there is empty space or, on one side, a neighbour."""
    ring, q = _overhang_ring(points, model_points, T_base_obj, explained, band, plane)
    if not ring.any():
        return 0.0
    axis = np.median(model_points[:, :2], axis=0)
    r0 = np.linalg.norm(model_points[model_points[:, 2] < model_points[:, 2].min() + 0.005, :2] - axis, axis=1).max()
    cells = len(np.unique(np.floor(q[ring, :2] / voxel).astype(np.int64), axis=0))
    return float(cells * voxel ** 2 / (np.pi * r0 ** 2))


def _overhang_ring(points: np.ndarray, model_points: np.ndarray, T_base_obj: np.ndarray, explained: np.ndarray,
                   band: tuple[float, float], plane: float) -> tuple[np.ndarray, np.ndarray]:
    """Which unexplained points (`q`: those of `points` not `explained`, in the object frame) lie in the plane of
    the model's base (within `plane`) `band` past its edge, radially; and `q`."""
    q, axis, r_model, z0, _ = _unexplained_along_axis(points, model_points, T_base_obj, explained)
    if len(q) == 0:
        return np.zeros(0, bool), q
    r0 = r_model[model_points[:, 2] < z0 + 0.005].max()
    r_q = np.linalg.norm(q[:, :2] - axis, axis=1)
    return (np.abs(q[:, 2] - z0) < plane) & (r_q > r0 + band[0]) & (r_q < r0 + band[1]), q


def within_wall(q: np.ndarray, model_points: np.ndarray, margin: float) -> np.ndarray:
    """Which points (`q`, object frame of a surface of revolution about z: `model_points`) lie between the model's
    base and rim and more than `margin` inside its wall (the model's median radius at their height, 5 mm slices;
    a negative margin reaches outside it)."""
    axis = np.median(model_points[:, :2], axis=0)
    r_model = np.linalg.norm(model_points[:, :2] - axis, axis=1)
    z0, z1 = model_points[:, 2].min(), model_points[:, 2].max()
    wall = _wall_at(model_points, r_model, z0, z1, q[:, 2])
    return (q[:, 2] > z0) & (q[:, 2] < z1) & (np.linalg.norm(q[:, :2] - axis, axis=1) < wall - margin)


def sunk(model_points: np.ndarray, T_base_obj: np.ndarray, inside_solid: Callable[[np.ndarray], np.ndarray]) -> float:
    """The share of a posed model's surface (`model_points`, object frame, evenly over the surface; posed at
    `T_base_obj`) that `inside_solid` (base-frame points -> bool: inside known solid matter) says lies inside solid
    matter. A real item rests on a support or leans on a wall: its surface reaches at most the fit's error into
    them."""
    if len(model_points) == 0:
        return 0.0
    P = model_points @ T_base_obj[:3, :3].T + T_base_obj[:3, 3]
    return float(np.mean(inside_solid(P)))


def intruded(points: np.ndarray, model_points: np.ndarray, T_base_obj: np.ndarray, explained: np.ndarray,
             margin: float = INTRUDE_MARGIN, voxel: float = INTRUDE_VOXEL) -> float:
    """Of map points near a pose of a vessel (`model_points` object frame, its axis z, opening at the top;
    `explained`: those on this pose's surface or on the surface of an item nested in it), the area those inside
    its cavity cover (more than `margin` inside the wall, between the base's top and the rim; counted in
    `voxel` cubes, so that the area counts and not how densely the views sampled it), over the opening's area.

    A vessel's cavity holds its own inner wall and floor, or an item nested in it; nothing else passes through
    its wall. A glass fitted upside down or lying over a drink can (a closed cylinder of about its width, but
    shorter) reaches past the can's end, where the items the can rests on are seen: their surfaces pass through
    the glass's wall and lie inside its cavity. (Upright, the can's lid across the opening is `filled`.)"""
    if len(points) == 0:
        return 0.0
    q, axis, r_model, z0, z1 = _unexplained_along_axis(points, model_points, T_base_obj, explained)
    inside = within_wall(q, model_points, margin) & (q[:, 2] > z0 + 0.005)  # above the base's own thickness
    if not inside.any():
        return 0.0
    cells = len(np.unique(np.floor(q[inside] / voxel).astype(np.int64), axis=0))
    r_rim = r_model[model_points[:, 2] > z1 - 0.005].max()
    return float(cells * voxel ** 2 / (np.pi * r_rim ** 2))
