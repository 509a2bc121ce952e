"""sink-pick: take every object out of the sink and set it down upright in the counter drop zone.

Targets: the drop zone (cell.drop_zone), free upright spots on a 2 cm grid that do not overlap what was already
put there; items that do not lie upright in the sink may also be set down the way they lie. Success: no object left in the sink (confirmed by consecutive scans) and each placement verified
(gone from the sink, seen at its spot).
"""

from __future__ import annotations

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget
from kitchenbot.tasks.base import Task, _drop_zone_targets, area_spots, as_is, with_plate_room


class SinkPick(Task):
    name = "sink-pick"
    description = "pick each object out of the sink and drop it in the counter drop zone"
    success_criteria = "sink empty; every object verified in the drop zone"

    def targets(self, obj: ObjectPose) -> list[PlaceTarget] | NoFreeSlot:
        model = self.inventory[obj.obj_id]
        zone = self.cell.spec.drop_zone
        out = _drop_zone_targets(model, zone, self.placed, 3, self.pending)
        R = obj.T_base_obj[:3, :3]
        if R[2, 2] < 0.95:
            # Not upright in the sink (a glass on its side): no grasp may reach "upright", so also offer the
            # drop zone as it lies now (set down the way it is held).
            lo = np.array(zone.origin_xy)
            taken = with_plate_room(model, zone, self.placed, self.pending)
            for T in area_spots(model, lo, lo + np.array(zone.size_xy), zone.z, taken, as_is(R), 2,
                                centre_inside="any"):
                out.append(PlaceTarget(T, "drop", free_yaw=False, support="counter (as it lay)"))
        return out or NoFreeSlot(f"drop zone has no free spot for a {obj.cls}")
