"""Recovery actions of the task runner: what the arm, gripper and camera do after a fault, before the state
machine re-scans, retries or gives up. Which actions, for which failure, is the table in
executive/recovery_rules.py (``_do_recover`` applies its first matching rule); docs/executive.md, "Recovery rules",
is generated from it.

- devices back to a commandable state (reconnect, unlock, gripper reboot);
- after a protective stop: mark where the motion met something, back off along it;
- back out of the sink after a failed grasp;
- put down whatever is still held (its target, the fallback spot, else open over the cell);
- look for an item that fell outside the sink (or a placement not seen at its target) and take it on again;
- give up safely.

A mixin of TaskRunner: the methods use the runner's devices, planner, task, journal and belief.
"""

from __future__ import annotations

import numpy as np

from kitchenbot.drivers.errors import DeviceNotConnectedError, DriverTimeoutError, LimitViolation, ProtectiveStopError
from kitchenbot.executive.belief import as_pose
from kitchenbot.executive.drop_footprint import drop_footprint
from kitchenbot.executive.failures import Failure, StepFailed, Stopped
from kitchenbot.executive.recovery_rules import CAMERA, rule_for
from kitchenbot.executive.recovery_strategies import recover_with
from kitchenbot.executive.strategies import SLIDABLE
from kitchenbot.executive.verify import target_presence
from kitchenbot.perception.rgbd import point_map
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.leave import rise_keeping_own_margins
from kitchenbot.planning.resting import lying_on
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget, PlanningFailure, Trajectory
from kitchenbot.world.gripper import DROP_HEIGHT
from kitchenbot.world.inventory import grasp_kind
from kitchenbot.world.same_item import SAME_ITEM_RADIUS, same_item


