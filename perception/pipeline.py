"""The perception pipeline, top to bottom: views -> masks -> instances -> map -> features -> candidates -> poses.

    perceiver = Perceiver(PerceptionSettings(), Inventory.builtin(), Cell())
    result = perceiver.perceive(views)      # result.poses: list[ObjectPose] in the base frame

Each stage is its own module and runnable alone; this file only wires them and times them.
"""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from kitchenbot.perception.associate import associate
from kitchenbot.world.cell import Cell
from kitchenbot.perception.cell_check import CellCheck, check_cell
from kitchenbot.perception.database import CadDatabase
from kitchenbot.perception.detect import Detection, Detector, PassThroughSegmenter, Segmenter
from kitchenbot.perception import backends
from kitchenbot.perception.features import FusedCloud, fuse_instance, voxel_keys, with_point_features
from kitchenbot.world.inventory import Inventory
from kitchenbot.perception.map import InstanceMap, align_to_cell, align_views, build_map, consolidate
from kitchenbot.perception.register import (Hypothesis, RegistrationConfig, Scorer, clean_depths, propose, refine,
                                           on_surface, screen_candidate, snap_upright, surface_fit)
from kitchenbot.perception.rgbd import check_view
from kitchenbot.perception.segment_geometric import GeometricSegmenter
from kitchenbot.perception.settings import PerceptionSettings
from kitchenbot.perception.surfaces import SurfaceMap, find_surfaces
from kitchenbot.perception.refit import RefitMemo, refit_beside_unexplained
from kitchenbot.perception.nest import add_nest_levels
from kitchenbot.perception.straight import straightness
from kitchenbot.perception.track import MapChange, best_prior, moved
from kitchenbot.perception.types import ObjectPose, View
from kitchenbot.perception.verify import (BASE_SEEN, base_seen, claimed_by, continuation, facing_unclaimed, filled,
                                          fine_fit, fine_tolerance, intruded, overhang, overhang_area, patch_normals,
                                          sunk, surface_noise, verify, within_wall)
from kitchenbot.perception.verify import Verification
from kitchenbot.transforms import inv

log = logging.getLogger(__name__)

# Classes whose items nest / stack on copies of themselves (a plate on a plate, a bowl in a bowl, a cup in a
# cup): what a pose of one of them leaves over is re-fitted at the tight tolerance.
NESTING_CLASSES = ("plate", "bowl", "cup")
# rad: the least angle between the axes of two nesting items for one to lean in the other (Perceiver._leaning_in):
# below it they are stacked or rest one in the other (`_stacked`, `_resting_in`), which use 30 deg
LEAN_IN_MIN = np.radians(30.0)
# How far a fit started upright (or upside down) may lean and still count as "near upright" (settled stacks in
# the simulator lean up to ~30 deg; beyond that the gravity prior is no prior).
MAX_REST_TILT = np.radians(30)
# Voxels: a point within this of a pose's surface (facing the same way) lies on it, for deciding between fits
# (which lean is right, which of two twins stays, whether a stacked copy is a duplicate): finer than the
# overlap score's one voxel, coarser than the depth noise at the scan distance (~1-2 mm).
SURFACE_TOL = 0.3
# Classes whose fits are checked upside down too (tall, thin-walled, nearly as wide at the top as at the base); a
# refine per object, so not for plates and bowls, whose sides the fits have not confused.
FLIP_CLASSES = ("cup", "mug", "glass")
# The `sunk` part is read on about this many of the model's surface points (evenly over it).
SUNK_POINTS = 2000
# Metres: a map point this close to a pose's surface is on it, when judging what continues past its ends (the
# sensor's noise and the fit's error; another pose's surface gets 1.5x this).
FINE_ON_TOL = 0.004
# Tall vessels open at the top, judged by what fills their cavity (verify.filled: a can's lid is no opening; a
# bowl is left out: what lies in one, a spoon or food scraps, is no evidence against it).
CAVITY_CLASSES = ("cup", "mug", "glass")
# Metres: an item nested in a vessel (verify.intruded) lies within its wall, up to this much outside it (the fits'
# error and a nested cup's wall on the outer one's inner wall).
NESTED_SLACK = 0.004
# Degrees below the horizontal a vessel's opening must face for verify.intruded to judge it: a lying vessel's
# mouth (within this of the horizontal) may have a neighbour's edge poking into it. Right poses facing up or
# sideways read up to 0.04 on development scans (a tilted mug, a leaning cup), right ones facing down 0.004.
INTRUDE_BELOW = 10.0
# Of the points on a pose's surface (3 mm, facing the same way), under this share not also on the surface of a pose
# that overlaps it: the pose is a second fit of what the others explain (Perceiver._drop_redundant). A compromise
# fit between two resting plates measured 4 %; the lower item of a stack owns its visible rim (over 40 %).
REDUNDANT_SHARE = 0.1
# perceive(..., region=): an instance with this share of its points in the region is fitted (an item whose origin
# lies in the region may reach well out of it: a plate across its border)
REGION_SHARE = 0.2
# Of the model's height: two copies of a tall vessel on one axis, turned opposite ways, with their centres closer
# than this along it overlap along it by a fifth of the height or more: their walls pass through each other
# (Perceiver._through_each_other; copies rim to rim or base to base, touching, are one height apart).
TURNED_OVERLAP = 0.8
# Quick (screening) score by which a candidate model may trail the best one and still be refined. Refinement raised
# a pick's score by at most 0.18 over its quick score on development scenes (and lowered 3 in 4); a model trailing by
# more than this never won there (perception_measurements.md, pose25).
DOMINATED_MARGIN = 0.25
# Voxels: gravity-aligned starts this close (and turned alike) are one start for the near-upright refinement
SAME_START = 0.5
# Candidate models (by appearance similarity) screened for every instance. One ranked lower is screened only when
# those before it left no hypothesis whose quick score reaches the overlap gate (settings.min_overlap), or when the
# segment is larger than the leading model (several touching items: a bowl in a pile was the third candidate and
# won). The third candidate's screening was 13-15 % of the estimate CPU (perception_measurements.md, pose26).
SCREENED_CANDIDATES = 2


def map_seg_ms(timings: dict[str, float]) -> float:
    """Map + segmentation time of one scan: every stage but pose estimation and the parts timed inside it
    (named "pose.*", e.g. "pose.refit"), which the "pose" time already holds."""
    return sum(v for k, v in timings.items() if k != "pose" and not k.startswith("pose."))


def scan_total_ms(timings: dict[str, float]) -> float:
    """Whole time of one scan: every stage once (the parts timed inside "pose" are in it already)."""
    return sum(v for k, v in timings.items() if not k.startswith("pose."))


@dataclass
class PerceptionResult:
    poses: list[ObjectPose]
    map: InstanceMap  # fused points (x, y, z) with instance ids, base frame
    detections: list[list[Detection]] = field(default_factory=list)  # per view
    timings_ms: dict[str, float] = field(default_factory=dict)  # per stage, whole call
    pose_ms: list[float] = field(default_factory=list)  # per instance: features + candidates + registration
    rejected: int = 0  # instances no inventory model explained
    views: list[View] = field(default_factory=list)  # the views as used (poses after alignment)
    timings_cpu_ms: dict[str, float] = field(default_factory=dict)  # process CPU time per stage
    pose_cpu_ms: list[float] = field(default_factory=list)  # process CPU time per instance
    surfaces_from: str = "cell"  # "cell": the configured cell's; "data": found in the scan; "plane": per view
    cell_check: CellCheck | None = None  # with use_cell="auto": how the configured cell fitted the scan
    surfaces: SurfaceMap | None = None  # the surfaces found in the scan ("data")
    tracked: int = 0  # instances posed from a prior (perceive(priors=), perception/track.py; before the fine check)
    kept: int = 0  # of those, priors kept as they were, unchecked (perceive(prior_map=): track.unchanged)

    @property
    def map_points(self) -> np.ndarray:
        return self.map.points

    @property
    def map_ids(self) -> np.ndarray:
        return self.map.ids


def make_detector(settings: PerceptionSettings, cell: Cell | None) -> tuple[Detector, Segmenter]:
    """The configured detector and segmenter (learned ones are registered by issue 4's backends)."""
    if settings.detector != "geometric" or settings.segmenter != "geometric":  # learned: perception/backends.py
        return backends.make_detector(settings, cell)
    if settings.detector == "geometric":
        det = GeometricSegmenter(cell)
    else:
        raise ValueError(f"perception.detector: {settings.detector!r} needs the learned backends, which are not "
                         "installed here; use 'geometric'")
    if settings.segmenter == "geometric":
        seg: Segmenter = det if isinstance(det, GeometricSegmenter) else PassThroughSegmenter()
    else:
        raise ValueError(f"perception.segmenter: {settings.segmenter!r} needs the learned backends; use 'geometric'")
    return det, seg


