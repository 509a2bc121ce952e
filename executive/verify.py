"""Is the placed object where it should be? A depth check from one view, independent of perception.

The model's surface points at the target pose are projected into the view; where they are the nearest thing
to the camera (a small z-buffer), the measured depth should agree. With the object there most pixels agree;
with it missing the camera sees what lies behind (rack floor, counter) and few agree. Fewer than
`min_pixels` projected pixels (target out of view) gives no decision.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kitchenbot.perception.inventory import ObjectModel
from kitchenbot.perception.types import View
from kitchenbot.transforms import inv


@dataclass
class Presence:
    pixels: int  # projected model pixels with a measured depth
    agree: float  # fraction of them within `tol` of the prediction
    decided: bool
    present: bool

    def as_dict(self) -> dict:
        return {"pixels": self.pixels, "agree": round(self.agree, 3), "decided": self.decided, "present": self.present}


def target_presence(view: View, model: ObjectModel, T_base_obj: np.ndarray, tol: float = 0.02,
                    min_pixels: int = 40, threshold: float = 0.5, stride: int = 4) -> Presence:
    T_cam_obj = inv(view.T_base_cam) @ T_base_obj
    P = model.points @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3]
    P = P[P[:, 2] > 0.05]
    h, w = view.depth.shape
    if not len(P):
        return Presence(0, 0.0, False, False)
    uv = P @ view.K.T
    u = (uv[:, 0] / uv[:, 2] / stride).astype(int)
    v = (uv[:, 1] / uv[:, 2] / stride).astype(int)
    hs, ws = h // stride, w // stride
    ok = (u >= 0) & (u < ws) & (v >= 0) & (v < hs)
    u, v, z = u[ok], v[ok], P[ok, 2]
    zbuf = np.full((hs, ws), np.inf)
    np.minimum.at(zbuf, (v, u), z)
    ys, xs = np.nonzero(np.isfinite(zbuf))
    meas = view.depth[ys * stride + stride // 2, xs * stride + stride // 2]
    good = np.isfinite(meas) & (meas > 0)
    n = int(good.sum())
    if n < min_pixels:
        return Presence(n, 0.0, False, False)
    agree = float(np.mean(np.abs(meas[good] - zbuf[ys[good], xs[good]]) < tol))
    return Presence(n, agree, True, agree >= threshold)
