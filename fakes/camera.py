"""FakeCamera: an OAK-D-like RGB-D camera on the simulated arm's flange.

Each capture renders the SimWorld from the true camera pose (arm joints x the world's true flange->camera
mount), adds the stereo depth noise model and image noise, and takes simulated time (one frame period).
Honest failures: dropped frames (timeout), NaN/zero depth, not connected. Optional per-capture pose
perturbation models an arm/calibration that is slightly off (the reported pose is not the true one).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kitchenbot.drivers.camera import Camera, Frame
from kitchenbot.drivers.errors import DeviceNotConnectedError, DriverTimeoutError
from kitchenbot.fakes.render import oakd_intrinsics, render, rgb_noise, stereo_noise
from kitchenbot.transforms import make_T


class FakeCamera(Camera):
    def __init__(
        self,
        world,
        width: int = 640,
        height: int = 480,
        fps: float = 15.0,
        pose_noise_m: float = 0.0,
        pose_noise_deg: float = 0.0,
        seed: int | None = None,
    ):
        self.world = world
        self.width, self.height, self.fps = int(width), int(height), float(fps)
        self.K = oakd_intrinsics(self.width, self.height)
        self.pose_noise_m, self.pose_noise_deg = pose_noise_m, pose_noise_deg
        self.rng = np.random.default_rng(world.seed + 7 if seed is None else seed)
        self._connected = False
        self.last_true_T_base_cam: np.ndarray | None = None  # ground truth of the last capture (for tests)
        self.last_labels: np.ndarray | None = None  # instance labels of the last capture (ground truth)

    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    @property
    def is_connected(self) -> bool:
        return self._connected

    def intrinsics(self) -> np.ndarray:
        return self.K.copy()

    def true_pose(self) -> np.ndarray:
        """Where the camera really is for the next capture (arm truth x mount truth x perturbation)."""
        T = self.world.T_base_cam()
        if self.pose_noise_m > 0 or self.pose_noise_deg > 0:
            rv = self.rng.normal(size=3)
            rv *= np.radians(self.pose_noise_deg) / max(np.linalg.norm(rv), 1e-12)
            dt = self.rng.normal(size=3)
            dt *= self.pose_noise_m / max(np.linalg.norm(dt), 1e-12)
            T = T @ make_T(Rotation.from_rotvec(rv).as_matrix(), dt)
        return T

    def capture(self, timeout: float = 2.0) -> Frame:
        if not self._connected:
            raise DeviceNotConnectedError("FakeCamera: not connected; call connect() first")
        faults = self.world.faults
        if faults.camera_drop > 0:
            faults.camera_drop -= 1
            self.world.clock.advance(timeout)
            raise DriverTimeoutError(f"FakeCamera: no frame within {timeout:.2f} s (dropped)")
        T = self.true_pose()
        r = render(self.world, self.K, T, self.width, self.height)
        depth = stereo_noise(r.depth, r.cos_incidence, self.K, self.rng)
        if faults.camera_nan_depth > 0:
            faults.camera_nan_depth -= 1
            depth = depth.copy()
            depth[:, : self.width // 2] = np.nan
            depth[:, self.width // 2 :] = 0.0
        self.world.clock.advance(1.0 / self.fps)
        self.last_true_T_base_cam = T
        self.last_labels = r.labels
        return Frame(rgb_noise(r.rgb, self.rng), depth, self.K.copy(), self.world.clock.now())
