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
from kitchenbot.perception.features import FusedCloud, fuse_instance, make_image_encoder, make_point_encoder
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


def make_detector(settings: PerceptionSettings, cell: Cell) -> tuple[Detector, Segmenter]:
    """The configured detector and segmenter (learned ones are registered by issue 4's backends)."""
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
                 database: CadDatabase | None = None):
        self.settings = settings or PerceptionSettings()
        self.inventory = inventory or Inventory.builtin()
        self.cell = cell or Cell()
        d, s = make_detector(self.settings, self.cell) if detector is None else (detector, None)
        self.detector = d
        self.segmenter = segmenter or s or PassThroughSegmenter()
        self.img_enc = make_image_encoder(self.settings.image_encoder)
        self.pt_enc = make_point_encoder(self.settings.point_encoder)
        self._db = database
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
        db = self.database
        if len(views) > 1 and self.settings.align_views:
            with timed("align"):
                views, _ = align_views(views, self.settings.voxel_size)
        with timed("segment"):
            dets = [self.segmenter.segment(v, self.detector.detect(v)) for v in views]
        with timed("associate"):
            ids = associate(views, dets, self.settings.iou_threshold)
        with timed("map"):
            m = consolidate(build_map(views, dets, ids))
        poses: list[ObjectPose] = []
        pose_ms: list[float] = []
        rejected = 0
        with timed("pose"):
            queue = list(m.instance_ids)
            next_id = max(queue) + 1 if queue else 0
            ids_out = m.ids.copy()
            splits = 0
            while queue:
                iid = queue.pop(0)
                sel = np.nonzero(ids_out == iid)[0]
                if len(sel) < 30:
                    ids_out[sel] = -1
                    continue
                t0 = time.perf_counter()
                hyp, query = self.estimate(m.select(sel), views)
                pose_ms.append(1000 * (time.perf_counter() - t0))
                if hyp is None:
                    rejected += 1
                    continue
                model = self.inventory[hyp.obj_id]
                # Points the pose explains belong to it; a large unexplained remainder is another object
                # (stacked / nested / touching items that segmentation could not separate).
                Ti = inv(hyp.T_base_obj)
                P = m.points[sel]
                d, _ = cKDTree(db[hyp.obj_id].dense_points).query(P @ Ti[:3, :3].T + Ti[:3, 3])
                explained = d < 1.5 * self.settings.voxel_size
                poses.append(ObjectPose(hyp.obj_id, model.cls, hyp.T_base_obj, hyp.score, P[explained], iid,
                                        hyp.visible_fraction))
                rest = sel[~explained]
                if splits < self.settings.max_splits and len(rest) >= 60:
                    for part in _clusters(m.points[rest], 1.5 * self.settings.voxel_size, 60):
                        ids_out[rest[part]] = next_id
                        queue.append(next_id)
                        next_id += 1
                        splits += 1
        m = InstanceMap(m.points, ids_out, m.view, m.pixel, m.cam_centres)
        return PerceptionResult(poses, m, dets, timings, pose_ms, rejected, list(views))

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
        rng = np.random.default_rng(0)
        best: Hypothesis | None = None
        for oid, _sim in cands:
            entry = self.database[oid]
            scorer = Scorer(entry, query.points, views, st.voxel_size)
            h = register_candidate(query, entry, self.inventory[oid], scorer, self.reg_cfg, rng)
            if best is None or h.score > best.score:
                best = h
        if best is None or best.score < st.min_overlap:
            return None, query
        return best, query


def _clusters(points: np.ndarray, eps: float, min_points: int) -> list[np.ndarray]:
    """Index arrays of the DBSCAN clusters (Open3D) with at least `min_points` points."""
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    lab = np.asarray(pc.cluster_dbscan(eps, 8, print_progress=False))
    out = []
    for k in range(lab.max() + 1 if len(lab) else 0):
        idx = np.nonzero(lab == k)[0]
        if len(idx) >= min_points:
            out.append(idx)
    return out
