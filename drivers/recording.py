"""Camera captures on disk: record RGB-D frames with their pose, read them back.

A recording is a folder of numbered captures::

    000000_rgb.png     8-bit RGB
    000000_depth.png   16-bit depth in millimetres (0 = invalid), the BOP/OAK-D convention
    000000.json        {"rgb", "depth", "depth_scale_m": 0.001, "K": 3x3, "T_base_cam": 4x4 or null, "stamp", ...}

:class:`CaptureRecorder` writes it (:class:`RecordingCamera` records any camera as it is used),
:func:`load_capture` / :func:`list_captures` read it, and
``drivers.replay_camera.ReplayCamera`` serves it back as a Camera. The depth conversions are pure functions
shared with the OAK-D driver.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from kitchenbot.drivers.camera import Camera, Frame
from kitchenbot.drivers.errors import DriverError
from kitchenbot.jsonfile import read_json

DEPTH_SCALE_M = 0.001  # one PNG unit = 1 mm
FORMAT_VERSION = 1


class RecordingError(DriverError):
    """A recording folder or one of its files is missing or unreadable; the message names the path."""


# ---- depth units (pure) ----------------------------------------------------------------------------------
def depth_mm_to_m(depth_mm: np.ndarray, scale_m: float = DEPTH_SCALE_M) -> np.ndarray:
    """uint16 depth (0 = invalid) -> float32 metres, invalid stays 0."""
    d = np.asarray(depth_mm)
    if d.ndim != 2:
        raise ValueError(f"depth: expected an (H, W) image, got shape {d.shape}")
    return d.astype(np.float32) * np.float32(scale_m)


def depth_m_to_mm(depth_m: np.ndarray, scale_m: float = DEPTH_SCALE_M) -> np.ndarray:
    """float metres -> uint16 units of `scale_m` (rounded); NaN, inf, <= 0 and out-of-range become 0 (invalid)."""
    d = np.asarray(depth_m, dtype=np.float64)
    if d.ndim != 2:
        raise ValueError(f"depth: expected an (H, W) image, got shape {d.shape}")
    units = np.round(d / scale_m)
    valid = np.isfinite(units) & (units > 0) & (units <= 65535)
    return np.where(valid, units, 0).astype(np.uint16)


# ---- one capture ------------------------------------------------------------------------------------------
@dataclass
class Capture:
    frame: Frame
    T_base_cam: np.ndarray | None  # 4x4 pose of the camera when the frame was taken (None if unknown)
    index: int
    path: Path  # the JSON file


def _matrix(value, shape: tuple[int, int], what: str, path: Path) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        m = np.zeros(0)
    if m.shape != shape or not np.all(np.isfinite(m)):
        raise RecordingError(f"{path}: '{what}' must be a finite {shape[0]}x{shape[1]} matrix, got {value!r}")
    return m


def load_capture(json_path: str | Path) -> Capture:
    """Read one capture (its JSON and the two PNGs it names); every problem names the file."""
    path = Path(json_path)
    meta = read_json(path, RecordingError, "capture metadata")
    if not isinstance(meta, dict):
        raise RecordingError(f"{path}: expected a JSON object, got {type(meta).__name__}")
    for key in ("rgb", "depth", "K", "stamp"):
        if key not in meta:
            raise RecordingError(f"{path}: missing key '{key}'")
    K = _matrix(meta["K"], (3, 3), "K", path)
    T = None if meta.get("T_base_cam") is None else _matrix(meta["T_base_cam"], (4, 4), "T_base_cam", path)

    rgb_path, depth_path = path.parent / meta["rgb"], path.parent / meta["depth"]
    bgr = cv2.imread(str(rgb_path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise RecordingError(f"{rgb_path}: missing or not a readable image (named by {path.name})")
    depth_raw = cv2.imread(str(depth_path), cv2.IMREAD_UNCHANGED)
    if depth_raw is None:
        raise RecordingError(f"{depth_path}: missing or not a readable image (named by {path.name})")
    if depth_raw.dtype != np.uint16 or depth_raw.ndim != 2:
        raise RecordingError(
            f"{depth_path}: expected a single-channel 16-bit PNG (depth in mm), got {depth_raw.dtype} {depth_raw.shape}"
        )
    if depth_raw.shape != bgr.shape[:2]:
        raise RecordingError(f"{depth_path}: size {depth_raw.shape[::-1]} differs from the RGB image {bgr.shape[1::-1]}")
    scale = float(meta.get("depth_scale_m", DEPTH_SCALE_M))
    frame = Frame(
        rgb=np.ascontiguousarray(bgr[:, :, ::-1]),
        depth=depth_mm_to_m(depth_raw, scale),
        K=K,
        stamp=float(meta["stamp"]),
    )
    return Capture(frame=frame, T_base_cam=T, index=int(meta.get("index", 0)), path=path)


def list_captures(folder: str | Path) -> list[Path]:
    """The capture JSON files of a recording, in order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RecordingError(f"{folder}: recording folder does not exist")
    files = sorted(p for p in folder.glob("*.json") if p.stem.isdigit())
    if not files:
        raise RecordingError(f"{folder}: no captures (expected files like 000000.json with _rgb.png/_depth.png)")
    return files


