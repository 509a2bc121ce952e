"""OraclePerceiver: object poses read from the simulator's truth instead of perceived.

ONLY for tests that say so and for ``kitchenbot run --oracle-perception`` (reports say ``"perception":
"oracle"``): it separates executive/planning behaviour from perception accuracy. Duck-typed on the SimWorld
(objects, held_uid) so the executive never imports ``fakes``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kitchenbot.perception.types import ObjectPose, View


@dataclass
class OracleResult:
    poses: list[ObjectPose]
    map_points: np.ndarray | None = None
    timings_ms: dict = field(default_factory=dict)


class OraclePerceiver:
    def __init__(self, world, points_per_object: int = 200):
        self.world = world
        self.n = points_per_object

    def perceive(self, views: list[View]) -> OracleResult:
        poses = []
        for uid, o in sorted(self.world.objects.items()):
            if uid == self.world.held_uid:
                continue
            T = np.array(o.T_base_obj, float)
            pts = o.model.points[:: max(1, len(o.model.points) // self.n)]
            poses.append(ObjectPose(o.model.obj_id, o.model.cls, T, 1.0, pts @ T[:3, :3].T + T[:3, 3], uid, 1.0))
        return OracleResult(poses)
