"""The perception pipeline, top to bottom: views -> masks -> instances -> map -> features -> candidates -> poses.

    perceiver = Perceiver(PerceptionSettings(), Inventory.builtin(), Cell())
    result = perceiver.perceive(views)      # result.poses: list[ObjectPose] in the base frame

Each stage is its own module and runnable alone; this file only wires them and times them.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from kitchenbot.perception.associate import associate
from kitchenbot.perception.cell import Cell
from kitchenbot.perception.database import CadDatabase
from kitchenbot.perception.detect import Detection, Detector, PassThroughSegmenter, Segmenter
from kitchenbot.perception import backends
from kitchenbot.perception.features import FusedCloud, fuse_instance
from kitchenbot.perception.inventory import Inventory
from kitchenbot.perception.map import InstanceMap, align_views, build_map, consolidate
from kitchenbot.perception.register import Hypothesis, RegistrationConfig, Scorer, propose, register_candidate
from kitchenbot.perception.rgbd import check_view
from kitchenbot.perception.segment_geometric import GeometricSegmenter
from kitchenbot.perception.settings import PerceptionSettings
from kitchenbot.perception.types import ObjectPose, View
from kitchenbot.transforms import inv


@dataclass
class PerceptionResult:
    poses: list[ObjectPose]
    map: InstanceMap  # fused points (x, y, z) with instance ids, base frame
    detections: list[list[Detection]] = field(default_factory=list)  # per view
    timings_ms: dict[str, float] = field(default_factory=dict)  # per stage, whole call
    pose_ms: list[float] = field(default_factory=list)  # per instance: features + candidates + registration
    rejected: int = 0  # instances no inventory model explained
    views: list[View] = field(default_factory=list)  # the views as used (poses after alignment)

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
                 database: CadDatabase | None = None, use_cell: bool = True):
        """`use_cell=False`: no known cell geometry (e.g. a BOP dataset of a table top); the geometric
        segmenter then removes the dominant support plane instead of the cell's surfaces."""
        self.settings = settings or PerceptionSettings()
        self.inventory = inventory or Inventory.builtin()
        self.cell = (cell or Cell()) if use_cell else None
        d, s = make_detector(self.settings, self.cell) if detector is None else (detector, None)
        self.detector = d
        self.segmenter = segmenter or s or PassThroughSegmenter()
        self.img_enc = backends.make_image_encoder(self.settings)  # colour | none | learned (fusion on/off)
        self.pt_enc = backends.make_point_encoder(self.settings.point_encoder)  # fpfh | plug-ins
        self._db = database
        self.settings_seed = 0
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
    def perceive(self, views: list[View]) -> PerceptionResult:
        timings: dict[str, float] = {}

        @contextmanager
        def timed(name: str):
            t0 = time.perf_counter()
            yield
            timings[name] = timings.get(name, 0.0) + 1000 * (time.perf_counter() - t0)

        for k, v in enumerate(views):
            check_view(v, f"views[{k}]")
        o3d.utility.random.seed(self.settings_seed)  # Open3D's RANSAC: same views, same answer
        db = self.database
        if len(views) > 1 and self.settings.align_views:
            with timed("align"):
                views, _ = align_views(views, self.settings.voxel_size)
        with timed("segment"):
            dets = backends.detect_and_segment(self.detector, self.segmenter, views)  # batched when learned
        with timed("associate"):
            ids = associate(views, dets, self.settings.iou_threshold)
        with timed("map"):
            m = consolidate(build_map(views, dets, ids))
        poses: list[ObjectPose] = []
        pose_ms: list[float] = []
        rejected = 0
        vox = self.settings.voxel_size
        with timed("pose"):
            queue = list(m.instance_ids)
            next_id = max(queue) + 1 if queue else 0
            ids_out = m.ids.copy()
            splits = 0
            found: list[tuple[Hypothesis, int]] = []
            while queue:
                iid = queue.pop(0)
                sel = np.nonzero(ids_out == iid)[0]
                if len(sel) < 30:
                    ids_out[sel] = -1
                    continue
                t0 = time.perf_counter()
                hyp, _query = self.estimate(m.select(sel), views)
                pose_ms.append(1000 * (time.perf_counter() - t0))
                if hyp is None:
                    rejected += 1
                    continue
                found.append((hyp, iid))
                # Points the pose explains belong to it; a large unexplained remainder is another object
                # (stacked / nested / touching items that segmentation could not separate).
                explained = self._explained(hyp, m.points[sel])
                rest = sel[~explained]
                if splits < self.settings.max_splits and len(rest) >= 60:
                    for part in _clusters(m.points[rest], 1.5 * vox, 60, vox / 2):
                        ids_out[rest[part]] = next_id
                        queue.append(next_id)
                        next_id += 1
                        splits += 1
            # One object, one pose: a pose whose explained map points are mostly claimed by a better-scoring
            # pose is a duplicate (the same object reached from two instances or a split remainder).
            claimed = np.zeros(len(m.points), bool)
            tree = cKDTree(m.points) if len(m.points) else None
            for hyp, iid in sorted(found, key=lambda t: -t[0].score):
                model = self.inventory[hyp.obj_id]
                near = np.array(tree.query_ball_point(hyp.T_base_obj[:3, 3], model.diameter / 2 + 2 * vox), int)
                expl = near[self._explained(hyp, m.points[near])] if len(near) else near
                if len(expl) == 0 or claimed[expl].mean() > 0.5:
                    continue
                claimed[expl] = True
                ids_out[expl] = iid
                poses.append(ObjectPose(hyp.obj_id, model.cls, hyp.T_base_obj, hyp.score, m.points[expl], iid,
                                        hyp.visible_fraction))
        m = InstanceMap(m.points, ids_out, m.view, m.pixel, m.cam_centres)
        return PerceptionResult(poses, m, dets, timings, pose_ms, rejected, list(views))

    def _explained(self, hyp: Hypothesis, points: np.ndarray) -> np.ndarray:
        """Which points lie on the posed model's surface (within 1.5 voxels)."""
        if len(points) == 0:
            return np.zeros(0, bool)
        Ti = inv(hyp.T_base_obj)
        d, _ = self.database[hyp.obj_id].tree.query(points @ Ti[:3, :3].T + Ti[:3, 3],
                                                     distance_upper_bound=1.5 * self.settings.voxel_size)
        return np.isfinite(d)

    def estimate(self, inst: InstanceMap, views: list[View]) -> tuple[Hypothesis | None, FusedCloud]:
        """Class and pose of one instance (its map points), or None when no model explains it."""
        st = self.settings
        masks: list[np.ndarray | None] = []
        for k, v in enumerate(views):
            sel = inst.view == k
            if not sel.any():
                masks.append(None)
                continue
            mk = np.zeros(v.depth.shape, bool)
            mk[inst.pixel[sel, 0], inst.pixel[sel, 1]] = True
            masks.append(mk)
        query = fuse_instance(inst.points, inst.view, inst.pixel, [v.rgb for v in views], masks, inst.cam_centres,
                              st.voxel_size, self.img_enc, self.pt_enc)
        if len(query.points) < 8:
            return None, query
        cands = propose(query, self.database, st.top_k, st.candidate_threshold)
        up = getattr(self.detector, "support_normal", None) if self.cell is None else None
        best: Hypothesis | None = None
        for oid, _sim, img_sim in cands:
            entry = self.database[oid]
            scorer = Scorer(entry, query.points, views, st.voxel_size)
            h = register_candidate(query, entry, self.inventory[oid], scorer, self.reg_cfg, up)
            if np.isfinite(img_sim):
                # Appearance must agree too: geometry alone confuses e.g. two nested cups with one glass.
                h.score *= 0.6 + 0.4 * max(0.0, img_sim)
            if best is None or h.score > best.score:
                best = h
        if best is None or best.score < st.min_overlap:
            return None, query
        return best, query


def _clusters(points: np.ndarray, eps: float, min_points: int, grid: float) -> list[np.ndarray]:
    """Index arrays of the DBSCAN clusters (Open3D, on a `grid`-voxel subsample for speed) with at least
    `min_points` of the original points."""
    key = np.floor(points / grid).astype(np.int64)
    _, first, inv_ = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv_ = inv_.reshape(-1)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[first]))
    lab = np.asarray(pc.cluster_dbscan(eps, 3, print_progress=False))[inv_]
    out = []
    for k in range(lab.max() + 1 if len(lab) else 0):
        idx = np.nonzero(lab == k)[0]
        if len(idx) >= min_points:
            out.append(idx)
    return out
