"""Before a run is declared done: is anything item-sized left in the sink that no pose explains?

A scan whose perception leaves nothing for the task to do does not mean the sink is clear. Perception may have
seen an item and found no model that explains it (a mug lying on its side, fitted by no candidate: the instance
is rejected), or seen too little of it for any pose; its points stay in the map, and neither the cell nor a
perceived or placed item explains them (executive/unrecognised.py groups them into things). Before, the run
ended `succeeded` with such an item still in the basin.

Now each item-sized thing (ITEM_EXTENT in two directions, ITEM_VOXELS voxels: single voxels and slivers beside a
pose fitted a centimetre off are noise) gets what a user would expect, once:

1. a targeted look: the camera straight above its centre (another view than the scan's oblique ones), and
2. a fresh fit: the scan's views and that view perceived again. Where that finds something for the task to do,
   the run goes on (it is picked as any item is).

A thing still unexplained when the scans confirm the sink empty ends the run not as `succeeded` but as
`unrecognised_left`, its position and size in the message and in RunReport.unrecognised (counted by
`kitchenbot bench tasks`). Runs whose map holds no such thing take no look and end as before.

A mixin of the verify state (executive/verification.py).
"""

from __future__ import annotations

import numpy as np

from kitchenbot.drivers.errors import DriverTimeoutError
from kitchenbot.executive.failures import StepFailed
from kitchenbot.executive.unrecognised import Unrecognised


def item_sized(thing: Unrecognised, extent: float, voxels: int) -> bool:
    """As wide as an item in two directions at least (a lying plate is thin in the third) and `voxels` voxels:
    not a sliver left beside a pose fitted a centimetre off."""
    return thing.voxels >= voxels and int(np.sum(thing.extent >= extent - 1e-9)) >= 2


class DoneCheck:
    ITEM_EXTENT = 0.04  # m: the smallest dishware (a cup, a glass) is ~7 cm across; seen in part, more than half
    ITEM_VOXELS = 6
    SAME_THING = 0.06  # m: a thing whose centre lies this close to one looked at is that one
    MAX_LOOKS = 3  # targeted looks per run

    def _things_left(self) -> list[Unrecognised]:
        """The item-sized things in the basin no pose explains (executive/unrecognised.py), largest first."""
        return [t for t in self._unrecognised_in_sink() if item_sized(t, self.ITEM_EXTENT, self.ITEM_VOXELS)]

    def _looked_at(self, thing: Unrecognised) -> bool:
        return any(np.linalg.norm(np.asarray(d["xyz"]) - thing.centre) < self.SAME_THING
                   for d in self.report.unrecognised_looks)

    def _look_at_things_left(self) -> bool:
        """Nothing is left as perceived: each item-sized thing no pose explains, not looked at before, gets one
        view from straight above and a fresh perception of the scan's views with it. True when that leaves the
        task something to do (the run goes on)."""
        for thing in self._things_left():
            if self._looked_at(thing) or len(self.report.unrecognised_looks) >= self.MAX_LOOKS:
                continue
            look = {"xyz": thing.centre.round(3).tolist(), "size": thing.extent.round(3).tolist(), "seen": False}
            self.report.unrecognised_looks.append(look)
            try:
                why = self._look_down_at(thing.centre) if self.planner is not None else "no planner"
                if why:
                    self._log("note", "no view of the thing no pose explains", xyz=thing.centre, reason=why)
                    continue
                view = self._capture_view(f"unexplained{len(self.report.unrecognised_looks)}", "unexplained",
                                          spot=True)
            except (StepFailed, DriverTimeoutError) as e:
                self._log("note", "no view of the thing no pose explains", xyz=thing.centre, reason=str(e))
                continue
            look["seen"] = True
            self.views = [*self.views, view]
            self._perceive()
            found = self.task.remaining(self.belief.poses)
            self._log("result", "looked at a thing no pose explains", xyz=thing.centre, extent=thing.extent,
                      found=[{"cls": p.cls, "xyz": p.T_base_obj[:3, 3]} for p in found])
            if found or self.belief.staged_waiting():
                return True
        return False

    def _name_things_left(self) -> None:
        """The scans confirm the sink empty: the item-sized things still unexplained are the run's outcome
        (`unrecognised_left`), each with where it is and its size."""
        things = self._things_left()
        if not things:
            return
        self.report.unrecognised = [{"xyz": t.centre.round(3).tolist(), "size": t.extent.round(3).tolist(),
                                     "voxels": t.voxels, "looked_at": self._looked_at(t)} for t in things]
        self.report.message = (f"{len(things)} unrecognised thing(s) left in the sink (no pose explains them "
                               "after a look from above): " + ", ".join(t.describe() for t in things))