class Perceiver:
    def __init__(self, settings: PerceptionSettings | None = None, inventory: Inventory | None = None,
                 cell: Cell | None = None, detector: Detector | None = None, segmenter: Segmenter | None = None,
                 database: CadDatabase | None = None, use_cell: bool | str | None = None):
        """`use_cell`: True / "always": segment with the configured cell's surfaces; False / "never": with the
        support surfaces and walls found in each scan (perception/surfaces.py), or, for a view without
        gravity (`perceive(..., up=None)`), its dominant plane; "auto": the cell when it fits what the cameras
        see (perception/cell_check.py), else the surfaces found, with a warning and `result.cell_check`.
        None: the setting `perception.use_cell` (default "auto")."""
        self.settings = settings or PerceptionSettings()
        self.inventory = inventory or Inventory.builtin()
        use_cell = self.settings.use_cell if use_cell is None else use_cell
        mode = ("always" if use_cell else "never") if isinstance(use_cell, bool) else use_cell
        if mode not in ("always", "never", "auto"):
            raise ValueError(f"use_cell: expected True, False, 'always', 'never' or 'auto', got {use_cell!r}")
        self.cell_mode = mode
        self.cell = (cell or Cell()) if mode != "never" else None
        self._active_cell: Cell | None = self.cell if mode == "always" else None  # per scan
        self._surfaces: SurfaceMap | None = None  # per scan, when no cell is used
        d, s = make_detector(self.settings, self.cell) if detector is None else (detector, None)
        self.detector = d
        self.segmenter = segmenter or s or PassThroughSegmenter()
        self.img_enc = backends.make_image_encoder(self.settings)  # colour | none | learned (fusion on/off)
        self.pt_enc = backends.make_point_encoder(self.settings.point_encoder)  # fpfh | plug-ins
        self._db = database
        self._depths: list[np.ndarray] | None = None  # per scan: depth with unknown = 0, shared by the scorers
        self._normals: tuple[int, dict] | None = None  # per scan: (id of the map's points, {point set: normals})
        self._fine_ctx: tuple | None = None  # per map: (its points, their KD-tree, the fine tolerance)
        self._fine_memo: dict[tuple, object] = {}  # per map: the fine check's parts and pieces (`_fine_parts`)
        self._query_memo: tuple[list, dict] | None = None  # per scan: (its views, {instance: query}) (`_query`)
        self.settings_seed = 0
        self.refit_memo = RefitMemo()  # re-fits beside what is left that failed, not tried again unchanged
        st = self.settings
        self.reg_cfg = RegistrationConfig(voxel=st.voxel_size, top_k=st.top_k, candidate_threshold=st.candidate_threshold,
                                          min_overlap=st.min_overlap)

    @property
    def database(self) -> CadDatabase:
        """The CAD feature database (built on first use, cached on disk)."""
        if self._db is None:
            self._db = CadDatabase.build(self.inventory, self.img_enc, self.pt_enc, self.settings.voxel_size,
                                         self.settings.cache_dir)
        return self._db

    # ---- the stages ---------------------------------------------------------------------------------------
    def _geometric(self) -> list[GeometricSegmenter]:
        """The geometric segmenters this perceiver uses (told per scan which surfaces to remove)."""
        out = [x for x in (self.detector, self.segmenter, getattr(self.segmenter, "geometric", None))
               if isinstance(x, GeometricSegmenter)]
        return out

    def perceive(self, views: list[View], up: np.ndarray | None = np.array([0.0, 0.0, 1.0]),
                 region=None, priors: list[ObjectPose] | None = None,
                 prior_map: np.ndarray | None = None) -> PerceptionResult:
        """Object poses from one scan. `up`: the base frame's up (against gravity); None when the views' frame
        has no known gravity (a BOP image without world poses): the dominant plane of each view is then the
        support. `region`: a mask over base-frame points (N, 3) -> (N,) bool; only instances with at least
        REGION_SHARE of their points in it are fitted (incremental perception, perception/region.py).
        `priors`: the poses believed before this scan (a re-scan); an instance one of them still explains keeps
        it after a local refinement instead of the global search (pose tracking, perception/track.py).
        `prior_map`: the map points the priors were perceived on; a prior whose surroundings are the same points
        now is kept as it was, with its verification, and not checked again (track.MapChange.unchanged)."""
        timings: dict[str, float] = {}

        cpu: dict[str, float] = {}

        @contextmanager
        def timed(name: str):
            t0, c0 = time.perf_counter(), time.process_time()
            yield
            timings[name] = timings.get(name, 0.0) + 1000 * (time.perf_counter() - t0)
            cpu[name] = cpu.get(name, 0.0) + 1000 * (time.process_time() - c0)

        for k, v in enumerate(views):
            check_view(v, f"views[{k}]")
        o3d.utility.random.seed(self.settings_seed)  # Open3D's RANSAC: same views, same answer
        self._depths = None
        self._normals = None
        self._query_memo = None  # this scan's instance queries (`_query`)
        self._fine_ctx, self._fine_memo = None, {}  # the fine check's map context and memo (`_fine_context`)
        db = self.database
        # Scan poses off (arm repeatability, hand-eye error): with a known cell each view is registered onto the
        # cell's sink (absolute and relative errors at once); without one, the views onto the first view.
        # Which surfaces to remove: the configured cell's ("auto": if it fits the scan once registered onto it,
        # perception/cell_check.py), or those found in the scan.
        check = None
        self._active_cell = None
        if self.cell_mode != "never":
            aligned = views
            if self.cell_mode == "auto":
                # A basin covered by a board (a table over the sink) is seen as covered however the views are
                # registered onto the cell (a level 3 cm over the floor against pose errors of millimetres):
                # known before the registration, which is then not needed (it was most of a table scan's map).
                with timed("cell_check"):
                    check = check_cell(views, self.cell)
                if check.fits or not check.is_covered:
                    check = None
            if self.settings.align_to_cell and check is None:
                with timed("align"):
                    aligned = [align_to_cell([v], self.cell)[0][0] for v in views]
            if self.cell_mode == "auto" and check is None:
                with timed("cell_check"):
                    check = check_cell(aligned, self.cell)
            if check is not None and not check.fits:
                log.warning("perception: %s", check.message)
            if check is None or check.fits:
                self._active_cell, views = self.cell, aligned
        if self._active_cell is None and len(views) > 1 and self.settings.align_views:
            with timed("align"):
                views, _ = align_views(views, self.settings.voxel_size)
        self._surfaces = None
        if self._active_cell is None and up is not None:
            with timed("surfaces"):
                self._surfaces = find_surfaces(views, up)
        for g in self._geometric():
            g.cell, g.surfaces = self._active_cell, self._surfaces
        with timed("segment"):
            dets = backends.detect_and_segment(self.detector, self.segmenter, views)  # batched when learned
        with timed("associate"):
            ids = associate(views, dets, self.settings.iou_threshold)
        with timed("map"):
            m = consolidate(build_map(views, dets, ids))
        self._depths = clean_depths(views)
        poses: list[ObjectPose] = []
        pose_ms: list[float] = []
        pose_cpu_ms: list[float] = []
        rejected = 0
        vox = self.settings.voxel_size
        with timed("pose"):
            queue = list(m.instance_ids)
            next_id = max(queue) + 1 if queue else 0
            if region is not None:
                queue = [i for i in queue if np.mean(region(m.points[m.ids == i])) >= REGION_SHARE]
            ids_out = m.ids.copy()
            used: set[int] = set()  # priors kept (tracked): one instance each
            # which points of this map and of the priors' map are still there: made when a prior first asks
            change = _LazyChange(m.points, prior_map, priors, db, 1.5 * vox) \
                if priors and prior_map is not None else None
            tracked_at: dict[int, tuple[np.ndarray, int]] = {}  # index in `found` of a tracked pose -> (its
            # instance's points, the prior's index)
            splits = 0
            found: list[tuple[Hypothesis, int, np.ndarray]] = []
            parts: set[int] = set()  # ids made by cutting a blob (never cut again)
            blob_of: dict[int, np.ndarray] = {}  # id of such a region -> the blob's voxel centres (Scorer context)
            groups: dict[int, list[np.ndarray]] = {}  # id of a remainder in pieces -> the pieces (map indices)
            # id of what a pose left over -> the points that pose (and those before it in the chain) explained:
            # the item stacked on what is left (Scorer `covered`: the surface hidden under it counts for nothing)
            under: dict[int, np.ndarray] = {}
            while queue:
                iid = queue.pop(0)
                sel = np.nonzero(ids_out == iid)[0]
                if len(sel) < 30:
                    ids_out[sel] = -1
                    continue
                t0, c0 = time.perf_counter(), time.process_time()
                hyp, prior_k = self._track(m.select(sel), views, priors, used, change) \
                    if priors else (None, None)
                if hyp is not None:
                    used.add(prior_k)
                else:
                    covered = _voxel_centres(m.points[under[iid]], vox / 2) if iid in under else None
                    hyp, _query = self.estimate(m.select(sel), views, [f[0] for f in found], covered,
                                                context=blob_of.get(iid))
                pose_ms.append(1000 * (time.perf_counter() - t0))
                pose_cpu_ms.append(1000 * (time.process_time() - c0))
                if iid in groups:
                    # What a pose left over, in several pieces (a lower item's rim peeking out on two sides of
                    # the item on it), was fitted as one. The pose must take each piece whole or leave it (the
                    # pieces it leaves are fitted again, together); one that takes parts of pieces is a
                    # compromise between items: fit the pieces apart.
                    pieces = groups.pop(iid)
                    shares = [] if hyp is None else [self._explained(hyp, m.points[pc]).mean() for pc in pieces]
                    if hyp is None or any(0.3 < f < 0.7 for f in shares) or max(shares) < 0.7:
                        for pc in pieces:
                            ids_out[pc] = next_id
                            if iid in under:
                                under[next_id] = under[iid]
                            queue.insert(0, next_id)
                            next_id += 1
                        continue
                if hyp is None:
                    if len(sel) >= 3000 and iid not in parts:
                        # Several items segmented together and no single model explains enough of them: cut
                        # the blob into item-sized regions and try each (what a region's pose leaves over is
                        # refitted as usual; duplicates are resolved below).
                        blob = _voxel_centres(m.points[sel], vox)
                        for part in _partition(m.points[sel], 0.07):
                            ids_out[sel[part]] = next_id
                            parts.add(next_id)
                            blob_of[next_id] = blob
                            queue.append(next_id)
                            next_id += 1
                        continue
                    rejected += 1
                    continue
                # Points the pose explains belong to it; a large unexplained remainder is another object
                # (stacked / nested / touching items that segmentation could not separate).
                explained = self._explained(hyp, m.points[sel])
                own = sel[explained]
                # After a plate / bowl / cup, what is left over is judged at a tighter tolerance (setting
                # residual_tolerance, 0.8 voxel): the peeking rim of a copy nested under this one lies within
                # 1.5 voxels of this one's surface (stack pitch ~1 cm).
                tight = explained
                if self.inventory[hyp.obj_id].cls in NESTING_CLASSES:
                    tight = self._explained(hyp, m.points[sel], self.settings.residual_tolerance,
                                            self._map_normals(m, sel))
                # Explain away: points of blob parts still waiting in the queue that this pose explains are
                # this object's too (an item cut in two by the blob partition must not be fitted twice).
                waiting_parts = [q for q in queue if q in parts]
                if waiting_parts:
                    pending = np.nonzero(np.isin(ids_out, waiting_parts))[0]
                    near = pending[np.linalg.norm(m.points[pending] - hyp.T_base_obj[:3, 3], axis=1)
                                   < 0.6 * self.inventory[hyp.obj_id].diameter]
                    if len(near):
                        also = near[self._explained(hyp, m.points[near])]
                        ids_out[also] = iid
                        own = np.concatenate([own, also])
                found.append((hyp, iid, own))
                if prior_k is not None:
                    tracked_at[len(found) - 1] = (sel, prior_k)
                rest = sel[~tight]
                above = own if iid not in under else np.concatenate([own, under[iid]])
                if splits < self.settings.max_splits and len(rest) >= 60:
                    pieces = [rest[part] for part in _clusters(m.points[rest], 1.5 * vox, 60, vox / 2)]
                    if len(pieces) > 1:  # fitted together first (see above)
                        ids_out[np.concatenate(pieces)] = next_id
                        groups[next_id] = pieces
                        under[next_id] = above
                        queue.append(next_id)
                        next_id += 1
                        splits += 1
                    else:
                        for part in pieces:
                            ids_out[part] = next_id
                            under[next_id] = above
                            queue.append(next_id)
                            next_id += 1
                            splits += 1
            # One object, one pose: a pose whose own points (those of its instance it explains) are mostly
            # explained by a better-scoring pose is a duplicate (one object reached from two instances).
            # Two poses of one model at one place (not stacked along the axis) are one object fitted twice,
            # e.g. a mug fitted with the wrong yaw and its unexplained handle fitted again: both are re-scored
            # on their joint points and the better one stays.
            # Verification (perception/verify.py): a pose must not put model surface where the cameras saw
            # through it, must agree with its points' normals and put them on its surface at the sensor's
            # precision (a can is not a cup, a box corner not a mug); one threshold. A pose that fails yields
            # nothing, before duplicates are resolved (it cannot make a right pose a "duplicate"); its points stay
            # in the map, an obstacle for the planner.
            self._fine_check(m, found)
            # A tracked pose the fine check rejects is not the end of that item: its instance gets the full
            # estimate, as an instance no prior explains does (else the item would be missing from this scan).
            retry = [k for k in tracked_at if found[k][0].verification is not None and
                     found[k][0].verification.score < self.settings.verify_threshold]
            for k in retry:
                (sel, prior), iid = tracked_at[k], found[k][1]
                used.discard(prior)
                hyp, _query = self.estimate(m.select(sel), views, [f[0] for j, f in enumerate(found) if j != k])
                if hyp is not None:
                    found[k] = (hyp, iid, sel[self._explained(hyp, m.points[sel])])
            if retry:
                self._fine_check(m, found)
            # A cup, mug or glass rejected may be fitted right but for its way up (thin-walled, nearly as wide
            # at the rim as at the base: the search cannot always tell, ADI cannot either), and the wrong way up
            # its cavity holds what it rests on or its own wall: it gets one more fit, turned over.
            if self._retry_turned_over(m, views, found):
                self._fine_check(m, found)
            # A pose rejected only for what lies around it unexplained (past a vessel's ends, in its cavity) points
            # at an item no pose explains yet (a glass nested in it, one standing under a glass lying across it):
            # what is unexplained there is fitted once more, as an item of its own, and the checks repeated.
            for hyp, own in self._fit_around_rejected(m, views, found):
                found.append((hyp, next_id, own))
                next_id += 1
            verified = []
            for f in found:
                ver = f[0].verification
                if ver is not None and ver.score < self.settings.verify_threshold:
                    rejected += 1
                else:
                    verified.append(f)
            kept: list[list] = []  # [hyp, iid, own]
            for hyp, iid, own in sorted(verified, key=lambda t: -t[0].score):
                P = m.points[own]
                if len(P) == 0:
                    continue
                twin = next((k for k in kept if self._same_place(k[0], hyp)), None)
                if twin is not None:
                    joint = np.union1d(twin[2], own)
                    scorer = Scorer(db[hyp.obj_id], _voxel_centres(m.points[joint], vox), views, vox,
                                    inside_solid=self._inside_solid(self._up()))
                    # The overlap score (epsilon one voxel) decides clear cases; between near-equals, the fit
                    # that puts more of the points on its surface within 3 mm (facing the right way) wins.
                    s_new, s_old = scorer(hyp.T_base_obj)[0], scorer(twin[0].T_base_obj)[0]
                    if abs(s_new - s_old) < 0.05:
                        P_joint, N_joint = m.points[joint], self._map_normals(m, joint)
                        s_new, s_old = (on_surface(P_joint, N_joint, db[h.obj_id], h.T_base_obj,
                                                   SURFACE_TOL * vox).mean()
                                        for h in (hyp, twin[0]))
                    if s_new > s_old:
                        twin[0] = hyp
                    twin[2] = joint
                    continue
                taken = np.zeros(len(P), bool)
                for k in kept:
                    # A copy of the same model stacked along its axis (a plate under a plate, a cup in a cup)
                    # has most of its visible surface within a voxel of the other one's (hidden) surface: only
                    # points on the other's surface within 3 mm, facing the same way, count as the other's.
                    # (Fits are millimetre-accurate; a nested cup's outer wall lies >= its wall thickness, 3.5
                    # mm, outside the wall of the cup in it. At 8 mm, a lower cup's own points were 85 % "taken"
                    # by the cup nested in it, and the lower cup dropped.)
                    # So does an item of another nesting model resting in or on it (a side plate in a dinner
                    # plate's well, both leaning in a pile): at 1.5 voxels the upper plate "took" the lower
                    # one's visible ring, which lies a few millimetres under the upper one's plane.
                    # So does an item leaning in another one at a steeper angle (a bowl resting 35 deg tilted in a
                    # bowl): the lower one's visible rim and outer wall lie within 1.5 voxels of the upper one's
                    # surface, and the lower bowl, fitted and verified, was dropped as the upper one's duplicate.
                    if self._stacked(k[0], hyp) or self._resting_in(k[0], hyp) or self._leaning_in(k[0], hyp):
                        taken |= self._explained(k[0], P, SURFACE_TOL, self._map_normals(m, own))
                    else:
                        taken |= self._explained(k[0], P)
                if taken.mean() > 0.6:
                    continue
                kept.append([hyp, iid, own])
            kept = self._drop_redundant(m, kept)
            # A pose that leaves part of its own item unexplained beside it (a fit 1-2 cm off that still passes)
            # is fitted again with that part, whatever its source: a kept prior is otherwise never corrected.
            with timed("pose.refit"):  # inside "pose": map_seg_ms leaves it out
                refit_beside_unexplained(self, m, views, kept)
            # Plates nested under a plate show a rim band a few millimetres under the one above, which that
            # plate's pose explains at the splitting tolerance: each nest level the data supports is added
            # (perception/nest.py).
            next_id += add_nest_levels(self, m, views, kept, next_id)
            for hyp, iid, own in kept:
                ids_out[own] = iid
                model = self.inventory[hyp.obj_id]
                ver = getattr(hyp, "verification", None)
                poses.append(ObjectPose(hyp.obj_id, model.cls, hyp.T_base_obj, hyp.score, m.points[own], iid,
                                        hyp.visible_fraction, ver.score if ver is not None else 1.0,
                                        ver.parts() if ver is not None else {}))
        m = InstanceMap(m.points, ids_out, m.view, m.pixel, m.cam_centres)
        source = "cell" if self._active_cell is not None else ("data" if self._surfaces is not None else "plane")
        return PerceptionResult(poses, m, dets, timings, pose_ms, rejected, list(views), cpu, pose_cpu_ms,
                                source, check, self._surfaces, len(used),
                                sum(1 for h, _, _ in found if h.source == KEPT) if priors else 0)

    def _overlapping(self, a: Hypothesis, b: Hypothesis) -> bool:
        """Whether two poses could be one object fitted twice: one model (axes within 30 deg, centres under half a
        diameter apart across: the same place or stacked) or two nesting models one resting in the other."""
        off = self._offset(a, b)
        if off is not None:
            return bool(off[2] < 0.5 * off[0].diameter)
        return self._resting_in(a, b)

    def _drop_redundant(self, m: InstanceMap, kept: list[list]) -> list[list]:
        """One object, one pose, judged on the points: of poses that overlap (`_overlapping`), one that puts almost
        none of the points on its surface (3 mm, facing the same way) that the others do not is a second fit of
        what they explain (a compromise between a plate and the plate resting in it, next to the lower plate's
        own refit 5 mm lower: as far apart as two stacked plates, so distances along the axis cannot tell). The
        poses with the fewest such points of their own go first, one at a time; what a dropped pose held goes to
        the overlapping pose that explains it. A stacked item's visible rim is on its surface only."""
        while True:
            worst, worst_share = None, REDUNDANT_SHARE
            for k, (hyp, _, own) in enumerate(kept):
                nbrs = [j for j, o in enumerate(kept) if j != k and self._overlapping(hyp, o[0])]
                if not nbrs:
                    continue
                idx = np.unique(np.concatenate([own] + [kept[j][2] for j in nbrs]))
                P, N = m.points[idx], self._map_normals(m, idx)
                on = self._explained(hyp, P, SURFACE_TOL, N)
                if not on.any():
                    continue
                others = np.zeros(len(P), bool)
                for j in nbrs:
                    others |= self._explained(kept[j][0], P, SURFACE_TOL, N)
                share = float((on & ~others).sum()) / on.sum()
                if share < worst_share:
                    worst, worst_share = k, share
            if worst is None:
                return kept
            hyp, _, own = kept.pop(worst)
            log.debug("perception: %s dropped, %.0f %% of the points on its surface are its own",
                      self.inventory[hyp.obj_id].name, 100 * worst_share)
            for o in sorted((o for o in kept if self._overlapping(hyp, o[0])), key=lambda o: -o[0].score):
                if len(own) == 0:
                    break
                took = self._explained(o[0], m.points[own])
                o[2] = np.concatenate([o[2], own[took]])
                own = own[~took]

    def _fine_check(self, m: InstanceMap, found: list[tuple[Hypothesis, int, np.ndarray]]) -> None:
        """Each found pose's `fine` verification part (perception/verify.py): the share of its own map points,
        less those a nearby pose has on its surface, that lie on its surface at the sensor's precision; for tall
        vessels and open ones, `continued` and `filled` (map points past its ends / in its cavity that no nearby
        pose explains).

        Only poses that pass the verification explain anything: the checks are repeated for the neighbours of
        poses that fail, without them, until no more fail. (A bottle fitted by two cups along its body: the
        second cup "explained" where the bottle goes on past the first one's rim, and was then rejected itself;
        the first one passed on the strength of a pose that was not kept.)

        A prior kept as it was (source KEPT: its surroundings are the points they were, track.unchanged) keeps the
        parts it was verified with; it is checked again only as the neighbour of a pose that fails."""
        failed: set[int] = set()
        todo = {k for k, f in enumerate(found) if f[0].source != KEPT}
        if not todo:  # every pose kept as it was: nothing to check (nor the map's tree and noise to measure)
            return
        tree, tol = self._fine_context(m)
        log.debug("perception: fine tolerance %.1f mm", 1000 * tol)
        while todo:
            alive = [f for k, f in enumerate(found) if k not in failed]
            # A pose rejected by `overhang_area` alone (a glass fitted along a drink can: its side and its ends
            # where the model's are, a lid wider than the base) still puts the surface of an item of its length
            # where it lies: it explains that surface for its neighbours' `continued` (a glass lying against the
            # can's end is not continued by it), and nothing else.
            along = [f for k, f in enumerate(found) if k in failed and self._lid_only(f[0])]
            for k in sorted(todo):
                self._fine_parts(m, tree, tol, found[k][0], found[k][2], alive, along)
            newly = {k for k, (h, _, _) in enumerate(found) if k not in failed and h.verification is not None
                     and h.verification.score < self.settings.verify_threshold}
            failed |= newly
            todo = {k for k, (h, _, _) in enumerate(found) if k not in failed and h.verification is not None and
                    any(self._near_each_other(h, found[j][0]) for j in newly)}

    def _retry_turned_over(self, m: InstanceMap, views: list[View],
                           found: list[tuple[Hypothesis, int, np.ndarray]]) -> bool:
        """Each cup, mug or glass pose the verification rejects is turned over (`_turned_over`), refined and
        verified again, with the poses that pass as its neighbours; the turned pose replaces it where it passes.
        Whether any did (the fine check is then repeated: its neighbours are judged with it)."""
        thr = self.settings.verify_threshold

        def failed(h: Hypothesis) -> bool:
            return h.verification is not None and h.verification.score < thr

        todo = [k for k, (h, _, _) in enumerate(found) if failed(h) and self.inventory[h.obj_id].cls in FLIP_CLASSES]
        if not todo:
            return False
        tree, tol = self._fine_context(m)
        changed = False
        for k in todo:
            h, iid, own = found[k]
            turned = self._turned_over(m, views, h, own)
            if turned is None:
                continue
            alive = [f for j, f in enumerate(found) if j != k and not failed(f[0])] + [(turned, iid, own)]
            self._fine_parts(m, tree, tol, turned, own, alive)
            a, b = h.verification, turned.verification
            # The turn is to set the way up right, not to fit other points: the turned fit must explain the points
            # at least as well (a glass over a drink can, rejected because the can's lid is in its cavity, turned
            # over takes less of the can, further off its surface, and claims free space).
            # (A model with a part off its body: the wrong turn's own points are those it explains at 1.5 voxels,
            # the neighbour's points its misplaced handle took among them, and those the right way; turned right,
            # it leaves those or explains them facing the other way.)
            lose = TURNED_MARGIN if self.inventory[h.obj_id].is_rotationally_symmetric else TURNED_PART_EXPLAINED
            if not failed(turned) and b.fine >= a.fine - TURNED_MARGIN and b.explained >= a.explained - lose \
                    and b.normals >= a.normals - lose and b.free_space <= a.free_space + TURNED_MARGIN:
                log.debug("perception: %s kept turned over (%.3f -> %.3f; %s -> %s)", self.inventory[h.obj_id].name,
                          h.verification.score, turned.verification.score,
                          {n: round(v, 3) for n, v in a.parts().items()},
                          {n: round(v, 3) for n, v in b.parts().items()})
                found[k] = (turned, iid, own)
                changed = True
        return changed

    def _turned_over(self, m: InstanceMap, views: list[View], h: Hypothesis, own: np.ndarray) -> Hypothesis | None:
        """The pose turned half round about a horizontal axis through the middle of the model (its x axis there),
        refined on the points the pose explained (`own`), with the checks every pose must pass (`_accepted`);
        None where it fails them or the ICP slid off (its axis more than 45 deg from the turned one, or its
        centre more than 0.2 diameter away: a fit onto another item is no turn). For a model with a part off its
        body (a mug's handle), also the best-scoring turns about the body's axis, either way up (a mug in a pile
        fitted with its handle 50-130 deg off or its axis reversed, rejected for the free space the handle
        claims; on its own points the true pose scored 0.03-0.17 higher): the best refined fit is the retry."""
        model, entry = self.inventory[h.obj_id], self.database[h.obj_id]
        query = self._query(m.select(own), views, point_features=False)  # registered and scored only
        if len(query.points) < 8:
            return None
        scorer = Scorer(entry, query.points, views, self.settings.voxel_size,
                        inside_solid=self._inside_solid(self._up()), depths=self._depths)
        c = 0.5 * (model.points.min(axis=0) + model.points.max(axis=0))
        R = np.diag([1.0, -1.0, -1.0])
        T_over = np.eye(4)
        T_over[:3, :3], T_over[:3, 3] = R, c - R @ c
        Tf = h.T_base_obj @ T_over
        starts = [Tf]
        if not model.is_rotationally_symmetric:
            # A part off the body (a mug's handle): the turns about the body's axis too, the fit's own and turned
            # over, scored on the points (the depth render counts against a handle where the cameras saw
            # through it); the best few refined besides the turn over.
            turns = [T @ _body_turn(model.points, a) for T in (h.T_base_obj, Tf)
                     for a in np.radians(np.arange(TURN_STEP, 360, TURN_STEP))]
            sc = scorer.batch(np.array(turns))[0]
            starts += [turns[k] for k in np.argsort(-sc)[:PART_TURNS_REFINED]]
        best = None
        for Ts in starts:
            t = refine(query, entry, scorer, Ts, self.reg_cfg, h.source + "-over",
                       symmetric=model.is_rotationally_symmetric)
            if t.T_base_obj[:3, 2] @ Ts[:3, 2] < np.cos(np.radians(45)) or \
                    np.linalg.norm(t.T_base_obj[:3, :3] @ c + t.T_base_obj[:3, 3] - Ts[:3, :3] @ c - Ts[:3, 3]) > \
                    0.2 * model.diameter:
                continue
            if best is None or t.score > best.score:
                best = t
        if best is None:
            return None
        best.score *= self._colour_weight(query, best, 1.0)
        return self._accepted(query, best, scorer)

    def _fit_around_rejected(self, m: InstanceMap, views: list[View],
                             found: list[tuple[Hypothesis, int, np.ndarray]]) -> list[tuple[Hypothesis, np.ndarray]]:
        """New poses for what poses rejected only by their surroundings leave unexplained; the fine check is
        repeated with them (every pose judged again) where there are any.

        A pose is rejected by its surroundings when it would pass without `continued` and `filled`, the map points
        past its ends or in its cavity that no pose explains. Those points may be an item the search missed (its
        segment held several items and was fitted wrong, and that fit was rejected): a glass nested in a glass
        fills the lower one's cavity and goes on past the end of a glass lying across it. The map points within
        the rejected pose's reach (CONTEXT_REACH diameters) that no pose explains (neither those that pass nor
        those rejected by their surroundings alone) are clustered, and each cluster is estimated as an instance of
        its own, with the poses found as stacking starts. A fit must pass every check as any pose does; a new
        pose that explains the points lets the pose that pointed at them pass."""
        thr = self.settings.verify_threshold

        def failed(h: Hypothesis) -> bool:
            return h.verification is not None and h.verification.score < thr

        def by_context(h: Hypothesis) -> bool:
            return failed(h) and replace(h.verification, continued=0.0, filled=0.0).score >= thr

        ctx = [f for f in found if by_context(f[0])]
        if not ctx:
            return []
        explaining = [f[0] for f in found if not failed(f[0]) or by_context(f[0])]
        tree, _ = self._fine_context(m)
        near: set[int] = set()
        for h, _, _ in ctx:
            near.update(tree.query_ball_point(h.T_base_obj[:3, 3], CONTEXT_REACH * self.inventory[h.obj_id].diameter))
        idx = np.array(sorted(near), int)
        idx = idx[m.ids[idx] >= 0]
        left = np.ones(len(idx), bool)
        for h in explaining:
            close = np.linalg.norm(m.points[idx] - h.T_base_obj[:3, 3], axis=1) < \
                (CONTEXT_REACH + 0.5) * self.inventory[h.obj_id].diameter
            if close.any():
                left[close] &= ~self._explained(h, m.points[idx[close]])
        idx = idx[left]
        if len(idx) < CONTEXT_MIN_POINTS:
            return []
        vox = self.settings.voxel_size
        new = []
        for part in _clusters(m.points[idx], 1.5 * vox, CONTEXT_MIN_POINTS, vox / 2):
            sel = idx[part]
            hyp, _query = self.estimate(m.select(sel), views, explaining)
            if hyp is not None:
                new.append((hyp, sel[self._explained(hyp, m.points[sel])]))
        if new:
            self._fine_check(m, found + [(h, -1, own) for h, own in new])
        return new

    def _near_each_other(self, a: Hypothesis, b: Hypothesis) -> bool:
        """Whether one pose can explain points the checks of the other look at (within their two diameters)."""
        return bool(np.linalg.norm(a.T_base_obj[:3, 3] - b.T_base_obj[:3, 3]) <
                    self.inventory[a.obj_id].diameter + self.inventory[b.obj_id].diameter)

    def _lid_only(self, h: Hypothesis) -> bool:
        """Whether a pose fails the verification by `overhang_area` alone."""
        v = h.verification
        return v is not None and v.score < self.settings.verify_threshold and \
            replace(v, overhang_area=0.0).score >= self.settings.verify_threshold

    def _fine_context(self, m: InstanceMap) -> tuple[cKDTree, float]:
        """The map's KD-tree and the fine check's tolerance (from the map's surface noise): computed once per scan
        and map (the fine check runs again after each retry; both depend on the map points alone). A new map
        also starts a new `_fine_memo` (its keys name map points by index)."""
        if self._fine_ctx is None or self._fine_ctx[0] is not m.points:
            tol = fine_tolerance(surface_noise(m.points[:: max(1, len(m.points) // 20000)]))
            self._fine_ctx = (m.points, cKDTree(m.points), tol)
            self._fine_memo = {}
        return self._fine_ctx[1], self._fine_ctx[2]

    def _fine_parts(self, m: InstanceMap, tree: cKDTree, tol: float, hyp: Hypothesis, own: np.ndarray,
                    found: list[tuple[Hypothesis, int, np.ndarray]],
                    along: list[tuple[Hypothesis, int, np.ndarray]] = ()) -> None:
        """The `fine`, `continued` and `filled` parts of one pose, with `found` the poses that may explain
        points near it (and `along` those that explain points for `continued` only: `_fine_check`).

        The parts depend only on the pose, its own points, the map and the poses near it (within their two
        diameters, and the centimetre the fine fit may move it): the fine check is repeated after each retry
        and for the neighbours of each pose that fails, and a pose whose inputs are all as they were gets the
        parts it was given then, not computed again (`_fine_memo`, one scan)."""
        if hyp.verification is None or len(own) == 0:
            return
        # A pose that cannot be there together with this one (`_through_each_other`) explains nothing for it:
        # of two such fits at most one is right, and each must not pass on the strength of the other.
        found = [f for f in found if f[0] is hyp or not self._through_each_other(hyp, f[0])]
        if hyp.verification.normals_segment is None:
            hyp.verification.normals_segment = hyp.verification.normals
        self._fine_context(m)  # the memo is this map's
        key = self._fine_key(tol, hyp, own, found, along)
        parts = self._fine_memo.get(key)
        if parts is None:
            parts = self._fine_parts_computed(m, tree, tol, hyp, own, found, along)
            self._fine_memo[key] = parts
        for name, value in parts.items():
            setattr(hyp.verification, name, value)

    def _memo(self, key: tuple, compute):
        """`compute()`, remembered for the scan under `key` (`_fine_memo`: keys name everything it reads)."""
        if key not in self._fine_memo:
            self._fine_memo[key] = compute()
        return self._fine_memo[key]

    def _fine_key(self, tol: float, hyp: Hypothesis, own: np.ndarray,
                  found: list[tuple[Hypothesis, int, np.ndarray]],
                  along: list[tuple[Hypothesis, int, np.ndarray]]) -> tuple:
        """Everything `_fine_parts_computed` reads but the map (`_fine_memo` is one map's): the gravity prior, the
        tolerance, the pose (model, pose, the normals part judged on its segment), its own points and the poses that can explain
        points it looks at (model and pose; the order does not matter: each check takes the union of what they
        explain)."""
        diameter, centre = self.inventory[hyp.obj_id].diameter, hyp.T_base_obj[:3, 3]

        def near(fs) -> frozenset:
            return frozenset((h.obj_id, h.T_base_obj.tobytes()) for h, _, _ in fs if h is not hyp and
                             np.linalg.norm(h.T_base_obj[:3, 3] - centre) <=
                             diameter + self.inventory[h.obj_id].diameter + FINE_KEY_SLACK)

        along_near = near(along) if self.inventory[hyp.obj_id].cls in FLIP_CLASSES else frozenset()
        up = self._up()  # (continued, overhang and intruded read the gravity prior)
        return ("parts", None if up is None else np.asarray(up, float).tobytes(), tol, hyp.obj_id, hyp.T_base_obj.tobytes(), np.asarray(own).tobytes(),
                hyp.verification.normals_segment, near(found), along_near)

    def _fine_parts_computed(self, m: InstanceMap, tree: cKDTree, tol: float, hyp: Hypothesis, own: np.ndarray,
                             found: list[tuple[Hypothesis, int, np.ndarray]],
                             along: list[tuple[Hypothesis, int, np.ndarray]]) -> dict[str, float]:
        """`_fine_parts` computed: the verification parts it sets, by name (`found` filtered already); `sunk` (the
        model's surface behind a support found in the data, verify.sunk) for every pose of a scan segmented with
        the surfaces found in it."""
        db = self.database
        reach = self.inventory[hyp.obj_id].diameter
        others = [(db[h.obj_id], h.T_base_obj) for h, _, _ in found if h is not hyp and
                  np.linalg.norm(h.T_base_obj[:3, 3] - hyp.T_base_obj[:3, 3]) <
                  0.5 * (reach + self.inventory[h.obj_id].diameter)]
        # The pieces that do not depend on the neighbours are remembered for the scan too (a pose checked again
        # because a neighbour failed has the same points and normals), and each neighbour's claim on them.
        own_key = np.asarray(own).tobytes()
        normals = self._memo(("normals", own_key), lambda: patch_normals(m.points[own], m.cam_centres[m.view[own]]))
        claimed = np.zeros(len(own), bool)
        for e, T in others:
            claimed |= self._memo(("claimed", own_key, tol, e.obj_id, T.tobytes()),
                                  lambda: claimed_by(m.points[own], normals, tol, [(e, T)]))
        # Points another pose has on its surface do not count against this one's normals either (the segment
        # of a stacked item, what the item on it left over, holds the rim of the item under it, fitted later).
        parts: dict[str, float] = {}
        facing = facing_unclaimed(m.points[own], normals, db[hyp.obj_id], hyp.T_base_obj, self.settings.voxel_size,
                                  tol, others, claimed)
        segment = hyp.verification.normals_segment
        parts["normals"] = segment if facing is None else max(segment, facing)
        sym = self.inventory[hyp.obj_id].is_rotationally_symmetric
        # (the fit depends on the neighbours only through the points they claim)
        parts["fine"], T_fine = self._memo(
            ("fine_fit", own_key, tol, hyp.obj_id, hyp.T_base_obj.tobytes(), claimed.tobytes()),
            lambda: fine_fit(m.points[own], normals, db[hyp.obj_id], hyp.T_base_obj, tol, others, sym, claimed))
        if self.inventory[hyp.obj_id].cls in FLIP_CLASSES:
            parts["continued"] = self._continued(m, tree, hyp, own, found + [f for f in along if f[0] is not hyp])
        near = None  # map points near the pose and which of them a pose explains (for filled and overhang)
        if self.inventory[hyp.obj_id].cls in CAVITY_CLASSES:
            near = self._explained_near(m, tree, hyp, found)
            parts["filled"] = self._filled(near, hyp, own)
        if self.inventory[hyp.obj_id].cls in FLIP_CLASSES:
            parts["overhang"], parts["overhang_area"] = \
                self._overhang(near or self._explained_near(m, tree, hyp, found), hyp, own)
            parts["intruded"] = self._intruded(m, tree, tol, hyp, found, T_fine)
            # (its own points no neighbour claims, at the pose the fine fit nudged onto them)
            # (remembered by its inputs: a pose checked again beside a new neighbour that claims none of its
            # points and stays out of its reach, e.g. after a fit around a rejected pose, is judged as before)
            parts["straight"] = self._memo(
                ("straight", own_key, claimed.tobytes(), tol, hyp.obj_id, T_fine.tobytes(),
                 tuple(sorted((e.obj_id, T.tobytes()) for e, T in others))),
                lambda: straightness(m.points[own][~claimed], normals[~claimed], db[hyp.obj_id], T_fine, tol,
                                     others))
        if self._active_cell is None and self._surfaces is not None:
            # Judged against the supports found in the data only (what items stand on). Not with the configured
            # cell, a prior whose boxes (5 mm inside their faces) a right fit a few millimetres low reaches into
            # with the whole of its flat base, nor against walls (a hand-made plate through the basin's side).
            dense = db[hyp.obj_id].dense_points
            parts["sunk"] = sunk(dense[::max(1, len(dense) // SUNK_POINTS)], hyp.T_base_obj,
                                 lambda P: self._surfaces.inside_solid(P, supports_only=True))
        return parts

    def _through_each_other(self, a: Hypothesis, b: Hypothesis) -> bool:
        """Whether two poses of one tall vessel (cup, mug, glass) lie on one axis turned opposite ways, their
        lengths overlapping along it (centres under `TURNED_OVERLAP` of the height apart along the axis, under
        half a diameter across): rigid copies can nest or stack only facing the same way (one rests in or on the
        other); turned the other way and overlapping, their walls pass through each other. Two glasses fitted rim
        into rim along a lying bottle's body are such a pair: each explained where the bottle went on past the
        other's end, and both passed."""
        if a.obj_id != b.obj_id or self.inventory[a.obj_id].cls not in FLIP_CLASSES:
            return False
        z = a.T_base_obj[:3, 2]
        if z @ b.T_base_obj[:3, 2] > -np.cos(np.radians(30)):
            return False
        model = self.inventory[a.obj_id]
        d = b.T_base_obj[:3, 3] - a.T_base_obj[:3, 3]
        return bool(abs(d @ z) < TURNED_OVERLAP * model.extents[2] and
                    np.linalg.norm(d - (d @ z) * z) < 0.5 * model.diameter)

    def _continued(self, m: InstanceMap, tree: cKDTree, hyp: Hypothesis, own: np.ndarray,
                   found: list[tuple[Hypothesis, int, np.ndarray]]) -> float:
        """verify.continuation for a pose of a tall vessel lying down (axis over 45 deg from up): map points past
        its ends that no pose explains. A copy fitted end to end along the axis does not explain them: that is
        how a bottle is fitted by cups (one after the other along its body). For a standing vessel (upright or
        upside down) an end is judged only where nothing past it reaches out across the axis: what lies across a
        cup's rim (a plate, a lying bottle) or under its base (its support) is past its end too, while an
        upright bottle's body, shoulder and neck go on past an upside-down cup's base within its radius. An
        upright vessel's base end is not judged at all: what lies under it is what it stands on, however narrow
        (a drink can, the glass it is nested in, whose wall goes on under its base); nor is the end past a closed
        base that the map points on the pose's surface show as a closed surface (`base_seen`)."""
        model = self.inventory[hyp.obj_id]
        T = hyp.T_base_obj
        z = T[:3, 2]
        up = self._up()
        up = np.array([0.0, 0.0, 1.0]) if up is None else up
        standing = abs(z @ up) >= np.cos(np.radians(45))
        idx, P, explained = self._near(m, tree, hyp)
        if len(idx) == 0:
            return 0.0
        explained = explained.copy()
        # A closed base the depth shows ends the item: what lies past it (a sponge on an upside-down mug's base)
        # rests on it; a bottle fitted by a cup goes on through where the cup's base would be, unseen. (The map
        # points on the pose's surface, not its own points: a turned-over retry keeps the points of the fit it
        # turns, which left the base out.)
        mine = idx[explained]
        closed = len(mine) > 0 and \
            base_seen(m.points[mine], self._map_normals(m, mine), model.points, T, FINE_ON_TOL) >= BASE_SEEN
        for h, _, _ in found:
            if h is hyp:
                continue
            other = self.inventory[h.obj_id]
            d = h.T_base_obj[:3, 3] - T[:3, 3]
            if np.linalg.norm(d) > model.diameter + other.diameter:
                continue
            along = abs(d @ z)
            # (For a standing vessel a copy along the axis explains as any pose does: upright copies along one
            # axis are a nested stack, and a copy fitted on a standing bottle is rejected on its own, after
            # which it explains nothing: the judging is repeated without it.)
            end_to_end = not standing and other.cls in FLIP_CLASSES and h.T_base_obj[:3, 2] @ z > np.cos(np.radians(30)) \
                and np.linalg.norm(d - (d @ z) * z) < 0.5 * model.diameter \
                and along > 0.25 * (model.extents[2] + other.extents[2])
            if not end_to_end:
                explained |= self._explains_near(hyp, P, h)
        return continuation(P, model.points, T, explained, len(own), only_along=standing,
                            on_base=(standing and z @ up > 0) or closed)

    def _near(self, m: InstanceMap, tree: cKDTree, hyp: Hypothesis) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Map points within the model's diameter of a pose (indices, points) and which of them the pose puts on its
        surface; remembered per pose for the map (`_fine_memo`: `continued`, `filled` and `overhang` all read
        them, again at each repeat of the fine check). Read only: copy before changing."""
        T = hyp.T_base_obj

        def compute():
            idx = np.array(tree.query_ball_point(T[:3, 3], self.inventory[hyp.obj_id].diameter), int)
            P = m.points[idx]
            on = on_surface(P, None, self.database[hyp.obj_id], T, FINE_ON_TOL) if len(P) else np.zeros(0, bool)
            return idx, P, on

        return self._memo(("near", hyp.obj_id, T.tobytes()), compute)

    def _explains_near(self, hyp: Hypothesis, P: np.ndarray, other: Hypothesis) -> np.ndarray:
        """Which of the map points near `hyp` (`P`, from `_near`) the pose `other` puts on its surface (at 1.5 x
        FINE_ON_TOL); remembered per pair of poses for the map. Read only."""
        return self._memo(("explains", hyp.obj_id, hyp.T_base_obj.tobytes(), other.obj_id, other.T_base_obj.tobytes()),
                          lambda: on_surface(P, None, self.database[other.obj_id], other.T_base_obj, 1.5 * FINE_ON_TOL))

    def _near_points(self, m: InstanceMap, tree: cKDTree, hyp: Hypothesis) -> tuple[np.ndarray, np.ndarray]:
        """Map points within the model's diameter of a pose, and which of them the pose puts on its surface."""
        _, P, on = self._near(m, tree, hyp)
        return P, on.copy()

    def _explained_near(self, m: InstanceMap, tree: cKDTree, hyp: Hypothesis,
                        found: list[tuple[Hypothesis, int, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        """Map points within the model's diameter of a pose, and which of them it or a nearby pose (`found`)
        puts on its surface."""
        model = self.inventory[hyp.obj_id]
        T = hyp.T_base_obj
        P, explained = self._near_points(m, tree, hyp)
        if len(P) == 0:
            return P, explained
        for h, _, _ in found:
            if h is not hyp and np.linalg.norm(h.T_base_obj[:3, 3] - T[:3, 3]) < \
                    model.diameter + self.inventory[h.obj_id].diameter:
                explained |= self._explains_near(hyp, P, h)
        return P, explained

    def _filled(self, near: tuple[np.ndarray, np.ndarray], hyp: Hypothesis, own: np.ndarray) -> float:
        """verify.filled for a pose of an open vessel: map points inside its cavity that no pose explains
        (`near`: `_explained_near`)."""
        P, explained = near
        if len(P) == 0:
            return 0.0
        return filled(P, self.inventory[hyp.obj_id].points, hyp.T_base_obj, explained, len(own))

    def _overhang(self, near: tuple[np.ndarray, np.ndarray], hyp: Hypothesis,
                  own: np.ndarray) -> tuple[float, float]:
        """verify.overhang and verify.overhang_area for a pose of a tall vessel that does not stand on its base
        (axis over 45 deg from up): map points in its base's plane just past its edge that no pose explains
        (`near`: `_explained_near`), per point of its own and as the area they cover. A standing vessel's base
        rests on something (a plate, a board), whose surface goes on past the edge."""
        up = self._up()
        up = np.array([0.0, 0.0, 1.0]) if up is None else up
        P, explained = near
        if hyp.T_base_obj[:3, 2] @ up >= np.cos(np.radians(45)) or len(P) == 0:
            return 0.0, 0.0
        model_points = self.inventory[hyp.obj_id].points
        return (overhang(P, model_points, hyp.T_base_obj, explained, len(own)),
                overhang_area(P, model_points, hyp.T_base_obj, explained))

    def _intruded(self, m: InstanceMap, tree: cKDTree, tol: float, hyp: Hypothesis,
                  found: list[tuple[Hypothesis, int, np.ndarray]], T_fine: np.ndarray | None = None) -> float:
        """verify.intruded for a pose of a tall vessel whose opening faces down (its axis, base to rim, at least
        `INTRUDE_BELOW` below the horizontal): the area of map points inside its cavity that neither it (within
        `tol`) nor an item nested in it (a pose within its wall) puts on its surface. Nothing is put into a
        vessel from below: what lies in its cavity there passes through its wall. One whose opening faces up or
        sideways is left out: things are put into cups and glasses, lean or poke into a lying one's mouth, and
        a can's lid across an upright opening is `filled`.

        The cavity is read at `T_fine`, the pose the fine check judged (`verify.fine_fit`: nudged onto its own
        points at the sensor's precision), where given. A vessel facing down rests on its rim: the surface it
        rests on comes up to the rim all round, and its own wall runs down to it, so a fit a few millimetres or
        degrees off (within 0.1 diameter) puts that surface, or its own wall, inside the model's wall near the
        rim. Nudged onto its own points it no longer does; a surface that passes through where the wall of a
        vessel fitted over something shorter would be stays inside wherever the fit is slid."""
        up = self._up()
        up = np.array([0.0, 0.0, 1.0]) if up is None else up
        if hyp.T_base_obj[:3, 2] @ up > -np.sin(np.radians(INTRUDE_BELOW)):
            return 0.0
        T = hyp.T_base_obj if T_fine is None else T_fine
        model = self.inventory[hyp.obj_id]
        P = m.points[np.array(tree.query_ball_point(T[:3, 3], model.diameter), int)]
        if len(P) == 0:
            return 0.0
        explained = on_surface(P, None, self.database[hyp.obj_id], T, tol)
        Ti = inv(T)
        for h, _, _ in found:
            if h is hyp or np.linalg.norm(h.T_base_obj[:3, 3] - T[:3, 3]) > \
                    model.diameter + self.inventory[h.obj_id].diameter:
                continue
            # Nested in it: of the other model's points between this one's base and rim, nearly all within its
            # wall (a cup in a cup; an item whose surface crosses the wall is no such thing).
            Q = self.inventory[h.obj_id].points[::4]
            Th = Ti @ h.T_base_obj
            q = Q @ Th[:3, :3].T + Th[:3, 3]
            span = (q[:, 2] > model.points[:, 2].min()) & (q[:, 2] < model.points[:, 2].max())
            if span.any() and within_wall(q[span], model.points, -NESTED_SLACK).mean() >= 0.9:
                explained |= on_surface(P, None, self.database[h.obj_id], h.T_base_obj, 1.5 * FINE_ON_TOL)
        return intruded(P, model.points, T, explained)

    def _up(self) -> np.ndarray | None:
        """The gravity prior for this scan: None with a cell (the base frame's z), the base frame's up with
        surfaces found in the data, the dominant plane's normal in single-view plane mode."""
        if self._active_cell is not None:
            return None
        if self._surfaces is not None:
            return self._surfaces.up
        return getattr(self.detector, "support_normal", None)

    def _inside_solid(self, up: np.ndarray | None):
        """Test for points inside known solid matter: the cell's boxes (deeper than 5 mm; the counter and the
        basin extended downwards), or more than 1 cm behind a surface found in the data, or in plane mode more
        than 1 cm below the support plane."""
        cell = self._active_cell
        if cell is not None:
            # Boxes near the sink only (objects are found there), shrunk by 5 mm.
            s_lo, s_hi = cell.sink_interior
            boxes = [b for b in cell.boxes
                     if np.all(b.upper > s_lo - 0.3) and np.all(b.lower < s_hi + np.array([0.3, 0.3, 0.6]))]
            if not boxes:
                return None
            lo = np.array([b.lower for b in boxes]) + 0.005
            hi = np.array([b.upper for b in boxes]) - 0.005
            # Under the counter and the basin is cabinet: nothing the cameras could see rests there.
            lo[[b.kind in ("counter", "sink") for b in boxes], 2] = -10.0

            # The open basin (less 5 mm) holds no solid: only points outside it are tested against the boxes
            # (most model points of a pose in the sink are inside it; the box test is the Scorer's hot spot).
            open_lo, open_hi = s_lo + 0.005, s_hi + np.array([-0.005, -0.005, 1.0])

            def inside(P: np.ndarray) -> np.ndarray:
                out = np.zeros(len(P), bool)
                rest = np.nonzero(~np.all((P > open_lo) & (P < open_hi), axis=1))[0]
                if len(rest):
                    Q = P[rest][:, None]
                    out[rest] = np.any(np.all((Q > lo) & (Q < hi), axis=2), axis=1)
                return out

            return inside
        if self._surfaces is not None:
            return self._surfaces.inside_solid
        det = self.detector
        if up is None or getattr(det, "support_offset", None) is None:
            return None
        d = det.support_offset
        return lambda P: P @ up + d < -0.01

    def _colour_weight(self, query: FusedCloud, h: Hypothesis, default: float) -> float:
        """0.6 + 0.4 x cosine between the colour of the query points this pose explains and the model's
        class token (the whole instance's colour misleads when two items were segmented together)."""
        entry = self.database[h.obj_id]
        if query.img.shape[1] == 0 or entry.ref.cls_token.size == 0:
            return default
        Ti = inv(h.T_base_obj)
        d, _ = entry.tree.query(query.points @ Ti[:3, :3].T + Ti[:3, 3], distance_upper_bound=self.settings.voxel_size)
        ok = np.isfinite(d)
        if ok.sum() < 5:
            return default
        f = query.img[ok].mean(axis=0)
        sim = float(f @ entry.ref.cls_token / max(np.linalg.norm(f), 1e-12))
        return 0.6 + 0.4 * max(0.0, sim)

    def _offset(self, a: Hypothesis, b: Hypothesis):
        """(model, distance along the axes, distance across a's axis) for two copies of one model whose axes
        are within 30 deg; None otherwise. Along: the larger of the offsets along a's and b's axes (a plate
        resting 10 deg tilted and 2 cm off-centre on another has its centre 3 mm above the lower one along its
        own axis, 6 mm along the lower one's)."""
        if a.obj_id != b.obj_id:
            return None
        z = a.T_base_obj[:3, 2]
        if abs(z @ b.T_base_obj[:3, 2]) < np.cos(np.radians(30)):
            return None
        d = b.T_base_obj[:3, 3] - a.T_base_obj[:3, 3]
        along = max(abs(d @ z), abs(d @ b.T_base_obj[:3, 2]))
        return self.inventory[a.obj_id], along, np.linalg.norm(d - (d @ z) * z)

    @staticmethod
    def _min_along(model) -> float:
        """Below this distance along a shared axis two copies of one model are one object: 0.12 height, or 0.8
        of the model's nest pitch (a cup in a cup sits 2.6 cm higher; two cup poses 1.6 cm apart along the axis
        would interpenetrate: the second was a fit of the first one's leftovers). The margin, 0.2 pitch (1 mm
        for plates), is what the fits' errors may take."""
        return max(0.12 * float(model.extents[2]), 0.8 * model.nest_pitch)

    def _same_place(self, a: Hypothesis, b: Hypothesis) -> bool:
        """Same model, axes within 30 deg, centres closer than 0.2 diameter across and _min_along along."""
        off = self._offset(a, b)
        if off is None:
            return False
        model, along, across = off
        return across < 0.2 * model.diameter and along < self._min_along(model)

    def _stacked(self, a: Hypothesis, b: Hypothesis) -> bool:
        """Same model, axes within 30 deg, centres apart along the axis by at least _min_along and across by
        under half a diameter (nested or stacked copies)."""
        off = self._offset(a, b)
        if off is None:
            return False
        model, along, across = off
        return across < 0.5 * model.diameter and along >= self._min_along(model)

    def _resting_in(self, a: Hypothesis, b: Hypothesis) -> bool:
        """Two poses of different models of nesting classes (plates, bowls, cups) whose axes are within 30 deg
        and whose centres are under half the smaller diameter apart across a's axis: one rests in or on the
        other (a side plate in a dinner plate, a cup in a bowl). Models differ in where their origin sits, so
        the distance along the axis says nothing here; whether one is a second fit of the other is judged by
        the points (only those on the other's surface within 3 mm, facing the same way, are the other's)."""
        if a.obj_id == b.obj_id:
            return False
        ma, mb = self.inventory[a.obj_id], self.inventory[b.obj_id]
        if ma.cls not in NESTING_CLASSES or mb.cls not in NESTING_CLASSES:
            return False
        z = a.T_base_obj[:3, 2]
        if abs(z @ b.T_base_obj[:3, 2]) < np.cos(np.radians(30)):
            return False
        d = b.T_base_obj[:3, 3] - a.T_base_obj[:3, 3]
        return float(np.linalg.norm(d - (d @ z) * z)) < 0.5 * min(ma.diameter, mb.diameter)

    def _leaning_in(self, a: Hypothesis, b: Hypothesis) -> bool:
        """Two poses of nesting classes (plates, bowls, cups; one model or two) whose axes are LEAN_IN_MIN or more
        apart, where `_stacked` and `_resting_in` do not look, and one of whose centres lies under half the smaller
        diameter from the other's axis: one leans in the other (a bowl resting 35 deg tilted in a bowl, a cup
        lying in a bowl). Whether one is a second fit of the other is judged by the points, as for those."""
        ma, mb = self.inventory[a.obj_id], self.inventory[b.obj_id]
        if ma.cls not in NESTING_CLASSES or mb.cls not in NESTING_CLASSES:
            return False
        za, zb = a.T_base_obj[:3, 2], b.T_base_obj[:3, 2]
        if abs(za @ zb) >= np.cos(LEAN_IN_MIN):
            return False
        d = b.T_base_obj[:3, 3] - a.T_base_obj[:3, 3]
        across = min(float(np.linalg.norm(d - (d @ z) * z)) for z in (za, zb))
        return across < 0.5 * min(ma.diameter, mb.diameter)

    def _explained(self, hyp: Hypothesis, points: np.ndarray, voxels: float = 1.5,
                   normals: np.ndarray | None = None) -> np.ndarray:
        """Which points lie on the posed model's surface (within `voxels` voxels); with `normals`, on a side of
        it facing the same way (register.on_surface)."""
        return on_surface(points, normals, self.database[hyp.obj_id], hyp.T_base_obj,
                          voxels * self.settings.voxel_size)

    def _map_normals(self, m: InstanceMap, idx: np.ndarray) -> np.ndarray:
        """Normals of map points m.points[idx], from their neighbours within 6 mm (finer than a voxel: a rim
        peeking 2 mm under another item keeps its own normal), facing the camera that saw each point.
        Remembered per scan and point set (the duplicate checks ask for the same points once per other pose)."""
        if self._normals is None or self._normals[0] != id(m.points):
            self._normals = (id(m.points), {})
        key = np.asarray(idx).tobytes()
        if key in self._normals[1]:
            return self._normals[1][key]
        P = m.points[idx]
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.006, max_nn=16))
        n = np.asarray(pc.normals)
        if len(n) != len(P):
            n = np.tile([0.0, 0.0, 1.0], (len(P), 1))
        else:
            flip = np.einsum("ij,ij->i", n, m.cam_centres[m.view[idx]] - P) < 0
            n[flip] *= -1
        self._normals[1][key] = n
        return n

    def _near_upright(self, query: FusedCloud, oid: int, scorer: Scorer, T_base_obj: np.ndarray, source: str,
                      up: np.ndarray) -> Hypothesis:
        """The best fit near the gravity-aligned pose T_base_obj: ICP with the axis held, then with it free from
        there; the free fit is taken unless it leans past MAX_REST_TILT or explains the data worse."""
        entry = self.database[oid]
        sym = self.inventory[oid].is_rotationally_symmetric
        held = refine(query, entry, scorer, T_base_obj, self.reg_cfg, source, upright=True, symmetric=sym)
        free = refine(query, entry, scorer, held.T_base_obj, self.reg_cfg, held.source, symmetric=sym)
        # The overlap score (epsilon one voxel) hardly tells a fit leaning 15 deg from an upright one; the
        # fraction of points on the surface within 3 mm does (a wrong lean leaves the far rim off).
        tol = SURFACE_TOL * self.settings.voxel_size
        if abs(free.T_base_obj[:3, 2] @ up) >= np.cos(MAX_REST_TILT) and free.score >= held.score - 0.03 and \
                surface_fit(query.points, query.normals, entry, free.T_base_obj, tol) >= \
                surface_fit(query.points, query.normals, entry, held.T_base_obj, tol):
            return free
        return held

    def _same_start(self, a: np.ndarray, b: np.ndarray, oid: int) -> bool:
        """Two gravity-aligned poses of model `oid` that are one start for ICP: origins within SAME_START (half
        of a voxel), the same way up, and (unless the model is a surface of revolution) turned alike within 2 deg."""
        if np.linalg.norm(a[:3, 3] - b[:3, 3]) > SAME_START * self.settings.voxel_size or a[:3, 2] @ b[:3, 2] < 0.9994:
            return False
        return self.inventory[oid].is_rotationally_symmetric or a[:3, 0] @ b[:3, 0] >= 0.9994

    def _flip_check(self, query: FusedCloud, best: Hypothesis, scorer: Scorer) -> Hypothesis:
        """The pose turned upside down about its own centre (object x axis), refined: cups, mugs and glasses
        are thin-walled and nearly as wide at the top as at the bottom, and where the rim or the base is hidden
        (nested, touching, in a pile) the search settled on the wrong way up although the right one scored
        higher. Taken when it scores about as well or better and puts more points on its surface within 3 mm."""
        entry = self.database[best.obj_id]
        Tf = best.T_base_obj @ np.diag([1.0, -1.0, -1.0, 1.0])
        h = refine(query, entry, scorer, Tf, self.reg_cfg, best.source + "-flip",
                   symmetric=self.inventory[best.obj_id].is_rotationally_symmetric)
        h.score *= best.score / max(scorer(best.T_base_obj)[0], 1e-9)  # the same colour weight
        # It must stay where it was, upside down (an ICP that slid onto another item of a blob is no flip), and
        # put more of the points on its surface: in a blob the overlap score also counts the neighbour's points.
        if h.T_base_obj[:3, 2] @ Tf[:3, 2] < np.cos(np.radians(45)) or \
                np.linalg.norm(h.T_base_obj[:3, 3] - Tf[:3, 3]) > 0.2 * self.inventory[best.obj_id].diameter:
            return best
        tol = SURFACE_TOL * self.settings.voxel_size
        if h.score > best.score - 0.01 and surface_fit(query.points, query.normals, entry, h.T_base_obj, tol) > \
                surface_fit(query.points, query.normals, entry, best.T_base_obj, tol) + 0.02:
            return h
        return best

    def _reach_share(self, points: np.ndarray, hyp: Hypothesis) -> float:
        """The query->model overlap over the query points within the model's reach (its bounding sphere, a voxel
        more): the share of what the pose could explain that it explains. A segment of several touching items
        (a bowl beside a bowl, a glass between two cans) is mostly out of one item's reach; over the whole
        segment a right pose of one of them explains a small share (under the 0.2 gate: the segment was then
        cut into 7 cm regions, which cut the items too). What it leaves is fitted again (explained away)."""
        model = self.inventory[hyp.obj_id]
        T = hyp.T_base_obj
        c = T[:3, :3] @ (0.5 * (model.points.min(axis=0) + model.points.max(axis=0))) + T[:3, 3]
        within = np.linalg.norm(points - c, axis=1) < 0.5 * model.diameter + self.settings.voxel_size
        if not within.any():
            return 0.0
        return hyp.or_query * len(points) / within.sum()

    YAW_SWEEP_MARGIN = 0.015  # score by which a turn about the body's axis must beat the fit it replaces

    def _yaw_sweep(self, query: FusedCloud, best: Hypothesis, scorer: Scorer, n: int = 12) -> Hypothesis:
        """For a model that is symmetric but for a part (a mug's handle): turn the pose about its body's axis in
        n steps, score each (the handle seen, or seen to be absent), and refine the best. The screening's
        yaw hypotheses are 45 deg apart and each is pulled by a coarse ICP in which the handle hardly counts:
        fits ended with the handle 80 deg off, the true pose scoring higher."""
        model = self.inventory[best.obj_id]
        entry = self.database[best.obj_id]
        c = np.median(model.points, axis=0)  # on the body's axis (the handle is a small part of the surface)
        c[2] = 0.0
        T = best.T_base_obj
        cands = []
        for a in np.linspace(0, 2 * np.pi, n, endpoint=False)[1:]:
            Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
            Tz = np.eye(4)
            Tz[:3, :3] = Rz
            Tz[:3, 3] = c - Rz @ c  # about the vertical line through c (object frame)
            cands.append(T @ Tz)
        cands = sorted(zip(scorer.batch(np.array(cands), coarse=True)[0].tolist(), cands), key=lambda t: -t[0])
        for _, Ta in cands[:1]:
            h = refine(query, entry, scorer, Ta, self.reg_cfg, best.source + "-yaw", symmetric=False)
            h.score *= best.score / max(scorer(best.T_base_obj)[0], 1e-9)  # the same colour weight
            tol = SURFACE_TOL * self.settings.voxel_size
            # clearly better only: with the handle hidden or among neighbours both turns score alike, and a
            # 0.5 % margin turned a mug lying on two others half round (its frame 3 cm off, its lift blocked)
            if h.score > best.score + self.YAW_SWEEP_MARGIN and \
                    surface_fit(query.points, query.normals, entry, h.T_base_obj, tol) >= \
                    surface_fit(query.points, query.normals, entry, best.T_base_obj, tol) - 0.02:
                best = h
        return best

    def estimate(self, inst: InstanceMap, views: list[View], found: list[Hypothesis] = (),
                 covered: np.ndarray | None = None, model: int | None = None,
                 context: np.ndarray | None = None) -> tuple[Hypothesis | None, FusedCloud]:
        """Class and pose of one instance (its map points), or None when no model explains it. `found`: poses
        already estimated nearby, whose stacking positions (same model shifted along its axis) are tried too.
        `covered`: points the poses of items on this one explain (what a pose left over is fitted with the
        points it took as `covered`: register.Scorer). `model`: only that model, if the features propose it (a
        known item fitted again). `context`: the points of the blob this instance is a region of, which confirm
        a model's surface as the instance's own do (register.Scorer `context`)."""
        st = self.settings
        query = self._query(inst, views)
        if len(query.points) < 8:
            return None, query
        cands = propose(query, self.database, st.top_k, st.candidate_threshold)
        if model is not None:
            cands = [c for c in cands if c[0] == model]
        up = self._up()
        # Screen every candidate's hypotheses, then refine the best few over all candidates. Appearance must
        # agree too: geometry alone confuses e.g. two nested cups with one glass.
        screened = []
        scorers = {}
        best_screen, best_sim = 0.0, cands[0][1] if cands else 0.0
        lead = cands[0][0] if cands else -1  # the model of the best quick score so far
        extent = float(np.ptp(query.points, axis=0).max())
        for rank, (oid, sim, img_sim) in enumerate(cands):
            if best_screen >= 0.9 and sim < best_sim - 0.15:
                continue  # a clear fit already, and this candidate looks clearly less alike: not worth the time
            if rank >= SCREENED_CANDIDATES and best_screen >= st.min_overlap and extent < self.inventory[lead].diameter:
                break  # one item's segment, with a fit that may pass already, from a model that looks more alike
            entry = self.database[oid]
            scorers[oid] = Scorer(entry, query.points, views, st.voxel_size, inside_solid=self._inside_solid(up),
                                  depths=self._depths, covered=covered, context=context)
            w = 0.6 + 0.4 * max(0.0, img_sim) if np.isfinite(img_sim) else 1.0
            stack = [h.T_base_obj for h in found if h.obj_id == oid and
                     np.linalg.norm(h.T_base_obj[:3, 3] - query.points.mean(axis=0)) < self.inventory[oid].diameter]
            for sc, name, T in screen_candidate(query, entry, self.inventory[oid], scorers[oid], self.reg_cfg, up,
                                                stack, bar=(best_screen - DOMINATED_MARGIN) / w)[:2]:
                screened.append((sc * w, oid, name, T, w))
                if sc * w > best_screen:
                    best_screen, lead = sc * w, oid
        # A model whose quick score trails the leader's by more than refinement has been seen to gain is not
        # refined (nor yaw-screened above): it cannot win.
        screened = [t for t in screened if t[0] >= best_screen - DOMINATED_MARGIN]
        screened.sort(key=lambda t: -t[0])
        # Refine the best few overall and the best of every candidate model (so one model's many similar
        # hypotheses cannot crowd out another model).
        picks, seen = [], set()
        for k, t in enumerate(screened):
            if k <= self.reg_cfg.keep_for_refine or t[1] not in seen:
                picks.append(t)
                seen.add(t[1])
        best: Hypothesis | None = None
        refined: set[tuple[int, bytes]] = set()
        for _, oid, name, T, w in picks:
            # A pick that is an earlier pick's pose exactly (one start screened under two names: a yaw turn of the
            # best hypothesis that is also the best tilted one) refines to the same fit and score: it cannot win.
            if (oid, T.tobytes()) in refined:
                continue
            refined.add((oid, T.tobytes()))
            h = refine(query, self.database[oid], scorers[oid], T, self.reg_cfg, name,
                       symmetric=self.inventory[oid].is_rotationally_symmetric)
            h.score *= self._colour_weight(query, h, w)
            if best is None or h.score > best.score:
                best = h
        # Gravity prior: dishware rests on surfaces, so a pose near upright / upside down that explains the data
        # about as well as a more tilted one wins (tilted fits of stacks explain two items badly). The fit
        # starts exactly upright (axis kept) and is then freed: settled stacks and nested items really lean
        # 5-25 deg, and an axis held exactly vertical put a 10 deg cup's rim 1 cm off and a nested bowl's 2 cm.
        up_vec = np.array([0.0, 0.0, 1.0]) if up is None else up
        vox = st.voxel_size
        if best is not None and abs(best.T_base_obj[:3, 2] @ up_vec) < 0.995:
            oid = best.obj_id
            w = best.score / max(scorers[oid](best.T_base_obj)[0], 1e-9)
            starts = [best.T_base_obj] + [T for _, o, _, T, _ in screened if o == oid][:3]
            tried: list[np.ndarray] = []
            for T in starts:
                if abs(T[:3, 2] @ up_vec) < np.cos(np.radians(35)):
                    continue
                T = snap_upright(T, up_vec)
                # The best pose is a refined screening hypothesis, and hypotheses from several starts converge
                # onto one: a start that snaps to one already tried (and not taken) would be refined to it again.
                if any(self._same_start(T, t, oid) for t in tried):
                    continue
                tried.append(T)
                h = self._near_upright(query, oid, scorers[oid], T, best.source, up_vec)
                h.score *= w
                # ... and puts about as many points on its surface within 3 mm: in a blob of two items (a cup lying
                # across one leaning in another) an upright fit between them took points of both and replaced the
                # lying cup's exact fit.
                if h.score >= best.score - 0.03 and \
                        surface_fit(query.points, query.normals, self.database[oid], h.T_base_obj, SURFACE_TOL * vox) >= \
                        surface_fit(query.points, query.normals, self.database[oid], best.T_base_obj, SURFACE_TOL * vox) - 0.02:
                    best = h
                    break
        if best is not None and not self.inventory[best.obj_id].is_rotationally_symmetric:
            best = self._yaw_sweep(query, best, scorers[best.obj_id])
        if best is not None and self.inventory[best.obj_id].cls in FLIP_CLASSES:
            best = self._flip_check(query, best, scorers[best.obj_id])
        if best is None:
            return None, query
        return self._accepted(query, best, scorers[best.obj_id]), query

    def _query(self, inst: InstanceMap, views: list[View], point_features: bool = True) -> FusedCloud:
        """One instance's map points as voxel centres with normals and fused features (`point_features=False`:
        without the point encoder's, for a query that is only registered and scored: pose tracking).

        Remembered per scan (`_query_memo`, for these `views`): the query is a function of the instance's points,
        views, pixels and camera centres and the views' images, so the same instance asked again gets the same
        cloud, and one made without point features gets them added (`with_point_features`) instead of being
        fused again: a tracked instance that moved is estimated, a re-fit's local refinement is followed by the
        full estimate, a tracked pose the fine check rejects is estimated on its instance, each on the points
        whose query was just made."""
        if self._query_memo is None or self._query_memo[0] is not views:
            self._query_memo = (views, {})
        memo = self._query_memo[1]
        key = (inst.points.tobytes(), inst.view.tobytes(), inst.pixel.tobytes(),
               np.asarray(inst.cam_centres).tobytes())
        if key in memo:
            cloud, featured = memo[key]
            if featured or not point_features:
                return cloud
            cloud = with_point_features(cloud, self.pt_enc, self.settings.voxel_size)
        else:
            cloud = self._fused(inst, views, point_features)
        memo[key] = (cloud, point_features)
        return cloud

    def _fused(self, inst: InstanceMap, views: list[View], point_features: bool) -> FusedCloud:
        """`_query` computed (features.fuse_instance)."""
        masks: list[np.ndarray | None] = []
        for k, v in enumerate(views):
            sel = inst.view == k
            if not sel.any():
                masks.append(None)
                continue
            mk = np.zeros(v.depth.shape, bool)
            mk[inst.pixel[sel, 0], inst.pixel[sel, 1]] = True
            masks.append(mk)
        return fuse_instance(inst.points, inst.view, inst.pixel, [v.rgb for v in views], masks, inst.cam_centres,
                             self.settings.voxel_size, self.img_enc, self.pt_enc, point_features)

    def _accepted(self, query: FusedCloud, best: Hypothesis, scorer: Scorer) -> Hypothesis | None:
        """`best` with its verification, if it passes the checks every pose must pass; else None."""
        st = self.settings
        # Both overlap ratios must be substantial: a tiny fragment "fully explained" by a model whose visible
        # surface the views do not confirm is no detection (paper: insufficient correspondences / low overlap).
        if best.score < st.min_overlap or best.or_model < 0.15 or self._reach_share(query.points, best) < 0.2:
            return None
        # Verification (perception/verify.py), judged on the final poses in perceive(): poses that fail it may
        # still lead the splitting of a blob to the right fits of its pieces.
        if not self.inventory[best.obj_id].is_rotationally_symmetric:
            turned = turn_clear(scorer, best.T_base_obj, self.inventory[best.obj_id].points)
            if turned is not None:
                best.T_base_obj = turned
                best.score, best.or_query, best.or_model, best.free_space, best.visible_fraction = scorer(turned)
                best.score *= self._colour_weight(query, best, 1.0)
        seen, free = free_space_within(scorer, best.T_base_obj, FREE_SPACE_SHIFT)
        best.verification = verify(query.points, query.normals, self.database[best.obj_id], best.T_base_obj, seen,
                                   free, st.voxel_size)
        return best

    def _track(self, inst: InstanceMap, views: list[View], priors: list[ObjectPose], used: set[int],
               change: "_LazyChange | None" = None) -> tuple[Hypothesis | None, int | None]:
        """Pose tracking (perception/track.py): the prior (not in `used`) that puts most of the instance's points
        on its surface, refined by a few ICP iterations from its pose, if it did not move and passes the checks
        every pose must pass (`_accepted`); with the prior's index. (None, None): the instance gets the full
        estimate. With `change` (this scan's map against the map the priors were perceived on), a prior whose
        surroundings did not change is kept as it was (`_kept`)."""
        vox = self.settings.voxel_size
        k = best_prior(inst.points, priors, self.database, used, 1.5 * vox)
        if k is None:
            return None, None
        prior = priors[k]
        if change is not None:
            kept = self._kept(prior, change.get())
            if kept is not None:
                return kept, k
        query = self._query(inst, views, point_features=False)  # registered and scored only: no FPFH
        if len(query.points) < 8:
            return None, None
        entry = self.database[prior.obj_id]
        sym = self.inventory[prior.obj_id].is_rotationally_symmetric
        scorer = Scorer(entry, query.points, views, vox, inside_solid=self._inside_solid(self._up()),
                        depths=self._depths)
        h = refine(query, entry, scorer, prior.T_base_obj, self.reg_cfg, "track", symmetric=sym, local=True)
        h.score *= self._colour_weight(query, h, 1.0)
        if moved(prior.T_base_obj, h.T_base_obj, sym):
            return None, None
        h = self._accepted(query, h, scorer)
        return (h, k) if h is not None else (None, None)

    def _kept(self, prior: ObjectPose, change: MapChange) -> Hypothesis | None:
        """`prior` as it was (pose, score, visible fraction, verification parts; source KEPT), if the map points
        within its model's diameter of its origin (what its checks and its neighbours' read) are the points they
        were when it was perceived (track.MapChange.unchanged) and it carries its verification's parts; else None."""
        names = Verification.__dataclass_fields__.keys() - {"normals_segment"}
        if not names <= prior.checks.keys():
            return None
        if not change.unchanged(prior.T_base_obj[:3, 3], self.inventory[prior.obj_id].diameter, prior=prior):
            return None
        h = Hypothesis(prior.obj_id, prior.T_base_obj.copy(), prior.score, visible_fraction=prior.visible_fraction,
                       source=KEPT)
        h.verification = Verification(**{n: prior.checks[n] for n in names})
        return h


#: Hypothesis.source of a prior kept as it was (Perceiver._kept)
KEPT = "kept"
# How much farther than their two diameters (metres) a pose counts as a neighbour in the fine check's memo key
# (`Perceiver._fine_key`): the fine fit may move the pose up to a centimetre, and `intruded` measures from there.
FINE_KEY_SLACK = 0.02

# By how much a vessel's pose turned over after a rejection may explain its points less well (`fine`, `explained`,
# `normals`, `free_space`; verification parts are shares) and replace it (Perceiver._retry_turned_over).
TURNED_MARGIN = 0.02
# `_fit_around_rejected`: the map points within this many diameters of a pose rejected by its surroundings alone
# are looked at for an item no pose explains; clusters of fewer points than CONTEXT_MIN_POINTS are not fitted
# (the size of a remainder refitted after a pose).
CONTEXT_REACH = 1.0
CONTEXT_MIN_POINTS = 60
# ... and, for a model with a part off its body turned about its axis, by how much it may explain fewer of the
# points the rejected fit explained (a mug: its handle is ~5 % of the model's surface, up to twice that of a fit's
# points where the handle faced the cameras; the known table failures reproduced: a right turn 0.03-0.11 lower).
TURNED_PART_EXPLAINED = 0.15
# How far (metres) a pose may be off and still count as right (the fits' error on partly hidden items lying or
# leaning: about a centimetre): the free-space check judges the best rigid shift within it (see free_space_within).
FREE_SPACE_SHIFT = 0.01
# ... and counts only a shift that clears most of it (at most this share left): a fit merely off is cleared by one
# shift, a wrong one only in part.
FREE_SPACE_CLEARED = 1 / 3


class _LazyChange:
    """A scan's `MapChange` of its map against the priors' map, with the surface the priors still seen where they
    were put on the points new in this map counted as still there (`MapChange.count_revealed`, at `tol`), made
    on the first `get` (a scan whose instances no prior explains never compares the maps)."""

    def __init__(self, now: np.ndarray, before: np.ndarray, priors: list[ObjectPose], database: CadDatabase,
                 tol: float):
        self.now, self.before, self.priors, self.database, self.tol = now, before, priors, database, tol
        self.change: MapChange | None = None

    def get(self) -> MapChange:
        if self.change is None:
            self.change = MapChange(self.now, self.before)
            self.change.count_revealed(self.priors, self.database, self.tol)
        return self.change


def free_space_within(scorer: Scorer, T_base_obj: np.ndarray, shift: float) -> tuple[float, float]:
    """(seen, free space share) of the pose, where the free-space share is the least over the pose and its rigid
    shifts by `shift` and half of it along the base axes that fit at least as well (overlap score) and keep at
    least as much of the model seen, if that shift leaves at most FREE_SPACE_CLEARED of the pose's own.

    A fit a centimetre off (inside the pose tolerance) puts its outline's model points over the surface behind,
    just past the item's silhouette, where the depth jumps: the pose is right, yet a fifth of its visible points
    read as free space. One rigid shift clears all of them when the fit is merely off; a wrong fit moved by a
    centimetre fits the data worse or still claims free space. (Excusing every point within a margin of the
    outline instead, each point on its own, let more wrong fits in piles through, already at a 3 mm margin.)"""
    score, _, seen, free, _ = scorer(T_base_obj)
    if free <= 0 or shift <= 0:
        return seen, free
    moves = [a * s * e for s in (0.5 * shift, shift) for e in np.eye(3) for a in (1.0, -1.0)]
    Ts = np.repeat(np.asarray(T_base_obj, float)[None], len(moves), axis=0)
    Ts[:, :3, 3] += np.array(moves)
    score_s, _, seen_s, free_s, _ = scorer.batch(Ts)
    ok = (seen_s >= seen) & (score_s >= score)
    if ok.any() and free_s[ok].min() <= FREE_SPACE_CLEARED * free:
        free = float(free_s[ok].min())
    return seen, free


# Turns about a body's axis tried for a part off it where the cameras saw through it (degrees apart).
TURN_STEP = 30


# Turns about the body's axis refined, besides the turn over, when a rejected pose of a model with a part off its
# body (a mug's handle) is retried (Perceiver._turned_over): the best-scoring of 22 (11 turns, either way up).
PART_TURNS_REFINED = 3


def _body_turn(model_points: np.ndarray, angle: float) -> np.ndarray:
    """Object-frame turn by `angle` about the body's axis: the object z axis through the median of the model's
    points across it (a mug's body, not its bounding box, whose middle the handle shifts)."""
    c = np.median(model_points[:, :2], axis=0)
    R = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    turn = np.eye(4)
    turn[:3, :3] = R
    turn[:2, 3] = c - R[:2, :2] @ c
    return turn


def turn_clear(scorer: Scorer, T_base_obj: np.ndarray, model_points: np.ndarray) -> np.ndarray | None:
    """The pose turned about its body's axis (the object z axis through the median of the model's points across
    it: a mug's body, not its bounding box) by a multiple of TURN_STEP that fits at least as well (overlap score),
    keeps at least as much of the model seen and leaves at most FREE_SPACE_CLEARED of the pose's free space, the
    one that fits best (the handle where the depth confirms it, not merely hidden); None if there is none (or no
    free space).

    A mug's body fixes its pose but for the turn about the body's axis; its handle, a small share of its points,
    decides that turn. Fitted with the handle a few tens of degrees off (the handle seen from one view only, a
    neighbour lying over the body), the overlap score barely notices, but the handle's model points hang where
    the cameras see through: free space rejects a pose whose body is right. Turned to where the handle is seen,
    it is cleared; a body with no handle seen anywhere (a can fitted as a mug) is not cleared by any turn."""
    score, _, seen, free, _ = scorer(T_base_obj)
    if free <= 0:
        return None
    Ts = np.array([T_base_obj @ _body_turn(model_points, a) for a in np.radians(np.arange(TURN_STEP, 360, TURN_STEP))])
    score_t, _, seen_t, free_t, _ = scorer.batch(Ts)
    ok = (seen_t >= seen) & (score_t >= score) & (free_t <= FREE_SPACE_CLEARED * free)
    if not ok.any():
        return None
    k = np.flatnonzero(ok)[np.argmax(score_t[ok])]
    return Ts[k]


def _partition(points: np.ndarray, spacing: float) -> list[np.ndarray]:
    """Index arrays of item-sized regions: farthest-point seeds `spacing` apart, each point to its nearest seed."""
    c = points.mean(axis=0)
    seeds = [int(np.argmin(np.linalg.norm(points - c, axis=1)))]
    dmin = np.linalg.norm(points - points[seeds[0]], axis=1)
    while dmin.max() > spacing and len(seeds) < 40:
        k = int(np.argmax(dmin))
        seeds.append(k)
        dmin = np.minimum(dmin, np.linalg.norm(points - points[k], axis=1))
    owner = cKDTree(points[seeds]).query(points)[1]
    return [np.nonzero(owner == k)[0] for k in range(len(seeds)) if (owner == k).sum() >= 30]


def _voxel_centres(points: np.ndarray, voxel: float) -> np.ndarray:
    _, inv_, cnt = np.unique(voxel_keys(points, voxel), return_inverse=True, return_counts=True)
    out = np.zeros((len(cnt), 3))
    np.add.at(out, inv_.reshape(-1), points)
    return out / cnt[:, None]


def _clusters(points: np.ndarray, eps: float, min_points: int, grid: float) -> list[np.ndarray]:
    """Index arrays of the DBSCAN clusters (Open3D, on a `grid`-voxel subsample for speed) with at least
    `min_points` of the original points."""
    _, first, inv_ = np.unique(voxel_keys(points, grid), return_index=True, return_inverse=True)
    inv_ = inv_.reshape(-1)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[first]))
    lab = np.asarray(pc.cluster_dbscan(eps, 3, print_progress=False))[inv_]
    out = []
    for k in range(lab.max() + 1 if len(lab) else 0):
        idx = np.nonzero(lab == k)[0]
        if len(idx) >= min_points:
            out.append(idx)
    return out
