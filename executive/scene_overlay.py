"""What the operator page draws over the camera images: the perceived objects' outlines and the chosen grasp, in
image coordinates of the views they were perceived from.

The runner's views, poses, selected object and pick plan change as it works. :class:`PerceptionTracker` is a
runner listener: it keeps references to them at the transitions where they belong together (:data:`PERCEIVED`:
the views and the poses found in them; ``selected``: the object chosen; ``planned``: its grasp), so a drawing
never mixes one scan's image with another scan's poses. Nothing is computed in the runner's thread; the
outlines are rendered when asked for (:meth:`PerceptionTracker.overlay`) and cached per perception.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import cv2
import numpy as np

from kitchenbot.perception.overlay import silhouette
from kitchenbot.planning.collision import GripperGeometry
from kitchenbot.transforms import inv

#: Outlines are traced on a raycast at 1/OUTLINE_SCALE of the image size (4x fewer rays; a pixel of error at
#: the image's own size is invisible on the page).
OUTLINE_SCALE = 2
#: Triggers fired right after a perception: by the perceive state, and by verify (it re-scans and perceives).
PERCEIVED = ("perceived", "next_object", "complete")


@dataclass
class Perception:
    """One perception: its views and the object poses found in them (references the runner replaces, never
    mutates)."""

    seq: int
    views: list
    poses: list
    selected: object = None  # ObjectPose chosen by select_grasp (one of `poses`, or a staged item)
    grasp: object = None  # planning.types.Grasp of the planned pick
    sim_t: float | None = None
    outlines: dict = field(default_factory=dict)  # view index -> [object dict], computed on demand
    views_ref: object = None  # the runner's list itself (a new scan assigns a new one)


class PerceptionTracker:
    """Runner listener that keeps the latest consistent perception, selected object and grasp."""

    def __init__(self, runner):
        self.runner = runner
        self.inventory = runner.robot.inventory
        self._lock = threading.Lock()
        self.latest: Perception | None = None

    def on_event(self, ev: dict) -> None:
        """Called in the runner's thread right after each event: only takes references."""
        if ev.get("type") != "transition":
            return
        r, trig = self.runner, ev.get("trigger")
        fresh = self.latest is None or r.views is not self.latest.views_ref
        if trig in PERCEIVED and fresh:
            with self._lock:
                seq = self.latest.seq + 1 if self.latest else 1
                self.latest = Perception(seq, list(r.views), list(r.belief.poses), sim_t=ev.get("sim_t"),
                                         views_ref=r.views)
        elif trig == "selected" and self.latest is not None:
            self.latest.selected, self.latest.grasp = r.item.obj, None
        elif trig == "planned" and self.latest is not None:
            pick = r.item.pick
            self.latest.grasp = pick.grasp if pick is not None else None

    def image(self, index: int) -> np.ndarray | None:
        p = self.latest
        if p is None or not 0 <= index < len(p.views):
            return None
        return p.views[index].rgb

    def overlay(self) -> dict:
        """{"seq", "sim_t", "views": [{"index", "width", "height", "objects": [...], "grasp": {...} | None}]}.
        Objects: {"obj_id", "cls", "name", "score", "instance_id", "selected", "outline": [[x, y], ...]} for those
        whose silhouette falls in the image; grasp: TCP, pre-grasp and the two finger pads projected."""
        p = self.latest
        if p is None:
            return {"seq": 0, "sim_t": None, "views": [], "grasp": None}
        views = []
        for k, v in enumerate(p.views):
            with self._lock:
                if k not in p.outlines:
                    p.outlines[k] = self._outlines(v, p.poses)
            objs = [o | {"selected": _same(p.poses[o["i"]], p.selected)} for o in p.outlines[k]]
            w, h = v.size
            views.append({"index": k, "width": w, "height": h, "objects": [_public(o) for o in objs],
                          "grasp": _grasp_in_image(p.grasp, v) if p.grasp is not None else None})
        g = p.grasp
        summary = None
        if g is not None:
            summary = {"name": g.spec.name, "cls": g.obj.cls, "opening": float(g.spec.opening),
                       "xyz": np.round(g.T_base_tcp[:3, 3], 4).tolist()}
        return {"seq": p.seq, "sim_t": p.sim_t, "views": views, "grasp": summary}

    def _outlines(self, view, poses) -> list[dict]:
        w, h = view.size
        s = OUTLINE_SCALE
        K = np.asarray(view.K, float).copy()
        K[:2] /= s
        T_cam_base = inv(np.asarray(view.T_base_cam, float))
        out = []
        for i, p in enumerate(poses):
            model = self.inventory.models.get(p.obj_id)
            if model is None:
                continue
            mask = silhouette(model.mesh, T_cam_base @ np.asarray(p.T_base_obj, float), K, w // s, h // s)
            cs, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            if not cs:
                continue
            c = cv2.approxPolyDP(max(cs, key=cv2.contourArea), 1.0, True)[:, 0, :]
            outline = ((c.astype(float) + 0.5) * s).round(1).tolist()
            out.append({"i": i, "obj_id": int(p.obj_id), "cls": p.cls, "name": model.name,
                        "score": round(float(p.score), 3), "instance_id": int(p.instance_id), "outline": outline})
        return out


def _same(a, b) -> bool:
    if a is None or b is None:
        return False
    return a is b or (a.instance_id >= 0 and a.instance_id == b.instance_id and a.cls == b.cls)


def _public(o: dict) -> dict:
    return {k: v for k, v in o.items() if k != "i"}


def project(points_base: np.ndarray, view) -> list[list[float] | None]:
    """Pinhole projection of base-frame points into the view ([x, y] pixels; None behind the camera)."""
    T = inv(np.asarray(view.T_base_cam, float))
    pc = (T[:3, :3] @ np.asarray(points_base, float).T).T + T[:3, 3]
    K = np.asarray(view.K, float)
    out: list[list[float] | None] = []
    for x, y, z in pc:
        if z <= 1e-3:
            out.append(None)
            continue
        out.append([round(float(K[0, 0] * x / z + K[0, 2]), 1), round(float(K[1, 1] * y / z + K[1, 2]), 1)])
    return out


def _grasp_in_image(g, view) -> dict | None:
    """The TCP, the pre-grasp point and the two finger pads (root to tip, at +-opening/2 along the TCP's y, the
    closing axis: planning.collision.GripperGeometry) in image coordinates."""
    geo = GripperGeometry()
    T = np.asarray(g.T_base_tcp, float)
    o = float(g.spec.opening) / 2 + geo.pad_thickness / 2
    local = np.array([[0, 0, 0], [0, o, geo.pad_root], [0, o, geo.pad_tip], [0, -o, geo.pad_root],
                      [0, -o, geo.pad_tip]], float)
    pts = (T[:3, :3] @ local.T).T + T[:3, 3]
    pts = np.vstack([pts, np.asarray(g.T_base_pregrasp, float)[:3, 3]])
    px = project(pts, view)
    if any(p is None for p in px):
        return None
    w, h = view.size
    if not any(-w <= x <= 2 * w and -h <= y <= 2 * h for x, y in px):
        return None
    return {"name": g.spec.name, "cls": g.obj.cls, "tcp": px[0], "fingers": [[px[1], px[2]], [px[3], px[4]]],
            "pregrasp": px[5]}
