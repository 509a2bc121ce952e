"""Value types that perception produces: views in, instances and object poses out."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class View:
    """One RGB-D frame with its camera pose in the base frame (arm pose x hand-eye calibration)."""

    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres; 0 or NaN = unknown
    K: np.ndarray  # (3, 3)
    T_base_cam: np.ndarray  # (4, 4)
    stamp: float = 0.0

    @property
    def size(self) -> tuple[int, int]:
        """(width, height)"""
        return self.rgb.shape[1], self.rgb.shape[0]


@dataclass
class ObjectPose:
    """A recognised object: which model, where (base frame), how sure, and the points it was seen as."""

    obj_id: int
    cls: str
    T_base_obj: np.ndarray
    score: float
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # base frame, metres
    instance_id: int = -1
    visible_fraction: float = 1.0  # how much of the object the views saw (1 = unoccluded)
    verification: float = 1.0  # how well the pose explains its segment (perception/verify.py; 1 = fully)
    checks: dict[str, float] = field(default_factory=dict)  # the verification's parts (seen, explained, ...)
