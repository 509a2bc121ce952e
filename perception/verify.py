"""Does a pose explain its segment? One number per pose, one threshold (setting `verify_threshold`).

The checks, each a share in [0, 1]:
- seen: of the posed model's surface the views could see (facing a camera, not hidden behind measured depth),
  how much the depth confirms near the segment (the Scorer's model->query ratio);
- explained: of the segment's points, how many lie on the model (within one voxel);
- free space: of that visible model surface, how much lies clearly in front of the measured depth, where the
  camera saw through it (render-and-compare: the model says "surface here", the depth says "empty");
- normals: of the explained points, how many lie on a side of the model facing the same way (within ~60 deg).

verification = min(1 - free / (seen + free), normals): of the model surface the depth can judge, the share it
does not see through, capped by the normals' agreement. Coverage both ways (seen, explained) is gated before
this by the registration's own thresholds (`min_overlap`, model->query >= 0.15, query->model >= 0.2): at this
point the segment may still hold several touching items, so a low `explained` is no evidence against a pose,
and a low `seen` is what an item half hidden under its neighbours looks like. What tells a box, a can or a
sponge fitted by a mug or a bowl from dishware fitted right is the free space: the dishware model puts
surface where the camera saw past the distractor. Calibrated on generated scenes with distractors
(`python -m kitchenbot.perception.calibrate_verify`, docs/perception.md "Verification").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kitchenbot.perception.database import ModelEntry
from kitchenbot.perception.register import on_surface


@dataclass
class Verification:
    seen: float
    explained: float
    free_space: float
    normals: float

    def parts(self) -> dict[str, float]:
        return {"seen": self.seen, "explained": self.explained, "free_space": self.free_space, "normals": self.normals}

    @property
    def score(self) -> float:
        judged = self.seen + self.free_space
        through = self.free_space / judged if judged > 0 else 1.0
        return max(0.0, min(1.0 - through, self.normals))


def verify(points: np.ndarray, normals: np.ndarray, entry: ModelEntry, T_base_obj: np.ndarray,
           seen: float, free_space: float, voxel: float) -> Verification:
    """The checks for a pose of `entry` against a segment (points and camera-facing normals, base frame);
    `seen` and `free_space` from the Scorer (model->query ratio and free-space share of the visible model)."""
    if len(points) == 0:
        return Verification(seen, 0.0, free_space, 0.0)
    near = on_surface(points, None, entry, T_base_obj, voxel)
    explained = float(near.mean())
    if not near.any():
        return Verification(seen, 0.0, free_space, 0.0)
    facing = on_surface(points[near], normals[near], entry, T_base_obj, voxel)
    return Verification(seen, explained, free_space, float(facing.mean()))
