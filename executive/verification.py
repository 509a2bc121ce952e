"""The verify state of the task runner: the first perception after a placement checks it (gone from the sink,
present at its target: executive/verify.py) and records it in the belief; then the run goes on, is complete, or
gives up with what is left and why.

A mixin of TaskRunner (executive/runner.py).
"""

from __future__ import annotations

import time

import numpy as np

from kitchenbot.executive.failures import StepFailed
from kitchenbot.executive.verify import target_presence
from kitchenbot.perception.types import ObjectPose
from kitchenbot.world.gripper import DROP_HEIGHT


class Verification:
    def _do_verify(self) -> str:
        """Re-scan (the first perception after a placement verifies it) and decide: next object, done, give up."""
        self.views = self._scan()
        self._perceive()
        b = self.belief
        if self._candidates() or b.staged_waiting():
            self.counts.empty_scans = 0
            return "next_object"
        left = self.task.remaining(b.poses)
        if left and self._try_harder(left):
            self.counts.empty_scans = 0
            return "next_object"
        if left:
            why = []
            for q in left:
                t = b.attempts_for(q)
                rs = sorted(set(t.reasons)) if t is not None else []
                why.append(f"{q.cls} ({', '.join(rs) or 'no attempts left'})")
            self.report.message = f"{len(left)} object(s) left in the sink: " + "; ".join(why)
            self.report.safe = self._make_safe()
            return "give_up"
        self.counts.empty_scans += 1
        if self.counts.empty_scans < self.opt.confirm_empty_scans:
            return "next_object"
        problems = []
        if b.unverified:
            problems.append(f"{len(b.unverified)} placement(s) not verified at the target: "
                            f"{', '.join(b.unverified)}")
        if b.staged:
            problems.append(f"{len(b.staged)} object(s) left on the counter after a regrasp failed: "
                            f"{', '.join(st.cls for st in b.staged)}")
        # First-scan items neither in the sink nor placed: as many as were dropped on the way (slips, a held item
        # let go over the cell) are lost; any more were never there (a duplicate detection in the first scan
        # that no later scan confirmed): noted, not a failure.
        missing = (b.first_total or 0) - self.report.objects_done - len(b.unverified) - len(b.staged)
        lost = min(max(missing, 0), b.dropped)
        if lost > 0:
            problems.append(f"{lost} object(s) dropped during the run are neither in the sink nor placed "
                            "(out of reach?)")
        if missing - lost > 0:
            self.report.message = (f"{missing - lost} first-scan detection(s) never confirmed by a later scan "
                                   "(duplicates?)")
        if problems:
            self.report.message = "sink empty, but " + "; ".join(problems)
            self.report.safe = self._make_safe()
            return "give_up"
        return "complete"

    def _same_class_near(self, obj: ObjectPose) -> list[ObjectPose]:
        return [q for q in self.belief.poses if q.cls == obj.cls and
                np.linalg.norm(q.T_base_obj[:3, 3] - obj.T_base_obj[:3, 3]) < self.opt.gone_radius]

    def _verify_pending(self) -> None:
        """Verify the last placement against fresh poses: gone from the sink, present at its target."""
        b = self.belief
        p = b.take_released()
        if p is None:
            return
        # Gone when fewer same-class objects are seen there than before the pick: the top plate of a stack
        # leaves the one nested below it within gone_radius.
        near = self._same_class_near(p.obj)
        still = near if len(near) >= p.near_before else []
        presence = None
        if p.target_view is not None:
            presence = target_presence(p.target_view, self.robot.inventory[p.obj.obj_id], p.T_base_obj)
        self._log("result", "verify", still_in_sink=len(still), presence=presence.as_dict() if presence else None)
        seen_there = presence is not None and presence.decided and presence.present
        if still and not seen_there:
            raise StepFailed("verify_failed", f"the {p.obj.cls} is still in the sink")
        if still:  # seen at its target: what is still counted at its old spot is the item under it or a duplicate
            self._log("note", "placed, though an item of its class is still seen where it was", cls=p.obj.cls)
        if presence is not None and presence.decided and not presence.present:
            # Gone from the sink but not seen where it should be (tipped over, fell): something is likely
            # there, so it stays an obstacle at its target; the report counts it as unverified.
            if p.staged is not None:
                b.unplace(p.staged)
            # it may have tipped or fallen off a stack next to its target: the recovery looks there from above
            # (as for a slip), and an item found there is picked up again (its record at the target goes)
            b.record_unseen(p.obj, b.record_placed(self.task, p.obj, p.target, p.T_base_obj), p.T_base_obj[:3, 3])
            raise StepFailed("verify_failed", f"the {p.obj.cls} was not seen at its target "
                             f"({presence.agree:.0%} of {presence.pixels} px agree)")
        T_settled = p.T_base_obj.copy()
        if presence is not None and presence.decided:
            T_settled[2, 3] += presence.dz  # where it came to rest (it was released a little above)
        if p.staging:
            # Set down on the flat counter, it rests DROP_HEIGHT below its target pose (which stands it on the
            # counter): the depth fit's offset can put an upside-down cup lower than it rests (its rim and the
            # counter agree alike), and grasps planned on such a pose hit the counter.
            T_settled[2, 3] = float(p.target.T_base_obj[2, 3]) - DROP_HEIGHT
        if p.staged is not None:  # it left its staging spot
            b.unplace(p.staged)
        placed = b.record_placed(self.task, p.obj, p.target, T_settled)
        b.scene_changed()
        if p.staging:
            b.record_staged(placed)  # a new item on that spot: the attempts of one staged there before are not its
            self._log("note", "staged for a regrasp", cls=p.obj.cls, xyz=T_settled[:3, 3])
        self.counts.consecutive_recoveries = 0
        if not p.staging:
            self.report.objects_done += int(self.task.wants(p.obj))  # not an item only moved out of the way
            self._cycle_done(p.obj.cls)

    def _cycle_done(self, cls: str) -> None:
        """A placement was verified: one placement cycle's wall and compute time into the report."""
        w0, m0, s0 = self.clock.cycle_t0
        wall, sim = time.perf_counter(), self._sim_now()
        self.report.cycles.append({"object": cls, "wall_s": round(wall - w0, 3),
                                   "compute_s": round((wall - w0) - (self.tracks.wall - m0), 3),
                                   "motion_sim_s": round(sim - s0, 3) if sim is not None else None})
        self.clock.cycle_t0 = (wall, self.tracks.wall, sim)
        self._emit({"type": "placed", "object": cls, "objects_done": self.report.objects_done,
                    "objects_total": self.report.objects_total})
