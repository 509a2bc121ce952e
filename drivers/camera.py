"""The Camera interface: an RGB-D camera with depth aligned to the colour image.

Implementations: ``drivers.oakd_camera.OakDCamera`` (real), ``drivers.replay_camera.ReplayCamera``,
``fakes.camera.FakeCamera``.
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass

import numpy as np

from kitchenbot.drivers.device import Device


@dataclass
class Frame:
    """One RGB-D capture. Depth is in metres, aligned to `rgb`; 0 or NaN where unknown."""

    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32, metres
    K: np.ndarray  # (3, 3) intrinsics of both images (OpenCV convention)
    stamp: float  # seconds

    def __post_init__(self) -> None:
        if self.rgb.ndim != 3 or self.rgb.shape[2] != 3 or self.rgb.dtype != np.uint8:
            raise ValueError(f"Frame.rgb: expected (H, W, 3) uint8, got {self.rgb.shape} {self.rgb.dtype}")
        if self.depth.shape != self.rgb.shape[:2]:
            raise ValueError(f"Frame.depth: expected shape {self.rgb.shape[:2]}, got {self.depth.shape}")
        if self.K.shape != (3, 3):
            raise ValueError(f"Frame.K: expected a 3x3 matrix, got {self.K.shape}")

    @property
    def size(self) -> tuple[int, int]:
        """(width, height)"""
        return self.rgb.shape[1], self.rgb.shape[0]


class Camera(Device):
    @abstractmethod
    def capture(self, timeout: float = 2.0) -> Frame:
        """The next synchronised RGB-D frame; DriverTimeoutError if none arrives in time."""

    @abstractmethod
    def intrinsics(self) -> np.ndarray:
        """3x3 K at the configured image size."""
