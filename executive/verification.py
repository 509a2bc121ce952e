"""The verify state of the task runner: a placement is checked (gone from the sink, present at its target:
executive/verify.py) and recorded in the belief; then the run goes on, is complete, or gives up with what is left
and why.

Where the view taken at the retreat pose settles it (the item seen at its target: then it is no longer where it
was picked, and nothing else in the sink touched it, so nothing else there moved) the sink is not scanned again:
the other poses and the map stay as perceived. Where a neighbour may have moved with it, or it came off a stack,
and RunOptions.verify_region_view is on (the default), one view straight down at the pick spot re-perceives
that region and the rest stays as perceived (incremental perception, perception/region.py), where that view
settles it: every known item of the region found again where the scan put it, nothing new there. Otherwise (the
view does not decide, the item is not seen there, the region's view misses an item it should show or finds one
moved or new, nothing left to do) a re-scan and a new perception decide, as the first perception after a
placement.

An item picked up from the counter (staged there for its regrasp) and placed is verified without a re-scan: the
sink was not touched since its last perception, and a scan's views show nothing of the counter
(``_verified_from_the_counter``); the arm then goes back over the sink, where the re-scan would have left it.

An item staged on the counter for a regrasp is recorded where it was put down, and it settles when let go (it
rolls, turns, tips): before it is grasped again, one view straight down at it replaces its record with where the
view shows it (``_look_at_staged``; once per record, Belief.needs_look).

A mixin of TaskRunner (executive/runner.py).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from scipy.spatial import cKDTree

from kitchenbot.drivers.errors import DriverTimeoutError
from kitchenbot.executive.belief import as_pose
from kitchenbot.executive.done_check import DoneCheck
from kitchenbot.executive.failures import StepFailed
from kitchenbot.executive.stage_times import diff as stage_diff
from kitchenbot.executive.unrecognised import Unrecognised, unrecognised_things
from kitchenbot.executive.verify import KEPT, NOT_TAKEN, UNSEEN, depth_agreement, target_presence, where_it_went
from kitchenbot.perception.region import Region, update_region
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.grasps import too_hidden
from kitchenbot.tasks.base import Placed
from kitchenbot.transforms import rotation_angle
from kitchenbot.world.gripper import DROP_HEIGHT


def _lowest(model, T_base_obj: np.ndarray) -> float:
    """Height of the lowest of `model`'s points with the item at T_base_obj (what it rests on)."""
    T = np.asarray(T_base_obj, float)
    return float((model.points @ T[:3, :3].T + T[:3, 3])[:, 2].min())


def _surface(model, T_base_obj: np.ndarray) -> np.ndarray:
    """Every fourth of `model`'s points with the item at T_base_obj (base frame): enough to tell touching items."""
    T = np.asarray(T_base_obj, float)
    return model.points[::4] @ T[:3, :3].T + T[:3, 3]


