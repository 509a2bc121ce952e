"""The signed gaps along one lift, each pair's computed once.

A lift's start contacts are checked twice on the fitted poses (planning/pick_place.py): whether a contact may break
and be made again within the fits' resolution (Planner._remade_in_fit), and, for a neighbour whose pose is doubtful,
whether the gap to it narrows again within that pose's error (Planner._may_meet_doubtful_again). Both read the same
profile: the pair's signed gap (Scene.signed_gaps, a bisection of ~12 mesh collision checks per state) at the lift's
configurations and the midpoints between them, clipped to 2 * POSE_ERROR. A LiftGaps holds one lift in one scene
and computes each pair's profile on its first use; both checks read it from there.

    gaps = LiftGaps(lift_scene, lift.q)
    s = gaps.of(("held", "obj:bowl_1"))   # signed gaps (m, negative: overlap) at the half-step samples

It reads the scene's geometry when a profile is first asked for: it lives for one lift check, during which the
scene does not change (a gripper opening set on the scene moves its pads: make a new LiftGaps after that).
"""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.doubtful_support import POSE_ERROR


def half_steps(Q: np.ndarray) -> np.ndarray:
    """The configurations of `Q` and the midpoints between them."""
    Q = np.asarray(Q, float)
    return np.vstack([np.vstack([a, (a + b) / 2]) for a, b in zip(Q[:-1], Q[1:])] + [Q[-1:]])


class LiftGaps:
    SPAN = 2 * POSE_ERROR  # m: gaps and overlaps beyond this are clipped to it

    def __init__(self, scene, Q: np.ndarray):
        self.scene = scene
        self.samples = half_steps(Q)
        self._of: dict[tuple[str, str], np.ndarray] = {}

    def of(self, pair: tuple[str, str]) -> np.ndarray:
        """The pair's signed gap (m; negative: overlap depth) at each sample, clipped to [-SPAN, SPAN]."""
        key = tuple(pair)
        if key not in self._of:
            self._of[key] = self.scene.signed_gaps(self.samples, key, self.SPAN)
        return self._of[key]
