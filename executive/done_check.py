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

Items lost in transit (an item that left the gripper on the way: Belief.drops) get the same: one that fell above
the sink counts as seen again only once a scan holds as many items of its class as before (Belief.await_in_sink);
one no scan saw back gets one look from straight above where it fell (it may rest on the rim, tilted above the
basin, where neither the sink's perception nor the check above look), and one found there is picked up from there
(as an item found where it slipped out over the counter). A drop still not seen again when the sink is confirmed
empty is named in the run's outcome (`Belief.lost_drops`: its class and where it was last held; the run gives up,
it does not succeed), whatever the first scan counted.

A mixin of the verify state (executive/verification.py).
"""

from __future__ import annotations

import numpy as np

from kitchenbot.drivers.errors import DriverTimeoutError
from kitchenbot.executive.failures import StepFailed
from kitchenbot.executive.unrecognised import Unrecognised, unrecognised_things
from kitchenbot.perception.rgbd import point_map
from kitchenbot.planning.types import PlaceTarget
from kitchenbot.world.gripper import DROP_HEIGHT


def item_sized(thing: Unrecognised, extent: float, voxels: int) -> bool:
    """As wide as an item in two directions at least (a lying plate is thin in the third) and `voxels` voxels:
    not a sliver left beside a pose fitted a centimetre off."""
    return thing.voxels >= voxels and int(np.sum(thing.extent >= extent - 1e-9)) >= 2


class DoneCheck:
    ITEM_EXTENT = 0.04  # m: the smallest dishware (a cup, a glass) is ~7 cm across; seen in part, more than half
    ITEM_VOXELS = 6
    SAME_THING = 0.06  # m: a thing whose centre lies this close to one looked at is that one
    MAX_LOOKS = 3  # targeted looks per run

    DROP_REACH = 0.25  # m around where it fell an item found there may have come to rest (RecoveryActions.SEARCH_RADIUS)
    ABOVE_RIM = 0.02  # m: an item centred this far above the counter top is not in the basin (it rests on the rim)

    def _look_for_sink_drops(self) -> bool:
        """Each drop above the sink no scan has seen back in it gets one view from straight above where it fell
        and a perception of it (the counter as support: executive/recovery.py `_drop_perceiver`). An item of its
        class found there out of the basin (on the rim, the counter beside it) is recorded where it lies and
        picked up from there: True (the run goes on)."""
        b = self.belief
        for sd in list(b.sink_drops):
            if sd.looked:
                continue
            sd.looked = True
            self.report.sink_drop_looks += 1
            try:
                why = self._look_down_at(sd.where) if self.planner is not None else "no planner"
                if why:
                    self._log("note", "no view of where the item fell", xyz=sd.where, reason=why)
                    continue
                view = self._capture_view(f"sinkdrop{self.report.sink_drop_looks}", "drop", spot=True)
            except (StepFailed, DriverTimeoutError) as e:
                self._log("note", "no view of where the item fell", xyz=sd.where, reason=str(e))
                continue
            with self.stages.within("perceive"):
                res = self._drop_perceiver().perceive([view])
            rim = float(sd.sink_lo_hi[1][2]) + self.ABOVE_RIM
            found = [p for p in res.poses if p.cls == sd.cls
                     and np.linalg.norm(p.T_base_obj[:2, 3] - sd.where[:2]) < self.DROP_REACH
                     and (not sd.holds(p) or p.T_base_obj[2, 3] > rim)]
            above = [] if found else self._above_the_rim(view, sd.where, rim)
            self._log("result", "looked where an item fell above the sink", xyz=sd.where, cls=sd.cls,
                      found=[p.T_base_obj[:3, 3] for p in found], above_rim=[t.centre for t in above])
            if not found:
                # nothing rests above the basin there: it fell back in, where the scans saw it (where the item's
                # centre was over the basin: one held mostly over the counter may lie beyond the counter's edge)
                if not above and sd.centred_over_basin():
                    b.found_sink_drop(sd)
                for d in b.lost_drops():  # named at the end with what rests there
                    if above and d["cls"] == sd.cls and np.allclose(d["xyz"], np.round(sd.site, 3)):
                        d["rests"] = above[0].describe()
                continue
            obj = min(found, key=lambda p: np.linalg.norm(p.T_base_obj[:2, 3] - sd.where[:2]))
            drop = b.found_sink_drop(sd)
            T_release = np.array(obj.T_base_obj, float)
            T_release[2, 3] += DROP_HEIGHT  # as if released there (place targets are release poses)
            placed = b.record_placed(self.task, obj, PlaceTarget(T_release, "drop", support="beside the basin "
                                                                 "(it fell there)"), obj.T_base_obj)
            self.report.recovered_drops += 1
            b.record_found(placed)
            b.record_found_drop(placed, drop)
            return True
        return False

    def _above_the_rim(self, view, site: np.ndarray, rim: float) -> list[Unrecognised]:
        """The item-sized things `view` shows above the counter top within DROP_REACH of `site` (x-y) that
        neither the cell nor an item in the belief explains: where a fallen item no model fits rests."""
        P = point_map(view, stride=2).reshape(-1, 3).astype(float)
        P = P[np.all(np.isfinite(P), axis=1)]
        lo = np.array([site[0] - self.DROP_REACH, site[1] - self.DROP_REACH, rim])
        hi = np.array([site[0] + self.DROP_REACH, site[1] + self.DROP_REACH, rim + 0.3])
        P = P[np.all((P >= lo) & (P <= hi), axis=1)]
        if not len(P):
            return []
        vox = self.planner.unexplained(P, self.belief.scene_objects())
        things = unrecognised_things(vox, self.planner.world.voxel_size, lo, hi)
        return [t for t in things if item_sized(t, self.ITEM_EXTENT, self.ITEM_VOXELS)]

    def _name_lost_drops(self) -> str:
        """The drops not seen again, for the run's message (empty: none); also in RunReport.lost."""
        lost = self.belief.lost_drops()
        self.report.lost = [{"cls": d["cls"], "xyz": d["xyz"]} for d in lost]
        if not lost:
            return ""
        return (f"{len(lost)} object(s) dropped during the run are neither in the sink nor placed (not seen again): "
                + ", ".join(f"{d['cls'] or 'an item'} last held at ({d['xyz'][0]:.2f}, {d['xyz'][1]:.2f}, "
                            f"{d['xyz'][2]:.2f}) m" + (f" (something no model fits rests above the rim there, "
                                                       f"{d['rests']})" if d.get("rests") else "") for d in lost))

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
