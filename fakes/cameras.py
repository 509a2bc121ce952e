"""Camera models the simulator can render as: intrinsics and the depth sensor's error model.

- ``oakd``: Luxonis OAK-D (the cell's camera): colour ~66 deg horizontal FoV at 640x480, stereo baseline
  7.5 cm, depth from 0.20 m (fakes/render.py's original constants).
- ``d435``: Intel RealSense D435 with depth aligned to colour at 640x480: colour fx ~ 615 px (69 x 42 deg
  at 1920x1080, scaled), principal point a few pixels off centre as factory calibrations have it, stereo
  baseline 5.0 cm, minimum depth ~0.18 m at this resolution, subpixel disparity noise ~0.08 px RMS.
- ``kinect``: Azure Kinect-like time of flight (NFOV unbinned, colour-aligned at 640x480): noise that
  grows slowly and linearly with range (no baseline), flying pixels smeared across depth edges instead of
  stereo holes, and multipath dropouts on grazing surfaces.

Values from the vendors' datasheets; the noise figures are typical, not measured on a unit here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kitchenbot.fakes.render import (OAKD_BASELINE, OAKD_FX, OAKD_MAX_DEPTH, OAKD_MIN_DEPTH,
                                     oakd_intrinsics, stereo_noise)


@dataclass(frozen=True)
class CameraModel:
    name: str
    fx_640: float  # focal length in pixels at 640 px width
    fy_ratio: float = 1.0  # fy / fx
    principal_offset_px: tuple[float, float] = (0.0, 0.0)  # (cx, cy) minus the image centre at 640x480
    kind: str = "stereo"  # stereo | tof
    baseline: float = OAKD_BASELINE  # m (stereo)
    min_depth: float = OAKD_MIN_DEPTH
    max_depth: float = OAKD_MAX_DEPTH
    disparity_sigma_px: float = 0.12  # stereo matching noise
    tof_sigma: tuple[float, float] = (0.0, 0.0)  # (constant m, per metre of range) for time of flight

    def intrinsics(self, width: int = 640, height: int = 480) -> np.ndarray:
        if self.name == "oakd":
            return oakd_intrinsics(width, height)  # exactly the original K
        s = width / 640.0
        fx = self.fx_640 * s
        cx = (width - 1) / 2 + self.principal_offset_px[0] * s
        cy = (height - 1) / 2 + self.principal_offset_px[1] * s
        return np.array([[fx, 0.0, cx], [0.0, fx * self.fy_ratio, cy], [0.0, 0.0, 1.0]])

    def depth_noise(self, depth: np.ndarray, cos_incidence: np.ndarray, K: np.ndarray, rng: np.random.Generator,
                    noise_scale: float = 1.0, dropout: float = 0.003) -> np.ndarray:
        """What this sensor measures of a true z-depth image (metres, 0 = no data)."""
        if self.kind == "stereo":
            return stereo_noise(depth, cos_incidence, K, rng, disparity_sigma_px=self.disparity_sigma_px * noise_scale,
                                dropout=dropout, baseline=self.baseline, min_depth=self.min_depth,
                                max_depth=self.max_depth)
        return tof_noise(depth, cos_incidence, rng, self.tof_sigma[0] * noise_scale, self.tof_sigma[1] * noise_scale,
                         self.min_depth, self.max_depth, dropout)


def tof_noise(depth: np.ndarray, cos_incidence: np.ndarray, rng: np.random.Generator, sigma0: float,
              sigma_per_m: float, min_depth: float, max_depth: float, dropout: float = 0.003,
              grazing_cos: float = 0.08) -> np.ndarray:
    """Depth as a time-of-flight camera measures it: sigma = sigma0 + sigma_per_m * z, 1 mm quantisation,
    flying pixels (a mix of the two depths) on one side of depth edges, dropouts at grazing angles."""
    z = depth.astype(np.float64)
    valid = (z >= min_depth) & (z <= max_depth)
    noisy = z + rng.standard_normal(z.shape) * (sigma0 + sigma_per_m * z)
    # Flying pixels: where the right or lower neighbour is much further/nearer, the pixel integrates both.
    for axis in (0, 1):
        nb = np.roll(z, -1, axis=axis)
        edge = (np.abs(nb - z) > 0.03 * np.maximum(z, 0.1)) & (nb > 0) & (z > 0)
        mix = rng.random(z.shape)
        noisy = np.where(edge & (rng.random(z.shape) < 0.5), z * (1 - mix) + nb * mix, noisy)
    holes = (cos_incidence < grazing_cos) | (rng.random(z.shape) < dropout)
    out = np.where(valid & ~holes, np.round(noisy * 1000.0) / 1000.0, 0.0)
    return out.astype(np.float32)


CAMERAS: dict[str, CameraModel] = {
    "oakd": CameraModel("oakd", OAKD_FX),
    "d435": CameraModel("d435", 615.0, fy_ratio=1.0008, principal_offset_px=(6.5, -3.2), baseline=0.050,
                        min_depth=0.18, max_depth=3.0, disparity_sigma_px=0.08),
    "kinect": CameraModel("kinect", 504.0, fy_ratio=1.0, principal_offset_px=(-2.4, 4.1), kind="tof",
                          min_depth=0.25, max_depth=2.9, tof_sigma=(0.0012, 0.0015)),
}


def camera_model(name: str) -> CameraModel:
    try:
        return CAMERAS[name]
    except KeyError:
        raise ValueError(f"camera: expected one of {sorted(CAMERAS)}, got {name!r}") from None