class Verification(DoneCheck):
    # What a pick can move is what rested or leaned on the item: items beside it on the same support, or under it,
    # stay where they were. An item touching the picked one (model surfaces at their perceived poses within
    # TOUCH_DISTANCE: poses are within ~1-2 cm, so measured generously) is taken to have moved with it when its
    # lowest point is above the picked one's (it rested on it), when it stands tilted (leaning: it may have leant
    # on it), or when it was seen only in part (perhaps hidden by the picked item: a new view may place it better).
    TOUCH_DISTANCE = 0.025  # m
    SAME_SUPPORT = 0.01  # m: lowest points this close rest on the same support
    LEANING = np.radians(20.0)  # tilt of the model's axis from vertical (upright or upside down)
    SEEN_IN_PART = 0.8  # visible_fraction below this share of a fully visible item's
    REGION_MARGIN = 0.03  # m around a neighbour that may have moved: the region its one view re-perceives

    def _do_verify(self) -> str:
        """Verify the placement from its view where that settles it; else re-scan (the first perception after a
        placement verifies it). Then decide: next object, done, give up."""
        if self._verified_from_target_view():
            return "next_object"
        self.views = self._confirming_scan()
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
            self.report.message = self._why_left(left)
            self.report.safe = self._make_safe()
            return "give_up"
        if self._look_at_things_left():  # something no pose explains, looked at from above and perceived anew
            self.counts.empty_scans = 0
            return "next_object"
        if self._look_for_sink_drops():  # an item that fell above the sink, found beside the basin: picked from there
            self.counts.empty_scans = 0
            return "next_object"
        self.counts.empty_scans += 1
        if self.counts.empty_scans < self.opt.confirm_empty_scans:
            return "next_object"
        problems = []
        if b.unverified:
            problems.append(f"{len(b.unverified)} placement(s) not verified at the target: "
                            f"{', '.join(b.unverified)}")
        if b.staged:
            problems.append(self._left_on_counter())
        # First-scan items neither in the sink nor placed: dropped and not seen again, or never there (Belief.unaccounted)
        lost, never = b.unaccounted(self.report.objects_done)
        if lost > 0:
            problems.append(self._name_lost_drops())
        if never > 0:
            self.report.message = (f"{never} first-scan detection(s) never confirmed by a later scan "
                                   "(duplicates?)")
        if problems:
            self.report.message = "sink empty, but " + "; ".join(problems)
            self.report.safe = self._make_safe()
            return "give_up"
        self._name_things_left()  # still no pose for an item-sized thing: the run ends `unrecognised_left`
        return "complete"

    def _confirming_scan(self) -> list:
        """The verify state's scan. Where nothing is left to do as perceived (the picked item aside), it is expected
        to be the first of the scans that confirm the sink empty (RunOptions.confirm_empty_scans): it captures the
        views of the later ones at each waypoint too, and the next confirming scan takes those instead of visiting
        the same waypoints again. They are the views that visit would capture: the same joint configurations, and
        nothing touched the scene in between (no grasp attempt, slide or other scan: TaskRunner._scene_token,
        and the scan before confirmed the sink empty). Otherwise the spare views are dropped and the waypoints
        visited."""
        spare, self.spare_scans = self.spare_scans, None
        if spare is not None and self.counts.empty_scans >= 1 and spare.token == self._scene_token():
            views, rest = spare.sets[0], spare.sets[1:]
            self._record_scan(views)
            if rest:  # for the confirming scan after this one (the token now counts this scan)
                self.spare_scans = dataclasses.replace(spare, sets=rest, token=self._scene_token())
            self._log("note", "confirming scan from the views captured with the one before: nothing touched since")
            return views
        frames = 1
        if self._expects_empty():
            frames = max(1, self.opt.confirm_empty_scans - self.counts.empty_scans)
        return self._scan(frames)

    def _expects_empty(self) -> bool:
        """Nothing left to do as perceived (the item just released aside; none staged on the counter, none being
        staged): the scan about to be taken should confirm the sink empty."""
        b = self.belief
        p = b.released
        if p is not None and p.staging:
            return False
        left = [q for q in b.poses if p is None or q is not p.obj]
        return not self.task.remaining(left) and not b.staged_waiting()

    def _why_left(self, left: list) -> str:
        """The run's message when it gives up with `left` still in the sink: each item with its reasons, what no
        pose explains, and the staged items on the counter with theirs."""
        b, why = self.belief, []
        for q in left:  # each with its latest failure (Belief.why_left)
            why.append(f"{q.cls} ({b.why_left(q) or 'no attempts left'})")
        things = self._unrecognised_in_sink()
        if things:
            why.append(f"{len(things)} unrecognised thing(s) no pose explains (buried, seen too little, or not "
                       "dishware): " + ", ".join(t.describe() for t in things))
        if b.staged:  # on the counter too: each named with its reason, as when the sink is empty
            why.append(self._left_on_counter())
        return f"{len(left)} object(s) left in the sink: " + "; ".join(why)

    def _left_on_counter(self) -> str:
        """The staged items still on the counter (a regrasp that failed, set aside), each with its reasons."""
        b = self.belief

        def why(st) -> str:  # its latest reason (a regrasp that failed, no room at its targets)
            r = b.why_left(as_pose(st))
            return f"{st.cls} ({r})" if r else st.cls
        return (f"{len(b.staged)} object(s) left on the counter after a regrasp failed or set aside: "
                f"{', '.join(why(st) for st in b.staged)}")

    def _unrecognised_in_sink(self) -> list[Unrecognised]:
        """What the map shows in the basin that neither the cell nor a perceived item explains, grouped into
        things (executive/unrecognised.py): named when the run gives up, as the items left are."""
        b = self.belief
        if self.planner is None or b.map_base is None or not len(b.map_base):
            return []
        lo, hi = self.robot.cell.sink_interior
        vox = self.planner.unexplained(b.map_base, b.scene_objects())
        things = unrecognised_things(vox, self.planner.world.voxel_size, lo, hi)
        for t in things:
            self._log("note", "something in the sink no pose explains", xyz=t.centre, extent=t.extent)
        return things

    def _verified_from_target_view(self) -> bool:
        """The released item is seen at its target in its retreat view, it was picked from the latest
        perception alone (no copy of its class within gone_radius: not off a stack), off the sink floor (not off
        another item), nothing else perceived touched it, and the task has items left: recorded as placed without
        a re-scan. Off a stack or another item, or touching one, one view of the pick region may settle it. False
        (nothing changed) when a re-scan must decide."""
        b, p = self.belief, self.belief.released
        if not self.opt.verify_without_rescan or p is None:
            return False
        if p.staged is not None:
            return self._verified_from_the_counter(p)
        if p.target_view is None or not any(q is p.obj for q in b.poses):
            return False
        presence = target_presence(p.target_view, self.robot.inventory[p.obj.obj_id], p.T_base_obj)
        if not (presence.decided and presence.present):
            return False  # not seen there (or the view cannot tell): the re-scan looks at the sink too
        others = [q for q in b.poses if q is not p.obj]
        off_floor = self._above_floor(p.obj) is not None
        held_up = self._held_up_by_unseen(p.obj, others)
        if held_up is not None:  # what it lay on has no pose: it hid it, and the map of before the pick lacks it
            self._log("note", "re-scan: it lay on something no pose describes", cls=p.obj.cls,
                      above_floor=round(held_up, 3))
            return False
        moved = self._moved_with(p.obj, others)
        for q, why in moved:
            self._log("note", "an item may have moved with the one picked", cls=q.cls, xyz=q.T_base_obj[:3, 3],
                      why=why)
        if not self.task.remaining(others) and not p.staging:
            return False  # nothing left as perceived: scans confirm the sink is empty
        # Off a stack (what is left of it is counted again) or off any other item: what the picked item hid under
        # it (an item nested in the one it lay on, seen by no view before) is in no map of before the pick, and the
        # next lift may meet it; one view of the pick region looks first.
        if moved or p.near_before > 1 or off_floor:
            if not (self.opt.verify_region_view and self._perceive_pick_region(p.obj, others, moved)):
                return False
            self._log("note", "verified with one view of the pick region, no re-scan", cls=p.obj.cls)
        else:
            b.picked_away(p.obj, self.task.pending_items(others))
            self._log("note", "verified from the placement view, no re-scan", cls=p.obj.cls)
        self._verify_pending(presence)
        self.counts.empty_scans = 0
        return True

    def _verified_from_the_counter(self, p) -> bool:
        """The released item `p` was picked up from the counter, where it was staged for its regrasp: the sink was
        not touched since its last perception (that of the put-down), and a scan's views (perception keeps what
        lies in the basin only) show nothing of the counter, so a re-scan decides nothing about it. It is verified
        as the re-scan would verify it (gone from where it was picked, present at its target: its target view, when
        there is one; executive/verification.py, ``_verify_pending``), with the sink's poses and map as perceived.
        False (nothing changed) when nothing would be left to do as perceived: the scans confirm the sink
        empty."""
        b = self.belief
        others_waiting = [st for st in b.staged_waiting() if st.instance_id != p.staged.instance_id]
        if not (self.task.remaining(b.poses) or p.staging or others_waiting):
            return False
        presence = None
        if p.target_view is not None:
            presence = target_presence(p.target_view, self.robot.inventory[p.obj.obj_id], p.T_base_obj)
        b.counter_item_moved(p.staged, self.task.pending_items)
        self._log("note", "a staged item verified without a re-scan: the sink was not touched", cls=p.obj.cls,
                  seen=None if presence is None else bool(presence.decided and presence.present))
        self._verify_pending(presence)
        self.counts.empty_scans = 0
        self._back_over_the_sink()
        return True

    def _back_over_the_sink(self) -> None:
        """The arm to where a re-scan would have left it (the last scan waypoint, over the sink), without its views:
        the next grasp's IK branch is chosen nearest where the arm stands, and from the rack it is another one
        than from over the sink (development: the approaches and transfers after a placement verified at the
        rack took longer than the re-scan's moves they replaced). A failed move is left to the next approach."""
        wps = self.robot.config.scan_waypoints
        if self.planner is None or not wps:
            return
        try:
            self._move_joints_via(np.asarray(wps[-1], float), "back over the sink",
                                  np.asarray(self.robot.config.robot.home, float))
        except StepFailed as e:
            if e.kind != "no_path":
                raise
            self._log("note", "no path back over the sink", reason=str(e))

    def _perceive_pick_region(self, obj: ObjectPose, others: list[ObjectPose],
                              moved: list[tuple[ObjectPose, str]]) -> bool:
        """One view straight down at where `obj` was picked; the region the pick may have changed (the item's own
        footprint and that of each neighbour that may have moved with it) re-perceived from it and merged into
        the belief (perception/region.py). False (the belief unchanged) when the view cannot be taken or does
        not settle it: then a re-scan decides."""
        inv, b = self.robot.inventory, self.belief
        m = inv[obj.obj_id]
        discs = [(obj.T_base_obj[:3, 3], m.diameter / 2 + self.TOUCH_DISTANCE)]
        discs += [(q.T_base_obj[:3, 3], inv[q.obj_id].diameter / 2 + self.REGION_MARGIN) for q, _ in moved]
        region = Region.around(discs)
        under = self._covered_from_above([q for q in others if region.contains(q.T_base_obj[None, :3, 3])[0]],
                                         others)
        if under is not None:
            self._log("note", "re-scan: from above, an item of the pick region lies under another", cls=under.cls,
                      xyz=under.T_base_obj[:3, 3])
            return False
        why = self._look_down_at(obj.T_base_obj[:3, 3])
        if why:
            self._log("note", "re-scan: no view of the pick region", reason=why)
            return False
        view = self._capture_view(f"region{self.report.attempts}", "region")
        z_floor = _lowest(m, obj.T_base_obj)
        with self.stages.within("perceive"):
            upd = update_region(self.perceiver, b.map_base, others, view, region, z_floor,
                                symmetric=lambda q: inv[q.obj_id].is_rotationally_symmetric)
        self._check_deadline()
        self._log("result", "perceive region", coverage=round(upd.coverage, 3), rescan=upd.rescan,
                  replaced=len(upd.replaced), found=[{"cls": p.cls, "xyz": p.T_base_obj[:3, 3]} for p in upd.found],
                  appeared=len(upd.appeared))
        hidden = [f for f in upd.found if self.planner is not None and too_hidden(f, self.planner.settings)]
        if upd.rescan is None and hidden:
            # too little of it seen to be grasped (the grasp filter skips it as buried): the scan's views may see
            # more of it now that the picked item is gone
            upd.rescan = "seen too little in the region's view to be grasped: " + ", ".join(f.cls for f in hidden)
        if upd.rescan is None and (upd.moved or upd.appeared):
            # One view settles only what it confirms: every item of the region where the scan put it. A pose fitted
            # from one view straight down (an item that moved, one the pick uncovered) is left to a re-scan's views:
            # plans near it are as good as its pose.
            upd.rescan = "moved or new in the region's view: " + ", ".join(
                [f"{f.cls} moved" for _, f in upd.moved] + [f"{f.cls} new" for f in upd.appeared])
        if upd.rescan is not None:
            self._log("note", "re-scan: one view of the pick region does not settle it", reason=upd.rescan)
            return False
        b.region_perceived(upd.poses, upd.map_points, self.task.pending_items(upd.poses))
        return True

    # An item lies under another as seen from above when one at least COVER_WIDTH as wide as it rests higher up
    # within COVER_OFFSET of its diameter of its axis (a plate, bowl or cup nested in a copy of itself): the view
    # straight down sees the top one only, and the oblique views of a scan see the rims of those under it.
    COVER_WIDTH, COVER_OFFSET = 0.8, 0.25

    def _covered_from_above(self, items: list[ObjectPose], others: list[ObjectPose]) -> ObjectPose | None:
        """The first of `items` that lies under another of `others` as seen from straight above (see
        COVER_WIDTH), else None."""
        inv = self.robot.inventory
        for q in items:
            dq = inv[q.obj_id].diameter
            for r in others:
                if r is q or r.T_base_obj[2, 3] <= q.T_base_obj[2, 3] + 0.005:
                    continue
                if inv[r.obj_id].diameter >= self.COVER_WIDTH * dq and np.linalg.norm(
                        r.T_base_obj[:2, 3] - q.T_base_obj[:2, 3]) < self.COVER_OFFSET * dq:
                    return q
        return None

    def _moved_with(self, obj: ObjectPose, others: list[ObjectPose]) -> list[tuple[ObjectPose, str]]:
        """Those of `others` that may have moved when `obj` was picked, each with why (see TOUCH_DISTANCE)."""
        out: list[tuple[ObjectPose, str]] = []
        inv = self.robot.inventory
        m = inv[obj.obj_id]
        P = _surface(m, obj.T_base_obj)
        tree = cKDTree(P)
        seen_whole = self.SEEN_IN_PART * self.planner.settings.visible_fraction_unoccluded \
            if self.planner is not None else 0.0
        for q in others:
            mq = inv[q.obj_id]
            gap = np.linalg.norm(q.T_base_obj[:3, 3] - obj.T_base_obj[:3, 3]) - m.diameter - mq.diameter
            if gap > self.TOUCH_DISTANCE:  # far apart (an origin lies within its model, within a diameter of it)
                continue
            Q = _surface(mq, q.T_base_obj)
            d, _ = tree.query(Q, distance_upper_bound=self.TOUCH_DISTANCE)
            if not np.isfinite(d).any():
                continue
            if Q[:, 2].min() > P[:, 2].min() + self.SAME_SUPPORT:
                out.append((q, "rested on it"))
            elif np.arccos(min(1.0, abs(float(q.T_base_obj[2, 2])))) > self.LEANING:
                out.append((q, "leaning"))
            elif q.visible_fraction < seen_whole:
                out.append((q, "seen in part"))
        return out

    def _above_floor(self, obj: ObjectPose) -> float | None:
        """How high (m) above the sink floor `obj`'s lowest point lay, when it lay in the sink higher than
        SAME_SUPPORT (on something); None when on the floor or not in the sink."""
        lo, hi = self.robot.cell.sink_interior
        T = obj.T_base_obj
        if not (lo[0] <= T[0, 3] <= hi[0] and lo[1] <= T[1, 3] <= hi[1]):
            return None  # not picked from the sink
        above = _lowest(self.robot.inventory[obj.obj_id], T) - float(lo[2])
        return above if above > self.SAME_SUPPORT else None

    def _held_up_by_unseen(self, obj: ObjectPose, others: list[ObjectPose]) -> float | None:
        """How high (m) above the sink floor `obj` lay when no perceived item was under it to hold it up (its lowest
        point more than SAME_SUPPORT above the floor, and no item of `others` touching it lower down), else None.
        What held it up was hidden by it: a pick from such a pile is verified by a re-scan, or the next plan would
        run on a map that does not show what the pick uncovered (a plate lifted into the plate under the one
        picked, which no pose described)."""
        above = self._above_floor(obj)
        if above is None:
            return None
        T = obj.T_base_obj
        m = self.robot.inventory[obj.obj_id]
        P = _surface(m, T)
        tree = cKDTree(P)
        for q in others:
            mq = self.robot.inventory[q.obj_id]
            if np.linalg.norm(q.T_base_obj[:3, 3] - T[:3, 3]) > m.diameter + mq.diameter:
                continue
            Q = _surface(mq, q.T_base_obj)
            if Q[:, 2].min() < P[:, 2].min() - self.SAME_SUPPORT / 2 and \
                    np.isfinite(tree.query(Q, distance_upper_bound=self.TOUCH_DISTANCE)[0]).any():
                return None  # a perceived item under it, touching it, holds it up
        return above

    def _same_class_near(self, obj: ObjectPose) -> list[ObjectPose]:
        return [q for q in self.belief.poses if q.cls == obj.cls and
                np.linalg.norm(q.T_base_obj[:3, 3] - obj.T_base_obj[:3, 3]) < self.opt.gone_radius]

    # m (horizontal) from its record within which an item of its class seen on the counter is the staged item: it
    # settles within a few cm of where it was let go (it may roll over on its side, as far as its height)
    STAGED_SEARCH = 0.08
    STAGED_AGREE = (0.01, 15.0)  # (m, deg): a view's pose this close to the record confirms it

    def _look_at_staged(self, st: Placed) -> Placed | None:
        """One view straight down at the staged item `st` before its regrasp; the item of its class the view shows
        within STAGED_SEARCH of the record (and nearer to it than to any other record) replaces the record, at the
        record's height (it rests on the counter: the lowest points agree) or as fitted, whichever explains the
        view's depth better (tilted across an edge its lowest point is not the record's), where it explains it
        better than the record does; a view within STAGED_AGREE of the record confirms it, unless a grasp planned on
        the record missed since its last look (then the depth decides). The record returned: the new one, or `st`
        when no view is had or the view does not show it; None when `st` was a found drop the view disproves
        (_found_drop_disproved: the record went)."""
        b = self.belief
        site = np.asarray(st.T_base_obj, float)[:3, 3]
        seen = view = None
        try:
            why = self._look_down_at(site) if self.planner is not None else "no planner"
            if why:
                self._log("note", "no view of the staged item", cls=st.cls, xyz=site, reason=why)
            else:
                view = self._capture_view(f"staged{self.report.attempts}", "staged", spot=True)
                with self.stages.within("perceive"):
                    res = self._drop_perceiver().perceive([view])
                seen = self._staged_in(st, res.poses)
        except (StepFailed, DriverTimeoutError) as e:
            self._log("note", "no view of the staged item", cls=st.cls, xyz=site, reason=str(e))
        if seen is None:
            if view is not None and self._found_drop_disproved(st, view):
                return None
            b.looked_at(self.task, st, None)
            self._log("result", "staged item", cls=st.cls, xyz=site, seen=False)
            return st
        m = self.robot.inventory[st.obj_id]
        T_fit = np.array(seen.T_base_obj, float)  # the view's pose as fitted
        T = T_fit.copy()
        T[2, 3] += _lowest(m, st.T_base_obj) - _lowest(m, T)
        R0 = np.asarray(st.T_base_obj, float)[:3, :3]
        moved = float(np.linalg.norm(T[:3, 3] - site))
        turned = float(np.degrees(rotation_angle(R0.T @ T[:3, :3])))
        if m.is_rotationally_symmetric:  # only its axis counts
            turned = float(np.degrees(np.arccos(np.clip(R0[:, 2] @ T[:3, 2], -1, 1))))
        # the view agrees with the record (within what a pose fit is off by): it lies where it was put down, and
        # the record of that is the better pose; not after a grasp planned on the record missed (Belief.missed_on):
        # off by less than a fit's error, it can still be off by more than a grasp tolerates (a cup lying on its
        # side 9 mm along its axis from its record: every pinch across its tapered body closed 4 mm wider than
        # planned), so the depth of the view decides between them
        doubted = b.missed_on(st)
        agrees = not doubted and moved < self.STAGED_AGREE[0] and turned < self.STAGED_AGREE[1]
        fits = {}
        if not agrees:
            # Which pose does the view bear out? A mug's fit from above can put its handle on the wrong side (its
            # origin, the box centre, then 3 cm off): the record, where it was put down, may be the right one. The
            # view's pose replaces it only where it explains the view's depth better.
            # The view's pose is compared at the record's height and as fitted: where it lies otherwise than put
            # down (tilted across an edge, on something), the record's height says nothing of its own.
            rec_fit, new_fit, fit_fit = (depth_agreement(view, m, X) for X in (st.T_base_obj, T, T_fit))
            if fit_fit.agree > new_fit.agree:
                T, new_fit = T_fit, fit_fit
            fits = {"record_fit": round(rec_fit.agree, 3), "view_fit": round(new_fit.agree, 3)}
            agrees = rec_fit.decided and rec_fit.agree >= new_fit.agree
        self._log("result", "staged item", cls=st.cls, xyz=T[:3, 3], seen=True, agrees=agrees,
                  moved_cm=round(100 * moved, 1), turned_deg=round(turned, 1), after_miss=doubted, **fits)
        return b.looked_at(self.task, st, None if agrees else T)

    def _found_drop_disproved(self, st: Placed, view) -> bool:
        """The view of the staged record `st` shows no item of its class near it. Where `st` is the record a look at
        a drop site made of the dropped item (Belief.found_drops), and the view's depth shows its spot without it
        (target_presence decided, not present) or a grasp planned on it has closed on nothing since its last look
        (Belief.missed_on), that look put it where it is not: the record goes, the drop is lost again, and the drop
        site is looked at anew (an item perceived at the disproved spot is not taken for it; what the view shows
        there unexplained is kept clear of). True if so. (The depth check of a placement, target_presence, cannot
        tell: a plate lowered by its thickness agrees with the counter it is not on.) Before, the record stayed: every later look saw nothing
        near it, three grasps closed on nothing, and the plate, standing in a rack 24 cm away, was in no map
        (the camera later ran into it)."""
        b = self.belief
        if st.instance_id not in b.found_drops:
            return False
        empty, missed = self._shows_nothing_at(view, st), b.missed_on(st)
        if not (empty or missed):
            return False
        b.disprove_found_drop(st)
        self._log("note", "the dropped item is not where the drop-site look put it: looked for again", cls=st.cls,
                  xyz=st.T_base_obj[:3, 3], empty=empty, after_miss=missed)
        self._search_drop_site(cls=st.cls)
        return True

    EMPTY_MIN_POINTS = 30  # view points over a record's footprint needed to call its spot empty

    def _shows_nothing_at(self, view, st: Placed) -> bool:
        """Whether `view` sees the footprint of the record `st` (x-y box of its model at its pose) and nothing there
        that the cell or another believed item does not explain: its spot is empty. False where the view has fewer
        than EMPTY_MIN_POINTS points there (it cannot tell)."""
        from kitchenbot.perception.rgbd import point_map

        T = np.asarray(st.T_base_obj, float)
        body = self.robot.inventory[st.obj_id].points @ T[:3, :3].T + T[:3, 3]
        lo, hi = body.min(axis=0), body.max(axis=0)
        P = point_map(view, stride=2).reshape(-1, 3).astype(float)
        P = P[np.all(np.isfinite(P), axis=1)]
        P = P[np.all((P[:, :2] >= lo[:2]) & (P[:, :2] <= hi[:2]), axis=1) & (P[:, 2] <= hi[2] + 0.05)]
        if len(P) < self.EMPTY_MIN_POINTS:
            return False
        others = [o for o in self.belief.scene_objects() if o.instance_id != st.instance_id]
        return len(self.planner.unexplained(P, others)) == 0

    def _staged_in(self, st: Placed, poses: list[ObjectPose]) -> ObjectPose | None:
        """The pose among `poses` that is the staged item `st` (see _look_at_staged), None if none is."""
        others = [p.T_base_obj[:2, 3] for p in self.belief.placed if p.instance_id != st.instance_id]
        xy = np.asarray(st.T_base_obj, float)[:2, 3]
        best, best_d = None, self.STAGED_SEARCH
        for p in poses:
            d = float(np.linalg.norm(p.T_base_obj[:2, 3] - xy))
            if p.cls != st.cls or d >= best_d:
                continue
            if any(np.linalg.norm(p.T_base_obj[:2, 3] - o) < d for o in others):
                continue  # nearer to another item put down there
            best, best_d = p, d
        return best

    def _verify_pending(self, presence=None) -> None:
        """Verify the last placement against fresh poses: gone from the sink, present at its target (`presence`:
        already measured in its view)."""
        b = self.belief
        p = b.take_released()
        if p is None:
            return
        # Gone when fewer same-class objects are seen there than before the pick: the top plate of a stack
        # leaves the one nested below it within gone_radius.
        near = self._same_class_near(p.obj)
        still = near if len(near) >= p.near_before else []
        if presence is None and p.target_view is not None:
            presence = target_presence(p.target_view, self.robot.inventory[p.obj.obj_id], p.T_base_obj)
        self._log("result", "verify", still_in_sink=len(still), presence=presence.as_dict() if presence else None,
                  carried=p.carried)
        went = where_it_went(p.carried, bool(still), presence)
        if went == KEPT:
            # Something was let go at the target and no view there can tell whether it stands there (no view;
            # the model's pixels have no depth, as a plate on edge in a rack below the counter). The sink still
            # showing its class is no proof it was not taken: a pinch into a stack lifts the top item of two
            # the scan saw as one, and the sink still shows "it". Forgotten, the slot looked free and the next
            # item was carried into the one standing there. Kept there as an obstacle (a slot of room lost if it
            # was not taken), not counted done; not counted unverified either (an item gone from the sink and
            # not seen at its target): the sink still shows its class, and the scans count what is left there.
            # Not looked for around it as an item the view saw absent is: one found standing in its slot would
            # be picked up again out of it.
            if p.staged is not None:
                b.unplace(p.staged)
            b.record_placed(self.task, p.obj, p.target, p.T_base_obj)
            self._log("note", "let go at its target, where no view can tell: kept there as an obstacle",
                      cls=p.obj.cls, xyz=p.T_base_obj[:3, 3])
            raise StepFailed("verify_failed", f"the {p.obj.cls} is still seen in the sink and no view of its "
                             "target can tell whether it stands there: kept there as an obstacle")
        if went == NOT_TAKEN:
            raise StepFailed("verify_failed", f"the {p.obj.cls} is still in the sink")
        if still and went == UNSEEN:
            # carried to its target and let go there: what the sink shows where it was picked is another item (the
            # one it lay on, seen with it as one before the pick), with no attempts of its own yet
            b.record_taken(p.obj)
            self._log("note", "carried to its target: the item of its class still seen where it was picked is "
                      "another one (it lay under it)", cls=p.obj.cls, xyz=still[0].T_base_obj[:3, 3])
        elif still:  # seen at its target: what is still counted at its old spot is the item under it or a duplicate
            self._log("note", "placed, though an item of its class is still seen where it was", cls=p.obj.cls)
        if went == UNSEEN:
            # Gone from the sink (or carried away from it) but not seen where it should be (tipped over, fell, or
            # standing where one view cannot make it out): something is likely there, so it stays an obstacle at
            # its target; the report counts it as unverified.
            if p.staged is not None:
                b.unplace(p.staged)
            # it may have tipped or fallen off a stack next to its target: the recovery looks there from above
            # (as for a slip): seen standing at its target there, it is verified; an item found near it is picked
            # up again (its record at the target goes)
            b.record_unseen(p.obj, b.record_placed(self.task, p.obj, p.target, p.T_base_obj), p.T_base_obj[:3, 3])
            raise StepFailed("verify_failed", f"the {p.obj.cls} was not seen at its target "
                             f"({presence.agree:.0%} of {presence.pixels} px agree)")
        T_settled = p.T_base_obj.copy()
        if presence is not None and presence.decided:
            T_settled[2, 3] += presence.dz  # where it came to rest (it was released a little above)
            # ... but not lower than its target's resting pose (DROP_HEIGHT below the target, which stands it on
            # what the belief holds under it: the counter, a rack, the item it nests on). Where the depth cannot
            # tell offsets apart, a lower one can agree best: a cup nested on a stack of cups agrees 2 cm down,
            # where the cup under it is. Recorded there, 1.6 cm below where it stood, a later transfer planned
            # 1.2 cm over the record ran the held bowl into it.
            T_settled[2, 3] = max(T_settled[2, 3], float(p.target.T_base_obj[2, 3]) - DROP_HEIGHT)
        if p.staging:
            # Set down on the flat counter, it rests DROP_HEIGHT below its target pose (which stands it on the
            # counter): the depth fit's offset can put an upside-down cup lower than it rests (its rim and the
            # counter agree alike), and grasps planned on such a pose hit the counter.
            T_settled[2, 3] = float(p.target.T_base_obj[2, 3]) - DROP_HEIGHT
        if p.staged is not None:  # it left its staging spot
            b.unplace(p.staged)
        placed = b.record_placed(self.task, p.obj, p.target, T_settled)
        b.record_taken(p.obj)
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
        st0, cpu0 = self.clock.cycle_stages0
        wall, sim = time.perf_counter(), self._sim_now()
        st, cpu = self.stages.totals(), self.stages.cpu_totals()
        by_stage, by_stage_cpu = stage_diff(st, st0), stage_diff(cpu, cpu0)
        self.report.cycles.append({"object": cls, "wall_s": round(wall - w0, 3),
                                   "compute_s": round((wall - w0) - (self.tracks.wall - m0), 3),
                                   "compute_cpu_s": round(sum(by_stage_cpu.values()), 3),
                                   "motion_sim_s": round(sim - s0, 3) if sim is not None else None,
                                   "stages_s": by_stage, "stages_cpu_s": by_stage_cpu})
        self.clock.cycle_t0 = (wall, self.tracks.wall, sim)
        self.clock.cycle_stages0 = (st, cpu)
        self._emit({"type": "placed", "object": cls, "objects_done": self.report.objects_done,
                    "objects_total": self.report.objects_total})
