"""Calibration files: the hand-eye result YAML that ``kitchenbot calibrate`` writes and the cell config reads,
and the recorded-samples JSON that ``kitchenbot calibrate solve`` reads.

Result YAML::

    T_flange_cam: [[...4 numbers...] x 4]   # eye in hand (or T_base_cam for eye to hand), metres
    method: park_martin_1994             # or park_martin_1994+reprojection (refined on the corner pixels)
    mount: eye_in_hand
    date: 2026-11-22T00:30:00+00:00
    samples_used: 14
    residuals: {rotation_deg: 0.03, translation_mm: 0.2, ...}   # means over the retained pairs, plus details

Samples JSON::

    {"mount": "eye_in_hand", "samples": [{"T_base_flange": 4x4, "T_cam_board": 4x4}, ...]}

optionally with the detected corners (then `solve` refines on the pixels like the routine): a top-level
`K` (3x3) and `dist` (list or null), and per sample `object_points` (N x 3, board frame, m) and
`image_points` (N x 2, px).
"""

from __future__ import annotations

import datetime as _dt
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from kitchenbot.calibration.park_martin import MOUNTS, X_NAME
from kitchenbot.calibration.residuals import HandEyeResult
from kitchenbot.jsonfile import read_json
from kitchenbot.transforms import is_rigid

class CalibrationFileError(ValueError):
    """A calibration or samples file is missing, unreadable, or lacks a valid key."""


def _matrix(value: Any, where: str) -> np.ndarray:
    try:
        T = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationFileError(f"{where}: expected a 4x4 nested list of numbers (metres)") from None
    if T.shape != (4, 4):
        raise CalibrationFileError(f"{where}: expected a 4x4 nested list (metres), got shape {T.shape}")
    if not is_rigid(T, tol=1e-4):
        raise CalibrationFileError(f"{where}: not a rigid transform (orthonormal rotation, last row 0 0 0 1)")
    return T


def save_hand_eye(path: str | Path, result: HandEyeResult, extra: dict | None = None) -> Path:
    """Write `result` as the calibration YAML (4x4 nested list in metres, method, date, residuals)."""
    path = Path(path)
    doc: dict[str, Any] = {
        result.name: [[float(v) for v in row] for row in result.X],
        "method": result.method,
        "mount": result.mount,
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "samples_used": len(result.samples_used),
        "samples_total": result.n_samples,
        "residuals": result.summary(),
    }
    if extra:
        doc.update(extra)
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))
    return path