class CaptureRecorder:
    """Append captures to a folder (created if needed); numbering continues after existing captures."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        existing = [int(p.stem) for p in self.folder.glob("*.json") if p.stem.isdigit()]
        self.next_index = max(existing) + 1 if existing else 0

    def save(self, frame: Frame, T_base_cam: np.ndarray | None = None, **extra) -> Path:
        """Write one capture; returns its JSON path. `extra` (JSON-serialisable) is stored alongside."""
        i = self.next_index
        stem = f"{i:06d}"
        rgb_name, depth_name = f"{stem}_rgb.png", f"{stem}_depth.png"
        if not cv2.imwrite(str(self.folder / rgb_name), np.ascontiguousarray(frame.rgb[:, :, ::-1])):
            raise RecordingError(f"{self.folder / rgb_name}: could not write the image")
        if not cv2.imwrite(str(self.folder / depth_name), depth_m_to_mm(frame.depth)):
            raise RecordingError(f"{self.folder / depth_name}: could not write the image")
        meta = {
            "format": FORMAT_VERSION,
            "index": i,
            "rgb": rgb_name,
            "depth": depth_name,
            "depth_scale_m": DEPTH_SCALE_M,
            "width": frame.size[0],
            "height": frame.size[1],
            "K": np.asarray(frame.K, float).tolist(),
            "T_base_cam": None if T_base_cam is None else np.asarray(T_base_cam, float).tolist(),
            "stamp": float(frame.stamp),
            **extra,
        }
        path = self.folder / f"{stem}.json"
        path.write_text(json.dumps(meta, indent=1))  # written last: a capture exists once its JSON does
        self.next_index += 1
        return path


class RecordingCamera(Camera):
    """Wraps any camera: each capture is passed through and also saved, with the camera pose from `pose_fn()`
    (e.g. ``lambda: arm.flange_pose() @ T_flange_cam``) when given. Replay with ``ReplayCamera(folder)``."""

    def __init__(self, camera: Camera, folder: str | Path, pose_fn: Callable[[], np.ndarray] | None = None):
        self.camera = camera
        self.recorder = CaptureRecorder(folder)
        self.pose_fn = pose_fn

    def connect(self) -> None:
        self.camera.connect()

    def disconnect(self) -> None:
        self.camera.disconnect()

    @property
    def is_connected(self) -> bool:
        return self.camera.is_connected

    def capture(self, timeout: float = 2.0) -> Frame:
        frame = self.camera.capture(timeout)
        self.recorder.save(frame, None if self.pose_fn is None else self.pose_fn())
        return frame

    def intrinsics(self) -> np.ndarray:
        return self.camera.intrinsics()
