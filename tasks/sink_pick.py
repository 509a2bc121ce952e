"""sink-pick: take every object out of the sink and set it down upright in the counter drop zone.

Targets: the drop zone (cell.drop_zone), free upright spots on a 2 cm grid that do not overlap what was already
put there. Success: no object left in the sink (confirmed by consecutive scans) and each placement verified
(gone from the sink, seen at its spot).
"""

from __future__ import annotations

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget
from kitchenbot.tasks.base import Task, _drop_zone_targets


class SinkPick(Task):
    name = "sink-pick"
    description = "pick each object out of the sink and drop it in the counter drop zone"
    success_criteria = "sink empty; every object verified in the drop zone"

    def targets(self, obj: ObjectPose) -> list[PlaceTarget] | NoFreeSlot:
        out = _drop_zone_targets(self.inventory[obj.obj_id], self.cell.spec.drop_zone, self.placed, 3,
                                 self.pending)
        return out or NoFreeSlot(f"drop zone has no free spot for a {obj.cls}")
