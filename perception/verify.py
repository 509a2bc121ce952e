"""Does a pose explain its segment? One number per pose, one threshold (setting `verify_threshold`).

Four checks, each a share in [0, 1]:
- seen: of the posed model's surface the views could see (facing a camera, not hidden behind measured depth),
  how much the depth confirms near the segment (the Scorer's model->query ratio);
- explained: of the segment's points, how many lie on the model (within one voxel);
- free space: of that visible model surface, how much lies clearly in front of the measured depth, where the
  camera saw through it (render-and-compare: the model says "surface here", the depth says "empty");
- normals: of the explained points, how many lie on a side of the model facing the same way (within ~60 deg;
  a box face fitted by a bowl's wall, a can by a cup's inside, agree in position but not in orientation).

verification = min(seen, explained) x normals x (1 - 2 x free space), clipped at 0: the weakest direction of
coverage decides, and wrong normals or seeing through the model scale it down. A box or a can fitted by a cup
explains its points only partly, or leaves visible cup surface unconfirmed, or puts cup surface where the
camera saw through; dishware fitted right scores high on all four. The threshold is calibrated on generated
scenes with distractors (docs/perception.md, "Verification").
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

    @property
    def score(self) -> float:
        return max(0.0, min(self.seen, self.explained) * self.normals * (1.0 - 2.0 * self.free_space))


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