def read_hand_eye(path: str | Path) -> dict:
    """The calibration YAML as a mapping, with its transform validated (key `T_flange_cam` or `T_base_cam`)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise CalibrationFileError(f"{path}: cannot read the hand-eye calibration file ({e.strerror})") from None
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise CalibrationFileError(f"{path}: not valid YAML: {e}") from None
    if not isinstance(doc, dict):
        raise CalibrationFileError(f"{path}: expected a mapping with T_flange_cam or T_base_cam at the top level")
    keys = [k for k in X_NAME.values() if k in doc]
    if not keys:
        raise CalibrationFileError(f"{path}: missing key T_flange_cam (eye in hand) or T_base_cam (eye to hand)")
    for k in keys:
        doc[k] = _matrix(doc[k], f"{path}: {k}")
    return doc


def load_hand_eye(path: str | Path, key: str = "T_flange_cam") -> np.ndarray:
    """The 4x4 transform stored under `key` in a calibration YAML (metres). Clear error naming the file and key."""
    doc = read_hand_eye(path)
    if key not in doc:
        other = [k for k in X_NAME.values() if k in doc]
        raise CalibrationFileError(f"{path}: missing key {key} (the file holds {', '.join(other)})")
    return doc[key]


def load_samples(path: str | Path) -> tuple[str, list[np.ndarray], list[np.ndarray]]:
    """(mount, T_base_flange list, T_cam_board list) from a recorded-samples JSON."""
    path = Path(path)
    doc = read_json(path, CalibrationFileError, "the samples file")
    if not isinstance(doc, dict):
        raise CalibrationFileError(f"{path}: expected an object with 'mount' and 'samples'")
    mount = doc.get("mount")
    if mount not in MOUNTS:
        raise CalibrationFileError(f"{path}: mount: expected one of {list(MOUNTS)}, got {mount!r}")
    samples = doc.get("samples")
    if not isinstance(samples, list):
        raise CalibrationFileError(f"{path}: samples: expected a list of {{T_base_flange, T_cam_board}} objects")
    F, C = [], []
    for k, s in enumerate(samples):
        if not isinstance(s, dict):
            raise CalibrationFileError(f"{path}: samples[{k}]: expected an object with T_base_flange and T_cam_board")
        for name, out in (("T_base_flange", F), ("T_cam_board", C)):
            if name not in s:
                raise CalibrationFileError(f"{path}: samples[{k}]: missing key {name}")
            out.append(_matrix(s[name], f"{path}: samples[{k}].{name}"))
    return mount, F, C


@dataclass
class Corners:
    """Optional per-sample corner measurements in a samples file (enables the pixel refinement in `solve`)."""

    K: np.ndarray
    dist: np.ndarray | None
    object_points: list[np.ndarray]  # (N_i, 3) board frame, metres
    image_points: list[np.ndarray]  # (N_i, 2) px


def save_samples(path: str | Path, mount: str, T_base_flange: list[np.ndarray], T_cam_board: list[np.ndarray],
                 extra: dict | None = None, corners: Corners | None = None) -> Path:
    """Write recorded samples in the format :func:`load_samples` reads (plus corners when given: `K`, `dist` at
    the top level and `object_points` / `image_points` per sample)."""
    if mount not in MOUNTS:
        raise ValueError(f"mount: expected one of {list(MOUNTS)}, got {mount!r}")
    samples = [{"T_base_flange": np.asarray(f).tolist(), "T_cam_board": np.asarray(c).tolist()}
               for f, c in zip(T_base_flange, T_cam_board)]
    doc: dict[str, Any] = {"mount": mount}
    if corners is not None:
        doc["K"] = np.asarray(corners.K, float).tolist()
        doc["dist"] = None if corners.dist is None else np.asarray(corners.dist, float).ravel().tolist()
        for s, o, i in zip(samples, corners.object_points, corners.image_points):
            s["object_points"] = np.asarray(o, float).reshape(-1, 3).tolist()
            s["image_points"] = np.asarray(i, float).reshape(-1, 2).tolist()
    doc["samples"] = samples
    if extra:
        doc.update(extra)
    path = Path(path)
    path.write_text(json.dumps(doc, indent=1))
    return path


def load_corners(path: str | Path) -> Corners | None:
    """The corner measurements of a samples file, or None when it has none (`K` absent)."""
    path = Path(path)
    doc = read_json(path, CalibrationFileError, "the samples file")
    if not isinstance(doc, dict) or doc.get("K") is None:
        return None
    K = np.asarray(doc["K"], dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise CalibrationFileError(f"{path}: K: expected a 3x3 camera matrix")
    dist = doc.get("dist")
    dist = None if dist is None else np.asarray(dist, dtype=np.float64).ravel()
    obj, img = [], []
    for k, s in enumerate(doc.get("samples", [])):
        for name in ("object_points", "image_points"):
            if name not in s:
                raise CalibrationFileError(f"{path}: samples[{k}]: missing key {name} (the file has K, so every "
                                           "sample needs its corners)")
        o = np.asarray(s["object_points"], dtype=np.float64)
        i = np.asarray(s["image_points"], dtype=np.float64)
        if o.ndim != 2 or o.shape[1] != 3 or i.shape != (len(o), 2) or len(o) < 4:
            raise CalibrationFileError(f"{path}: samples[{k}]: expected object_points (N, 3) and image_points "
                                       f"(N, 2) with N >= 4, got {o.shape} and {i.shape}")
        obj.append(o)
        img.append(i)
    return Corners(K, dist, obj, img)