class RecoveryActions:
    def _do_recover(self) -> str:
        """Apply the first recovery rule that matches the failure (executive/recovery_rules.py)."""
        f, c = self.failure, self.counts
        self.report.recoveries += 1
        if f.kind != "planning":  # planning failures are bounded per object; these count towards giving up
            c.consecutive_recoveries += 1
        if f.kind in CAMERA:
            c.scan_failures += 1
        rule = rule_for(f, c)
        self._log("note", "recover", kind=f.kind, state=f.state, actions=list(rule.actions), then=rule.then)
        ctx: dict = {}
        for action in rule.actions:
            self.report.recovery_actions[action] = self.report.recovery_actions.get(action, 0) + 1
            if action == "make_safe":
                self.report.message = rule.message.format(kind=f.kind, message=f.message)
            getattr(self, f"_act_{action}")(f, ctx)
        if rule.then == "give_up" and "make_safe" not in rule.actions:
            self.report.message = rule.message.format(kind=f.kind, message=f.message)
            self.report.safe = False
        return rule.then

    # ---- the rules' actions (recovery_rules.ACTIONS) --------------------------------------------------------------
    def _act_make_safe(self, f: Failure, ctx: dict) -> None:
        self.report.safe = self._make_safe()

    def _act_restore_devices(self, f: Failure, ctx: dict) -> None:
        self._restore_devices(f)

    def _act_record_plan_failure(self, f: Failure, ctx: dict) -> None:
        obj = self.item.obj
        if obj is None:
            return
        self._record_plan_failure(obj, f)
        if self.item.staged is None:
            self.belief.record_unplannable(obj)

    def _record_plan_failure(self, obj: ObjectPose, f: Failure) -> None:
        """The planning failure `f` against `obj`, with the strategy that failed last and the items it named lying
        on `obj` or in its way (plan_item's ``strategy``, ``named``: instance ids in the belief's scene)."""
        b = self.belief
        scene = b.scene_objects()
        named = [next((p for p in scene if p.instance_id == i), None) for i in f.details.get("named", ()) if i >= 0]
        b.record_plan_failure(obj, f.details.get("planning_kind", f.kind), f.details.get("strategy", ""),
                               [p for p in named if p is not None])

    def _act_prefer_blocker(self, f: Failure, ctx: dict) -> None:
        b, obj = self.belief, self.item.obj
        if obj is None:
            return
        b.record_blocked(obj, f.details.get("blocking"))
        ids = f.details.get("pinned_by") or ()
        on_it = [p for i in ids for p in b.scene_objects() if i >= 0 and p.instance_id == i]
        if ids and len(on_it) == len(ids) and self.item.staged is None:  # it waits until one of them moves
            b.record_pinned(obj, on_it)
            self._log("note", "waits until what pins it moves", cls=obj.cls, by=[p.cls for p in on_it])

    def _act_record_failure(self, f: Failure, ctx: dict) -> None:
        obj = self.item.obj
        if obj is None:
            return
        if f.state in ("plan", "select_grasp"):  # skipped until the scene changes
            self._record_plan_failure(obj, f)
        elif f.state in ("execute", "verify"):  # counted when executed
            self.belief.record_failure(obj, f.kind)
            if f.kind == "grasp_missed":
                self.belief.doubt(obj)
            if f.kind == "grasp_missed" and self.item.pick is not None:
                for name in self._missed_alike(f, obj, self.item.pick.grasp.spec.name):
                    self.belief.record_missed_grasp(obj, name)
            if f.kind == "grasp_missed" and self._closed_on_a_nest(f, obj):
                self.belief.record_nest_felt(obj)
            if f.kind == "grasp_missed" and self.item.staged is not None:
                self.belief.look_again(self.item.staged)

    def _missed_alike(self, f: Failure, obj: ObjectPose, name: str) -> list[str]:
        """The grasp `name` that missed, and, where its grip closed off its planned width (``expected`` in the
        failure: it took in something besides the item's wall) on a round item, every grasp of its kind: the same
        pinch turned about the item's axis (``kind_NN``) meets the same thing there. A plate nested on another is
        seen as one plate; each rim pinch then closes across both rims, wherever around the plate it is tried,
        and the item's attempts ran out on the one kind while other kinds (a shallower bite) take the top plate
        alone."""
        if "expected" not in f.details:
            return [name]
        inv = self.planner.inventory if self.planner is not None else self.robot.inventory
        model = inv.models.get(obj.obj_id)
        kind = grasp_kind(name)
        if model is None or not model.is_rotationally_symmetric or kind is None:
            return [name]
        return [name] + [g.name for g in model.grasps if g.name != name and grasp_kind(g.name) == kind]

    # a plate's grip that closes wider than planned by this fraction of its nest pitch (or more) took in a second
    # rim: the pitch is the rise from one nested plate to the next, so both rims and the gap between them
    NEST_FELT = 0.8

    def _closed_on_a_nest(self, f: Failure, obj: ObjectPose) -> bool:
        """Whether the grip that failed `f` closed on a plate wider than planned (``expected`` in the failure) by
        NEST_FELT of its model's nest pitch or more: its pads took in the rim of a plate nested under it, the pair
        seen as one plate (SLIDABLE classes only: those nest flat)."""
        if "expected" not in f.details or "opening" not in f.details or obj.cls not in SLIDABLE:
            return False
        inv = self.planner.inventory if self.planner is not None else self.robot.inventory
        model = inv.models.get(obj.obj_id)
        if model is None or model.nest_pitch <= 0:
            return False
        return float(f.details["opening"]) - float(f.details["expected"]) >= self.NEST_FELT * model.nest_pitch

    def _act_back_off(self, f: Failure, ctx: dict) -> None:
        tr = self.tracks
        stopped = tr.stopped.name if f.kind in ("protective_stop", "contact") and tr.stopped else None
        ctx["stopped"] = stopped
        if stopped == "lift":
            # Back down the lift (the way it came: free in the world as it is) and let go where the item was taken
            # from. A put-down planned from the stop point starts right against what the lift met, which no model
            # holds (a missed or mis-posed neighbour): its first move met the same thing again. Where the item is
            # let go there, the lift's direction is remembered for it (its next plans lift it otherwise); where it
            # is put down elsewhere, what the lift was about to sweep is marked after (mark_lift_contact).
            ctx["lift_marks"] = self._contact_sliver(tr.stopped) if self.planner is not None else None
            direction = self._stopped_direction(tr.stopped) if self.planner is not None else None
            obj = self.item.obj
            try:
                if self._retrace(tr.stopped, "back_off", short_of=self.RELEASE_ABOVE) and self._holding():
                    self._release_in_place()
                    if obj is not None and direction is not None:
                        self._remember_stopped_lift(obj, direction, ctx)
            except ProtectiveStopError as e:  # should not happen (the way back was free): put down from here
                self._unlock_after_refused("back off stopped", e)
            tr.stopped = None
        elif stopped:
            self._back_off()

    def _release_in_place(self) -> None:
        """Open where the held item was taken from (the arm back at the grasp): it stands where it stood."""
        pick = self.item.pick
        opening = pick.grasp.spec.opening if pick is not None else None
        self._cmd("gripper.open", opening=opening, release=True)
        self.gripper.open(opening)
        self._log("note", "backed down the stopped lift and let go where the item was taken from")

    def _remember_stopped_lift(self, obj: ObjectPose, direction: np.ndarray, ctx: dict) -> None:
        """The item of a stopped lift stands where it was taken: what the lift was about to sweep (the held item's
        surface and the pads, CONTACT_LOOKAHEAD further along) is not marked. That sliver is the space the item's
        own next grasp and lift need (the pads' boxes over its rim, its surface over where it stands): marked, every
        grasp of it collided with the marks until the scene changed, while what the lift met may lie anywhere
        along the item (a bowl's foot under a plate's flange, 5 cm below the marks). What is known is that lifting
        it this way from here meets something: its next plans lift it otherwise (Belief.record_stopped_lift)."""
        ctx["lift_marks"] = None
        self.belief.record_stopped_lift(obj, direction)
        self._log("note", "the stopped lift's direction is not tried again for this item", cls=obj.cls,
                  direction=np.asarray(direction, float))

    def _act_leave_after_slip(self, f: Failure, ctx: dict) -> None:
        if f.kind == "slip" and not self._holding():  # the strategies for a slip (executive/recovery_strategies.py)
            recover_with(self, "slip")

    def _act_put_down_held(self, f: Failure, ctx: dict) -> None:
        if self._holding():  # not again where the held item was just stopped on its way down to its target
            self._put_down_held(avoid_place_target=ctx.get("stopped") in ("transfer", "lower"))

    def _act_mark_lift_contact(self, f: Failure, ctx: dict) -> None:
        if ctx.get("lift_marks") is not None:  # the next try at this item lifts clear of what it met
            self._add_contact_marks(ctx["lift_marks"])

    def _act_back_out(self, f: Failure, ctx: dict) -> None:
        self._back_out()

    def _act_search_drop_site(self, f: Failure, ctx: dict) -> None:
        if self.belief.drop_site is not None:  # it slipped out, or was let go over the cell: look where it fell
            self._search_drop_site()

    # ---- the actions' mechanics ----------------------------------------------------------------------------------
    def _restore_devices(self, f: Failure) -> None:
        """Bring the devices back to a commandable state (bounded reconnects, unlock, gripper reboot)."""
        c = self.counts
        if not self.arm.is_connected:
            if c.reconnects >= self.opt.max_reconnects:
                raise DeviceNotConnectedError(f"arm: still disconnected after {c.reconnects} reconnects")
            c.reconnects += 1
            self._cmd("arm.connect", attempt=c.reconnects)
            self.arm.connect()
        from kitchenbot.drivers.arm import SafetyState

        if self.arm.safety_state() is SafetyState.PROTECTIVE_STOP:
            self._cmd("arm.unlock_protective_stop", reason=f.kind)
            self.arm.unlock_protective_stop()
        if self.gripper.error() is not None:
            self._cmd("gripper.reboot", error=self.gripper.error())
            self.gripper.reboot()
            self._cmd("gripper.open")
            self.gripper.open()
        if self.arm.is_moving():
            self.arm.stop()

    def _unlock_after_refused(self, what: str, e: Exception, kind: str = "note") -> None:
        """A recovery motion was refused (a limit) or stopped (a protective stop): journal why (`kind`, `what`)
        and, where the arm stands in a protective stop, unlock it, so that the next action or rule can move it.
        The one way every recovery motion (back off, back out, rise out, put down) gets the arm going again."""
        from kitchenbot.drivers.arm import SafetyState

        self._log(kind, what, reason=str(e))
        if self.arm.safety_state() is SafetyState.PROTECTIVE_STOP:
            self._cmd("arm.unlock_protective_stop", reason=what)
            self.arm.unlock_protective_stop()

    def _back_off(self) -> None:
        """After a protective stop (on the real arm: a contact) go back along the motion it cut short, to where
        that motion started: the one way known to be free in the world as it is. Re-planning from the stop
        point with the same world model would lead into the same contact."""
        traj, self.tracks.stopped = self.tracks.stopped, None
        if traj is None:
            return
        if self.planner is not None:
            self._mark_contact(traj)
        try:
            if self._retrace(traj, "back_off"):
                self._log("note", "backed off along the stopped motion", motion=traj.name)
        except ProtectiveStopError as e:  # should not happen (the way back was free): leave it to the next rule
            self._unlock_after_refused("back off stopped", e)

    CONTACT_LOOKAHEAD = 0.015  # m of tool travel past a stop within which what it touched must lie
    RELEASE_ABOVE = 0.005  # m short of a stopped lift's start where the item is let go (it drops that far)

    def _ahead_of_stop(self, traj: Trajectory) -> np.ndarray | None:
        """A protective stop cut `traj` short (the arm stands on it): its sample CONTACT_LOOKAHEAD of tool travel
        further along (its last where it ends sooner), or None where the arm is not on it."""
        robot = self.planner.robot
        k = self._index_on(traj)
        if k is None:
            return None
        p0 = robot.fk_tcp(self.arm.joint_positions())[:3, 3]
        j = k
        while j + 1 < len(traj) and np.linalg.norm(robot.fk_tcp(traj.q[j + 1])[:3, 3] - p0) < self.CONTACT_LOOKAHEAD:
            j += 1
        return traj.q[min(j + 1, len(traj) - 1)]

    def _stopped_direction(self, traj: Trajectory) -> np.ndarray | None:
        """The direction (unit, base frame) the tool moved in where a protective stop cut `traj` short: from the
        stop point to CONTACT_LOOKAHEAD further along (from the motion's start where it stopped at its end), or
        None where the arm is not on it or it did not move the tool."""
        q_ahead = self._ahead_of_stop(traj)
        if q_ahead is None:
            return None
        fk = self.planner.robot.fk_tcp
        p = fk(self.arm.joint_positions())[:3, 3]
        d = fk(q_ahead)[:3, 3] - p
        if np.linalg.norm(d) < 1e-4:
            d = p - fk(traj.q[0])[:3, 3]
        n = float(np.linalg.norm(d))
        return d / n if n >= 1e-4 else None

    def _contact_sliver(self, traj: Trajectory) -> np.ndarray | None:
        """A protective stop cut `traj` short (the arm stands on it): what the tool (or what it holds) touched
        lies in the space it was about to sweep, the next CONTACT_LOOKAHEAD of its path. Points filling that
        sliver (base frame), or None."""
        robot, g = self.planner.robot, self.planner.world.gripper
        q_ahead = self._ahead_of_stop(traj)
        if q_ahead is None:
            return None
        q = self.arm.joint_positions()
        opening = float(self.gripper.opening())
        # the pads (and what they hold) lead the tool into whatever it meets; the palm and camera behind them are
        # left out: their slivers would fill the space the arm itself needs to back away
        boxes = g.pads(robot.T_flange_tcp, opening)

        def inside(P, T_base_box, size, pad=0.003):
            L = (P - T_base_box[:3, 3]) @ T_base_box[:3, :3]
            return np.all(np.abs(L) <= np.asarray(size) / 2 + pad, axis=1)

        F0, F1 = robot.fk(q, "flange"), robot.fk(q_ahead, "flange")
        out = []
        for tb in boxes:  # grid points of each pad where it was about to be, and is not yet
            size = np.asarray(tb.size, float)
            axes = [np.linspace(-h / 2, h / 2, max(2, int(np.ceil(h / 0.01)) + 1)) for h in size]
            G = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
            T1 = F1 @ tb.T_flange_box
            P = G @ T1[:3, :3].T + T1[:3, 3]
            keep = np.ones(len(P), bool)
            for tb0 in boxes:
                keep &= ~inside(P, F0 @ tb0.T_flange_box, tb0.size)
            out.append(P[keep])
        dragged = self._dragged_sliver(traj, q, q_ahead, np.concatenate(out) if out else np.zeros((0, 3)))
        if dragged is not None:
            out = dragged
        pick = self.item.pick
        if dragged is None and pick is not None and self._holding():  # the held item's surface where it was about to be
            from scipy.spatial import cKDTree

            m = self.robot.inventory[pick.grasp.obj.obj_id]
            T_tcp_obj = pick.grasp.T_tcp_obj
            T0, T1 = robot.fk_tcp(q) @ T_tcp_obj, robot.fk_tcp(q_ahead) @ T_tcp_obj
            P0 = m.points @ T0[:3, :3].T + T0[:3, 3]
            P1 = m.points @ T1[:3, :3].T + T1[:3, 3]
            out.append(P1[cKDTree(P0).query(P1)[0] > 0.005])
        pts = np.concatenate(out) if out else np.zeros((0, 3))
        return pts if len(pts) else None

    LEADING_ANGLE = np.radians(45.0)  # rad either side of a slide's direction within which its item leads

    def _dragged_sliver(self, traj: Trajectory, q: np.ndarray, q_ahead: np.ndarray, pads: np.ndarray) -> list | None:
        """For a stopped press or slide (the closed fingers press on the item and drag it along): the item's
        surface where it was about to be, and of `_contact_sliver`'s pad points those beside it, not over it. The
        pads ride on the item, so the space ahead of them over it is the item's own (the next pick of it lifts
        through there: marked, it blocked every lift of that item until the scene changed); what stopped the
        slide met the item's leading side, its underside (jammed on what it rests on), or the pads beside it.
        None for any other motion."""
        from scipy.spatial import Delaunay

        sl = self.item.slide
        if sl is None or not any(traj is t for t in (sl.press, sl.slide)):
            return None
        robot = self.planner.robot
        m = self.robot.inventory[sl.target.obj_id]
        T_obj = np.asarray(sl.target.T_base_obj, float)

        def item_at(qq):  # the item rides with the pads along the slide (as planned); a press leaves it where it is
            T = T_obj if traj is sl.press else robot.fk_tcp(qq) @ np.linalg.inv(robot.fk_tcp(sl.slide.q[0])) @ T_obj
            return m.points @ T[:3, :3].T + T[:3, 3], T[:3, 3]

        (P0, _), (P1, c1) = item_at(q), item_at(q_ahead)

        def over(P, Q):  # points of P over the item's points Q (within their footprint seen from above)
            try:
                return Delaunay(Q[:, :2]).find_simplex(P[:, :2]) >= 0
            except Exception:  # noqa: BLE001 - a degenerate footprint (an item on edge): nothing counts as over it
                return np.zeros(len(P), bool)

        # the slide is level: the item's leading side where it was about to be (outside where it is, within
        # LEADING_ANGLE of the slide's direction seen from its centre: what a level push meets lies ahead of it)
        r = P1[:, :2] - c1[:2]
        lead = r @ np.asarray(sl.direction, float)[:2] >= np.cos(self.LEADING_ANGLE) * np.linalg.norm(r, axis=1)
        ahead = P1[lead & ~over(P1, P0)]
        pads = pads[~over(pads, P1)] if len(pads) else pads
        return [ahead, pads]

    def _mark_contact(self, traj: Trajectory) -> None:
        """Mark where the motion `traj`, cut short by a protective stop, met something (see _add_contact_marks)."""
        self._add_contact_marks(self._contact_sliver(traj))

    def _add_contact_marks(self, pts: np.ndarray | None, unseen_cls: str | None = None) -> None:
        """Keep `pts` (a contact sliver) as map points no object explains, so plans keep clear of it as of any
        unknown obstacle: the same world model would otherwise plan into the same contact (a cup recorded where it
        did not settle; a neighbour in a pile perceived a few mm off, which the next scan perceives the same way).
        Marks in the sink last until the scene has changed (Belief.mark_contact); `unseen_cls`: they stand for a
        fallen item of that class no view recognised, and go when a perception recognises one among them."""
        if self.belief.mark_contact(pts, unseen_cls):
            self._log("note", "marked where the stopped motion met something", points=len(pts),
                      centre=pts.mean(axis=0))

    def _back_out(self) -> None:
        """After a failed grasp the gripper may be around an object in the sink: open, then straight back out."""
        if self.failure is None or self.failure.state != "execute":
            return
        pick = self.item.pick
        if pick is not None:
            # open (never close: pads that let go of an item wider than planned would close on it again)
            if not self._holding() and self.gripper.opening() < pick.grasp.spec.opening:
                self._cmd("gripper.open", opening=pick.grasp.spec.opening)
                self.gripper.open(pick.grasp.spec.opening)
            if self._retrace(pick.grasp_in, "back_out"):  # it was on the grasp-in line
                return
        # (no pick: a slide was cut short, the fingers may still press on the item: straight up). Only in the sink:
        # this move is not planned, and elsewhere low down (a rack) the tool is not around a sink item; a stop
        # there is left to the planned escape of the next motion (Motions._escape).
        lo, hi = self.robot.cell.sink_interior
        tcp = self.arm.tcp_pose()[:3, 3]
        in_sink = bool(np.all(tcp[:2] >= np.asarray(lo)[:2]) and np.all(tcp[:2] <= np.asarray(hi)[:2]))
        if in_sink and tcp[2] < 0.05 and self.planner is not None:
            self._rise_out()
        elif in_sink and tcp[2] < 0.05:  # deep in the sink elsewhere: straight up a little
            T = self.arm.tcp_pose()
            T[2, 3] += self.BACK_OUT_RISES[0]
            self._cmd("arm.move_linear", up=self.BACK_OUT_RISES[0])
            try:
                with self._arm_lock:
                    self.arm.move_linear(T, speed=0.05, accel=0.3, asynchronous=True)
                self._wait_motion("back out up", 2.5)
            except (LimitViolation, ProtectiveStopError) as e:
                self._unlock_after_refused("back out refused", e)

    BACK_OUT_RISES = (0.08, 0.06, 0.04, 0.02)  # m straight up out of the sink, longest first

    def _rise_out(self) -> None:
        """Straight up out of the sink by the longest of BACK_OUT_RISES along which the arm keeps its own margins
        (planning.leave.rise_keeping_own_margins): a straight TCP line can bring the wrist within the margin of
        the forearm, a start every planned motion refuses. None: stay (the next motion's planned escape)."""
        why = []
        for up in self.BACK_OUT_RISES:
            r = rise_keeping_own_margins(self.planner, self.arm.joint_positions(), up)
            if isinstance(r, PlanningFailure):
                why.append(f"{up:.2f} m: {r.message}")
                continue
            try:
                self._run_trajectory(r[0])
            except (LimitViolation, ProtectiveStopError) as e:
                self._unlock_after_refused("back out refused", e)
            return
        self._log("note", "no way straight up out of the sink keeping the arm's own margins", reason="; ".join(why))

    SEARCH_RADIUS = 0.25  # m around the drop site an item found there may have come to rest

    def _search_drop_site(self, cls: str | None = None) -> None:
        """An item slipped out outside the sink (over the counter): the sink scans never look there. Look straight
        down at where it fell; an item of its class found there (and not one placed earlier) is picked up again
        from there, as an item staged on the counter is. Where it fell is judged by the item as it was held
        (executive/drop_footprint.py): part of it over the basin, a scan must see it back in the sink; its centre
        (or a part of it well) beyond the basin, the counter is looked at too, straight down at its centre.
        `cls`: the dropped item's class where no item is being handled (a drop looked for again)."""
        b = self.belief
        site, unseen_rec = b.take_drop_site()  # (unseen_rec: a placement not seen at its target, kept there)
        held = b.take_dropped_held() if unseen_rec is None else None
        cls = cls or (self.item.obj.cls if self.item.obj is not None else None)
        if site is None or cls is None or self.planner is None:
            return
        lo, hi = self.robot.cell.sink_interior
        fp = drop_footprint(site, held, (lo, hi))
        awaited = None
        if fp.over_basin and unseen_rec is None and self.item.obj is not None:
            # it fell back into the sink, or onto its rim: a scan that sees it back says so
            obj = self.item.obj
            at = obj.T_base_obj[:3, 3]  # (a duplicate detection of it is not another item)
            expect = 1 + sum(1 for p in b.poses if p.cls == cls and self.task.in_sink(p) and p is not obj
                             and not same_item(p.cls, p.T_base_obj[:3, 3], cls, at))
            awaited = b.await_in_sink(cls, site, expect, (lo, hi), look_at=fp.centre)
        if not fp.beyond_basin:
            return
        if awaited is not None:
            self._log("note", "the dropped item was held over the basin's edge: awaited in the sink, looked for on "
                      "the counter", cls=cls, tool=site, centre=fp.centre)
        site = fp.centre
        keep_out = self._keep_out(site, cls)
        self.tracks.searching = True
        unseen = True
        try:
            with b.keeping_out(keep_out):
                why = self._look_down_at(site)
                if why:
                    self._log("note", "no way to look at the drop site", at=site, reason=why)
                    return
                view = self._capture_view(f"drop{b.dropped}", "drop", spot=True)
            unseen = False
        except (StepFailed, DriverTimeoutError, ProtectiveStopError) as e:
            self._log("note", "drop site not seen", reason=str(e))
            self._restore_devices(self.failure or Failure("error", str(e), self.state))
            return
        finally:
            self.tracks.searching = False
            if unseen and keep_out is not None:
                # the item lies somewhere under there, unseen: plans keep clear of it for the rest of the run
                # (what is in the sink is dropped once an item has been placed: the scans see the sink)
                self._add_contact_marks(keep_out, cls)
        if unseen_rec is not None and unseen_rec.target.kind != "stage" and self._seen_at_its_target(view, unseen_rec):
            return
        with self.stages.within("perceive"):
            res = self._drop_perceiver().perceive([view])
        placed = [o for o in b.obstacles() if unseen_rec is None or o.instance_id != unseen_rec.instance_id]
        found = [p for p in res.poses if p.cls == cls
                 and np.linalg.norm(p.T_base_obj[:2, 3] - site[:2]) < self.SEARCH_RADIUS
                 and not self.task.in_sink(p)
                 and not any(self._is_placed_item(p, o) for o in placed)
                 and not any(same_item(cls, p.T_base_obj[:3, 3], cls, x) for x in b.disproved_spots)]
        self._log("result", "drop site", at=site, found=[p.T_base_obj[:3, 3] for p in found])
        if not found:
            # nothing of its class recognised there (fallen into a rack, lying on its side against something): it
            # still lies about there, unseen by the sink scans; what the view shows inside the keep-out that
            # neither the cell nor a believed item explains is where it lies: plans keep clear of it
            # (the whole cylinder: the item's top may stand right under where the tool was when it fell)
            self._add_contact_marks(self._unexplained_in(view, self._keep_out(site, cls, clear_of_tool=False)), cls)
            return
        obj = min(found, key=lambda p: np.linalg.norm(p.T_base_obj[:2, 3] - site[:2]))
        drop = b.record_drop_found() if unseen_rec is None else None
        if awaited is not None:
            b.stop_awaiting(awaited)
        if unseen_rec is not None and unseen_rec.cls == cls:  # nothing stands at its target; handled again from here
            b.found_unseen(unseen_rec)
            self._log("note", "the item not seen at its target lies near it", cls=cls, xyz=obj.T_base_obj[:3, 3],
                      target=unseen_rec.T_base_obj[:3, 3])
        T_release = np.array(obj.T_base_obj, float)
        T_release[2, 3] += DROP_HEIGHT  # as if released there (place targets are release poses)
        where = PlaceTarget(T_release, "drop", support="counter (it fell there)")
        placed = b.record_placed(self.task, obj, where, obj.T_base_obj)
        self.report.recovered_drops += 1
        if self.task.accepts_as_it_lies(obj):  # it fell where the task wants it (the drop zone takes it as it is)
            self.report.objects_done += int(self.task.wants(obj))
            b.scene_changed()
            self._log("note", "the dropped item lies at its target", cls=cls, xyz=obj.T_base_obj[:3, 3])
            return
        b.record_found(placed)
        b.record_found_drop(placed, drop)
        b.seen_where_marked([obj])  # marks that stood for it unrecognised (an earlier look) would cage it
        # what else the view shows where it may have fallen, that neither the cell nor a believed item (the found
        # one included) explains, is kept clear of: the look may have put it in the wrong place (a plate standing
        # in a rack, seen as one lying 24 cm away; the camera later hit it where it stood, in no map)
        self._add_contact_marks(self._away_from(obj, self._unexplained_in(
            view, self._keep_out(site, cls, clear_of_tool=False))), cls)
        self._emit({"type": "progress", "note": f"found the dropped {cls} on the counter"})

    AWAY_FROM_FOUND = 0.03  # m: unexplained voxels this close to a found item's surface are its own (a fit's error)

    def _away_from(self, obj: ObjectPose, vox: np.ndarray | None) -> np.ndarray | None:
        """The voxel centres `vox` farther than AWAY_FROM_FOUND from `obj`'s model surface at its pose: what its
        pose does not explain for being a few mm off is not kept as an obstacle around it (its regrasp goes there)."""
        if vox is None or not len(vox) or obj.obj_id not in self.robot.inventory.models:
            return vox
        from scipy.spatial import cKDTree

        T = np.asarray(obj.T_base_obj, float)
        surface = self.robot.inventory[obj.obj_id].points @ T[:3, :3].T + T[:3, 3]
        d, _ = cKDTree(surface).query(vox, distance_upper_bound=self.AWAY_FROM_FOUND)
        return vox[~np.isfinite(d)]

    def _is_placed_item(self, p: ObjectPose, placed: ObjectPose) -> bool:
        """Whether the pose `p` found at a drop site is the item the robot put down as `placed`, seen again: where
        something was placed (within SAME_ITEM_RADIUS in x-y), whatever perception calls it, unless `p` rests on
        it as the pick order judges that (planning.resting.lying_on: `p` higher, lifting `placed` runs into it for
        longer than the other way round, and `p` lifted leaves it within 2 cm; a misreading of the placed item
        overlaps it deeper than that). An item of the same class within SAME_ITEM_RADIUS in 3-D is always the
        placed one. Before, x-y alone
        decided: a glass that slipped out above the drop zone and came to rest on its side on the plates placed
        there (its centre 3 cm from theirs in x-y) was taken for a plate, not found, and the run ended with it
        lost although it lay in view."""
        a, o = np.asarray(p.T_base_obj, float)[:3, 3], np.asarray(placed.T_base_obj, float)[:3, 3]
        if np.linalg.norm(a[:2] - o[:2]) >= SAME_ITEM_RADIUS:
            return False
        if same_item(p.cls, a, placed.cls, o):
            return True
        return not lying_on(placed, [p], self.planner.inventory)

    def _seen_at_its_target(self, view, rec) -> bool:
        """A second view (straight down at its target) of a placement its first view did not see there: where this
        one shows it standing as recorded (the depth check, executive/verify.py), it is verified there (counted
        done, no longer unverified) and True. Not perceived anew: a perception that finds it there would take it
        for an item fallen near its target and pick it up again out of its slot."""
        presence = target_presence(view, self.robot.inventory[rec.obj_id], rec.T_base_obj)
        self._log("result", "second look at the target", cls=rec.cls, presence=presence.as_dict())
        if not (presence.decided and presence.present):
            return False
        b = self.belief
        if rec.cls in b.unverified:
            b.unverified.remove(rec.cls)
        self.report.objects_done += int(self.task.wants(as_pose(rec)))
        b.scene_changed()
        self._log("note", "seen standing at its target on a second look: verified there", cls=rec.cls,
                  xyz=rec.T_base_obj[:3, 3])
        return True

    def _unexplained_in(self, view, region: np.ndarray | None) -> np.ndarray | None:
        """Centres of the 2 cm voxels of what `view` sees within 1 cm of `region`'s points (a keep-out) that neither
        the cell nor an item in the belief explains; None without a region."""
        if region is None or not len(region):
            return None
        from scipy.spatial import cKDTree

        P = point_map(view, stride=2).reshape(-1, 3).astype(float)
        P = P[np.all(np.isfinite(P), axis=1)]
        d, _ = cKDTree(region).query(P, distance_upper_bound=0.01)
        return self.planner.unexplained(P[np.isfinite(d)], self.belief.scene_objects())

    KEEP_OUT_DEPTH = 0.45  # m below the drop site a fallen item may have come to rest (a rack under the counter)

    def _keep_out(self, site: np.ndarray, cls: str, clear_of_tool: bool = True) -> np.ndarray | None:
        """Points filling an upright cylinder under the drop site, as wide as the fallen item and reaching from
        KEEP_OUT_DEPTH below the site up to where the item may stand (no scene knows it yet): as map points no
        object explains, the planner keeps clear of them like of any unknown obstacle. The item fell from the
        tool, so the cylinder ends below the tool as it is now (lowered in 2 cm steps until the tool clears it;
        what is left within the margin is escaped straight up). None if no such cylinder clears the tool.
        `clear_of_tool=False`: the whole cylinder, wherever the tool is (a region to look in, not an obstacle)."""
        models = [m for m in self.robot.inventory.models.values() if m.cls == cls]
        radius = max((m.diameter for m in models), default=0.3) / 2 + 0.03
        z_lo = float(site[2]) - self.KEEP_OUT_DEPTH
        z_hi = max(0.0, z_lo) + max((float(np.max(m.extents)) for m in models), default=0.3) + 0.01
        g = np.arange(-radius, radius + 1e-9, 0.01)
        X, Y = np.meshgrid(g, g)
        disc = np.c_[X.ravel(), Y.ravel()][np.hypot(X.ravel(), Y.ravel()) <= radius] + site[:2]
        q = self.arm.joint_positions()
        while z_hi > z_lo + 0.02:
            pts = np.concatenate([np.c_[disc, np.full(len(disc), z)] for z in np.arange(z_lo, z_hi, 0.01)])
            if not clear_of_tool:
                return pts
            scene = self.planner.scene([], pts)
            if scene.touching_only(scene.colliding_pairs(q)).valid(q):
                return pts
            z_hi -= 0.02
        return None

    def _drop_perceiver(self):
        """The configured pipeline without the cell's geometry: the counter is the support plane (the pipeline's
        sink-only segmentation would see nothing there). The oracle sees everything anyway."""
        from kitchenbot.perception.pipeline import Perceiver

        p = self.perceiver
        if not isinstance(p, Perceiver):
            return p
        if self.table_perceiver is None:
            self.table_perceiver = Perceiver(p.settings, p.inventory, database=p.database, use_cell=False)
        return self.table_perceiver

    PUT_DOWN_AVOID_RADIUS = 0.10  # m: no second put-down try this close to a target where the held item hit something

    def _put_down_held(self, avoid_place_target: bool = False) -> bool:
        """Something is in the gripper after a fault: place it at its target, else the fallback spot; if every
        plan fails or is stopped by the arm, open where it is when that is over the cell (sink, counter, racks:
        it drops a few centimetres onto them and the scan will find it). True if it was placed.
        `avoid_place_target`: the way to the planned target was just stopped; no target near it is tried."""
        it = self.item
        grasp = it.pick.grasp if it.pick is not None else None
        targets = []
        if it.place is not None:
            targets.append(it.place.target)
        if it.obj is not None:
            fb = self.task.fallback_target(it.obj, self.belief)
            if not isinstance(fb, NoFreeSlot):
                targets.append(fb)
        hit: list[np.ndarray] = []  # where a put-down was stopped: the world there is not as modelled
        if avoid_place_target and it.place is not None:
            hit.append(it.place.target.T_base_obj[:3, 3])
        if grasp is not None:
            for tgt in targets:
                if any(np.linalg.norm(tgt.T_base_obj[:2, 3] - h[:2]) < self.PUT_DOWN_AVOID_RADIUS for h in hit):
                    continue
                q = self.arm.joint_positions()
                plan = self.planner.plan_place(q, grasp, tgt, objects=self.belief.scene_objects())
                if not plan.ok:
                    continue
                self._log("note", "putting down the held object", target=tgt.T_base_obj[:3, 3])
                try:
                    self._run_trajectory(plan.transfer)
                    self._run_trajectory(plan.lower, guarded=True)
                    opening = plan.release_opening if plan.release_opening is not None else grasp.spec.opening
                    self._cmd("gripper.open", opening=opening, release=True)
                    self.gripper.open(opening)
                    if self.arm.stopped_on_contact:
                        self._retrace(plan.lower, "retreat")
                    else:
                        self._run_trajectory(plan.retreat)
                    # It stands there now: verified by the next scan like any placement (its own target), or,
                    # at the fallback spot, staged to be picked up again (unless the task takes it there).
                    T_rest = np.array(plan.T_base_obj, float)
                    T_rest[2, 3] = min(T_rest[2, 3], float(tgt.T_base_obj[2, 3]))
                    own = it.place is not None and tgt is it.place.target
                    if it.obj is not None:
                        there = ObjectPose(it.obj.obj_id, it.obj.cls, T_rest, 1.0)
                        # (its transfer was not polled for a hold: the sink may still show what the hand held)
                        self._expect_placed(tgt, T_rest, staging=it.staging if own
                                            else not self.task.accepts_as_it_lies(there), carried=False)
                    return True
                except ProtectiveStopError as e:
                    self._unlock_after_refused("put_down_stopped", e, kind="fault")
                    hit.append(tgt.T_base_obj[:3, 3])
                    self._back_off()
                    if not self._holding():
                        return False
        tcp = self.arm.tcp_pose()[:3, 3]
        (x0, y0), (x1, y1) = self.robot.cell.spec.counter_extent_xy
        if x0 <= tcp[0] <= x1 and y0 <= tcp[1] <= y1:
            self._log("note", "no way to put the held object down; opening over the cell", tcp=tcp)
            self.belief.record_dropped(tcp, it.staged, it.obj.cls if it.obj is not None else None,
                                       self._held_points())
            self._cmd("gripper.open", release=True)
            self.gripper.open()
            return False
        self._log("fault", "holding_unsafe", message="the gripper holds an object away from the cell; not opening",
                  tcp=tcp)
        return False

    def _make_safe(self) -> bool:
        """Give up safely: anything held put down, the arm at home, the gripper open. True if achieved."""
        try:
            self._restore_devices(self.failure or Failure("give_up", "", self.state))
            if self._holding():
                self._put_down_held()
            self._back_out()
            self._move_joints(np.asarray(self.robot.config.robot.home, float), "home (safe pose)")
            self._cmd("gripper.open")
            self.gripper.open()
            self._log("result", "safe", q=self.arm.joint_positions())
            return True
        except Stopped:
            return False
        except Exception as e:  # noqa: BLE001 - record why the arm could not be made safe
            self._log("fault", "make_safe_failed", error=f"{type(e).__name__}: {e}")
            return False
