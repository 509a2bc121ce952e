"""Run recordings: a rerun ``.rrd`` per run, and every scan saved as a BOP scene (so real runs grow a dataset).

Recorder (rerun SDK, a RecordingStream saved to a file): per view the RGB, the depth (metres) and the pinhole
camera with its base-frame pose; the perception map points and the estimated object poses (model points at
each pose); planned trajectories as TCP polylines; every state change as a text log and a scalar-free
timeline ``sim_time`` / ``step``.

ScanDataset: ``<dir>/<split>/<scene_id:06d>/{rgb,depth}/<im_id:06d>.png`` + ``scene_camera.json`` (``cam_K``,
``cam_R_w2c``, ``cam_t_w2c`` in mm with base = world, ``depth_scale``) + ``scene_est.json`` (the poses the
executive acted on, for later labelling). Same layout as the BOP writer in fakes/bop.py, without ground truth.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from kitchenbot.drivers.ur_kinematics import fk_flange
from kitchenbot.perception.types import View
from kitchenbot.transforms import inv

DEPTH_SCALE = 0.1  # mm per depth PNG unit (BOP convention: depth_mm = value * depth_scale)


class Recorder:
    """Writes one rerun recording for one run."""

    def __init__(self, path: str | Path, robot_model, T_flange_tcp: np.ndarray, inventory, run_name: str = "run"):
        import rerun as rr

        self.rr = rr
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rec = rr.RecordingStream("kitchenbot", recording_id=f"{run_name}")
        self.rec.save(str(self.path))
        self.model, self.T_flange_tcp, self.inventory = robot_model, T_flange_tcp, inventory
        self.step = 0
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def _time(self, sim_t: float | None) -> None:
        self.step += 1
        self.rec.set_time("step", sequence=self.step)
        if sim_t is not None:
            self.rec.set_time("sim_time", duration=float(sim_t))

    def state(self, src: str, dest: str, trigger: str, sim_t: float | None) -> None:
        self._time(sim_t)
        self.rec.log("executive/state", self.rr.TextLog(f"{src} --{trigger}--> {dest}"))

    def views(self, views: list[View], sim_t: float | None) -> None:
        rr = self.rr
        self._time(sim_t)
        for k, v in enumerate(views):
            base = f"world/cam{k}"
            self.rec.log(base, rr.Transform3D(translation=v.T_base_cam[:3, 3], mat3x3=v.T_base_cam[:3, :3]))
            h, w = v.depth.shape
            self.rec.log(base, rr.Pinhole(image_from_camera=v.K, resolution=[w, h]))
            self.rec.log(f"{base}/rgb", rr.Image(v.rgb).compress(jpeg_quality=85))
            depth_mm = np.round(np.nan_to_num(v.depth, nan=0.0) * 1000).clip(0, 65535).astype(np.uint16)
            self.rec.log(f"{base}/depth", rr.DepthImage(depth_mm, meter=1000.0))

    def perception(self, result, poses, sim_t: float | None) -> None:
        rr = self.rr
        self._time(sim_t)
        pts = getattr(result, "map_points", None)
        if pts is not None and len(pts):
            ids = getattr(result, "map_ids", None)
            cls = (np.asarray(ids) + 1).clip(0, 65535).astype(np.uint16) if ids is not None else None  # 0 = none
            self.rec.log("world/map", rr.Points3D(pts, class_ids=cls, radii=0.002))
        for k, p in enumerate(poses):
            m = self.inventory[p.obj_id]
            P = m.points[::8] @ p.T_base_obj[:3, :3].T + p.T_base_obj[:3, 3]
            self.rec.log(f"world/objects/{k}", rr.Points3D(P, colors=np.array(m.colour) * 255, radii=0.002,
                                                          labels=[f"{p.cls} {p.score:.2f}"] + [""] * (len(P) - 1)))
        masks = [d for d in (getattr(result, "detections", None) or [])]
        for k, dets in enumerate(masks):
            seg = None
            for j, d in enumerate(dets):
                mk = getattr(d, "mask", None)
                if mk is None:
                    continue
                if seg is None:
                    seg = np.zeros(mk.shape, np.uint16)
                seg[mk] = j + 1
            if seg is not None:
                self.rec.log(f"world/cam{k}/masks", rr.SegmentationImage(seg))

    def plan(self, trajectories, sim_t: float | None) -> None:
        self._time(sim_t)
        for t in trajectories:
            P = np.array([(fk_flange(self.model, q) @ self.T_flange_tcp)[:3, 3] for q in t.q[:: max(1, len(t.q) // 50)]])
            self.rec.log(f"world/plan/{t.name or 'trajectory'}", self.rr.LineStrips3D([P], radii=0.003))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()


class ScanDataset:
    """Appends each scan as one BOP scene under `root/split`."""

    def __init__(self, root: str | Path, split: str = "scans"):
        self.dir = Path(root) / split
        self.dir.mkdir(parents=True, exist_ok=True)
        existing = [int(p.name) for p in self.dir.iterdir() if p.is_dir() and p.name.isdigit()]
        self.next_id = max(existing, default=-1) + 1

    def write_scan(self, views: list[View], estimates: list | None = None) -> Path:
        scene = self.dir / f"{self.next_id:06d}"
        self.next_id += 1
        (scene / "rgb").mkdir(parents=True, exist_ok=True)
        (scene / "depth").mkdir(parents=True, exist_ok=True)
        cams = {}
        for im_id, v in enumerate(views):
            Image.fromarray(v.rgb).save(scene / "rgb" / f"{im_id:06d}.png")
            d = np.round(np.nan_to_num(v.depth, nan=0.0) * 1000.0 / DEPTH_SCALE).clip(0, 65535).astype(np.uint16)
            Image.fromarray(d).save(scene / "depth" / f"{im_id:06d}.png")
            T = inv(v.T_base_cam)
            cams[str(im_id)] = {"cam_K": v.K.reshape(-1).tolist(), "depth_scale": DEPTH_SCALE,
                                "cam_R_w2c": T[:3, :3].reshape(-1).tolist(), "cam_t_w2c": (T[:3, 3] * 1000).tolist(),
                                "stamp": float(v.stamp)}
        (scene / "scene_camera.json").write_text(json.dumps(cams))
        return scene
