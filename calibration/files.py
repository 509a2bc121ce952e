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
"""

from __future__ import annotations

import datetime as _dt
import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from kitchenbot.calibration.park_martin import MOUNTS, X_NAME
from kitchenbot.calibration.residuals import HandEyeResult
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
    try:
        doc = json.loads(path.read_text())
    except OSError as e:
        raise CalibrationFileError(f"{path}: cannot read the samples file ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise CalibrationFileError(f"{path}: not valid JSON: {e}") from None
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


def save_samples(path: str | Path, mount: str, T_base_flange: list[np.ndarray], T_cam_board: list[np.ndarray],
                 extra: dict | None = None) -> Path:
    """Write recorded samples in the format :func:`load_samples` reads."""
    if mount not in MOUNTS:
        raise ValueError(f"mount: expected one of {list(MOUNTS)}, got {mount!r}")
    doc: dict[str, Any] = {
        "mount": mount,
        "samples": [{"T_base_flange": np.asarray(f).tolist(), "T_cam_board": np.asarray(c).tolist()}
                    for f, c in zip(T_base_flange, T_cam_board)],
    }
    if extra:
        doc.update(extra)
    path = Path(path)
    path.write_text(json.dumps(doc, indent=1))
    return path
