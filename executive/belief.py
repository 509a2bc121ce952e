"""What the robot believes during a task run, in one place, changed only through the named operations below.

- **poses**: the latest perception (provenance: "perceived"); what the robot put down is kept as **placed**
  records (provenance: "placed", or "staged" for items set down on the counter to be grasped again, "seen" once
  a view has replaced a staged record's pose: an item settles where it is let go, so a staged record is looked at
  before its regrasp);
- **the map**: the latest perception's map points, plus **contact marks** (where a stopped motion met something
  no model shows) and **keep-outs** (where a fallen item may lie unseen), which plans keep clear of;
- **pending**: the models the task still has to move (from the latest perception);
- **released**: the placement executed but not verified yet;
- **attempts** per item (executed grasps, planning failures since the scene last changed, slides), and what
  blocked what (the item tried next);
- the **scene epoch**: how often the scene changed (placements, slides); planning failures and contact marks in
  the sink are per epoch.

"The same item" is defined once (:func:`same_item`, world/same_item.py): the same class within SAME_ITEM_RADIUS.

The tasks read a belief (``Task.targets(obj, belief)``: ``placed``, ``pending``) and never change it; the runner
and its recovery change it through these operations only.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from kitchenbot.executive import machine as M
from kitchenbot.executive.left_reason import Reason
from kitchenbot.executive.waiting import Waits
from kitchenbot.perception.types import ObjectPose, View
from kitchenbot.planning.types import MapPoints
from kitchenbot.tasks.base import Placed
from kitchenbot.world.same_item import SAME_ITEM_RADIUS, same_item  # noqa: F401 (SAME_ITEM_RADIUS: re-exported)


@dataclass
class Attempts:
    """What happened to one item: executed grasp attempts, and planning failures since the scene last changed
    (an item under or behind others is unplannable until they are gone, so those failures are forgotten after
    each change of the scene)."""
    cls: str
    pos: np.ndarray
    count: int = 0
    reasons: list = field(default_factory=list)  # every failure's kind, oldest first (a strategy reads the history)
    # its latest failure with what it named: the reason a run that gives up reports (executive/left_reason.py)
    latest: Reason | None = None
    plan_failures: int = 0
    plan_epoch: int = -1
    slides: int = 0
    missed: list = field(default_factory=list)  # grasps (spec names) that closed on nothing here: not tried again
    # a grip of it closed across more than its own rim (a nest of plates seen as one): slid before it is gripped
    # again (executive/strategies.py, SlideTopOfNest); cleared by the slide
    nest_felt: bool = False
    # (T_base_press, direction) of its slides that stopped at the press or on the way: not planned again (the same
    # belief plans the same slide; planning/slide.py `repeats`); cleared when it slides
    stopped_slides: list = field(default_factory=list)
    set_aside_plans: int = 0  # plans to set it aside on the counter (it had no target and blocked another item)
    no_room: tuple | None = None  # (scene epoch, items keeping room) when its task last had no target for it
    # directions (unit, base frame) of its lifts that a protective stop cut short, the item let go where it was
    # taken: its next plans lift it otherwise (Planner.plan_pick's `stopped_lifts`); cleared when it moves (a slide)
    stopped_lifts: list = field(default_factory=list)

    def plan_failed(self, epoch: int) -> None:
        if self.plan_epoch != epoch:
            self.plan_epoch, self.plan_failures = epoch, 0
        self.plan_failures += 1

    def exhausted(self, epoch: int) -> bool:
        return self.count >= M.MAX_ATTEMPTS_PER_OBJECT or (
            self.plan_epoch == epoch and self.plan_failures >= M.MAX_PLAN_FAILURES_PER_SCENE)


@dataclass
class Released:
    """A placement executed but not yet verified."""

    obj: ObjectPose
    target: Any
    T_base_obj: np.ndarray
    target_view: View | None
    staging: bool = False  # set down upright on the counter to be grasped again (regrasp)
    staged: Placed | None = None  # the record this item was picked up from (a staged item)
    near_before: int = 1  # same-class items within gone_radius of it in the scan it was picked from
    # the gripper held it from the lift to its release at the target (every motion poll said holding): it left
    # where it was picked, whatever the sink shows there (executive/verify.py, where_it_went)
    carried: bool = False


@dataclass(eq=False)
class SinkDrop:
    """An item that left the gripper above the sink, not yet seen back in it (Belief.await_in_sink)."""
    cls: str
    site: np.ndarray  # where the tool was
    expect: int  # items of its class the sink holds if it fell back in (less those taken out since)
    sink_lo_hi: tuple  # the basin (Cell.sink_interior)
    looked: bool = False  # the done check looked where it fell
    look_at: np.ndarray | None = None  # where the item was when it fell (None: `site`)

    @property
    def where(self) -> np.ndarray:
        """Where to look for it: where the item was when it fell, else where the tool was."""
        return self.site if self.look_at is None else self.look_at

    def centred_over_basin(self) -> bool:
        """Whether where it was (`where`) lies over the basin in x-y."""
        lo, hi = self.sink_lo_hi
        xy = self.where[:2]
        return bool(np.all(xy >= np.asarray(lo)[:2]) and np.all(xy <= np.asarray(hi)[:2]))

    def holds(self, p: ObjectPose) -> bool:
        """`p` lies in the sink by its x-y (up to its rim, as the task counts it)."""
        lo, hi = self.sink_lo_hi
        xy = np.asarray(p.T_base_obj, float)[:2, 3]
        return bool(np.all(xy >= np.asarray(lo)[:2]) and np.all(xy <= np.asarray(hi)[:2]))


@dataclass
class BeliefMap:
    """The map plans keep clear of: the latest perception's points, contact marks (where a stopped motion met
    something no model shows; a keep-out under a drop site where a fallen item may lie unseen) with the scene
    epoch each was made in, and a temporary keep-out."""

    base: np.ndarray | None = None
    contact_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    contact_epochs: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    keep_out: np.ndarray | None = None
    _cache: tuple | None = None

    @property
    def points(self) -> np.ndarray | None:
        """All of it as one array (the same object while nothing changes: the planner caches by identity)."""
        if self._cache is None:
            parts = [p for p in (self.base, self.contact_points, self.keep_out) if p is not None and len(p)]
            # the marks (contacts, keep-out) last, flagged: no perceived object explains them away (MapPoints)
            marks = sum(len(p) for p in (self.contact_points, self.keep_out) if p is not None)
            pts = np.vstack(parts) if len(parts) > 1 else parts[0] if parts else self.base
            self._cache = (MapPoints.of(pts, marks) if marks else pts,)
        return self._cache[0]

    def set_base(self, points: np.ndarray | None) -> None:
        self.base, self._cache = points, None

    @property
    def marks(self) -> np.ndarray:
        """The points no perception put there: contact marks and the keep-out, as one (N, 3) array."""
        parts = [p for p in (self.contact_points, self.keep_out) if p is not None and len(p)]
        return np.vstack(parts) if parts else np.zeros((0, 3))

    def add_contacts(self, pts: np.ndarray, epoch: int) -> None:
        self.contact_points = np.vstack([self.contact_points, pts])
        self.contact_epochs = np.concatenate([self.contact_epochs, np.full(len(pts), epoch)])
        self._cache = None

    def keep_contacts(self, keep: np.ndarray) -> None:
        self.contact_points, self.contact_epochs = self.contact_points[keep], self.contact_epochs[keep]
        self._cache = None

    def set_keep_out(self, pts: np.ndarray | None) -> None:
        self.keep_out, self._cache = pts, None


@dataclass
class Belief:
    poses: list[ObjectPose] = field(default_factory=list)
    map: BeliefMap = field(default_factory=BeliefMap)
    scene_epoch: int = 0
    placed: list[Placed] = field(default_factory=list)  # what the robot put down (staged items included)
    staged: list[Placed] = field(default_factory=list)  # of those, set down on the counter for a regrasp
    # what the task still has to move: (ObjectPose or None, ObjectModel) pairs; `pending` = the models of those
    # that can still come out (room at the targets is kept for those only)
    pending_items: list = field(default_factory=list)
    released: Released | None = None
    attempts: list[Attempts] = field(default_factory=list)
    unverified: list[str] = field(default_factory=list)  # classes gone from the sink but not seen at their target
    unplannable: list[ObjectPose] = field(default_factory=list)  # failed to plan with the current poses
    blocked_by: dict = field(default_factory=dict)  # instance id -> the instance id the planner said blocks it
    prefer_instance: int | None = None  # the item to try next (it blocks the last one tried)
    waits: Waits = field(default_factory=Waits)  # items pinned by what lies on them: not planned until that moves
    drop_site: np.ndarray | None = None  # where the tool was when the last item slipped out
    # the item that slipped out last as it was held when it left the gripper (its model's points in the base frame;
    # None where the grasp is not known): where it fell is judged by it, not by the tool point (take_dropped_held)
    dropped_held: np.ndarray | None = None
    unseen_placement: Placed | None = None  # the record of a placement its check did not see
    dropped: int = 0  # items that left the gripper on the way
    # each drop as it stands: {"cls", "xyz" (where the tool was), "found"}; the ones not found are named at the end
    drops: list = field(default_factory=list)
    # drops over the sink not yet seen back in it (SinkDrop): a scan confirms each, or the done check looks for it
    sink_drops: list = field(default_factory=list)
    drops_found: int = 0  # of those, seen again: fallen back into the sink (the scans see it) or found where it fell
    first_total: int | None = None  # the task's items in the first perception
    seen_staged: set = field(default_factory=set)  # instance ids of staged records whose pose a view gave
    # instance ids of staged records a grasp missed on since they were last looked at: the record is off by more
    # than a grasp tolerates, so the next look does not keep it for agreeing with the view within a fit's error
    missed_staged: set = field(default_factory=set)
    # found-drop records (instance id -> the drop's entry in `drops`): a look at the drop site put the item there;
    # a later look that shows the spot empty disproves it (Belief.disprove_found_drop)
    found_drops: dict = field(default_factory=dict)
    # where a drop-site look put a dropped item that a later look showed was not there: a look at the drop site
    # does not take an item perceived there for it again (RecoveryActions._search_drop_site)
    disproved_spots: list = field(default_factory=list)
    # contact marks that stand for an item that fell where no view recognised it: (its class, those marks); they go
    # once a perception recognises an item of that class among them (Belief.seen_where_marked)
    unseen_items: list = field(default_factory=list)
    _next_id: int = 0

    # ---- what is still to do ------------------------------------------------------------------------------------
    @property
    def pending(self) -> list:
        """The models of what the task still has to move and can still come out: an item that has proven stuck in
        this scene (Belief.stuck: every plan for it failed since the scene last changed, or its grasps are used
        up) keeps no room at the targets, so what can come out gets it (a crowded sink: the lower rack's last
        room was kept for plates whose grasps all collide, and the bowls that could come out had no slot). The
        room comes back when the scene changes (the item is tried again)."""
        return [m for p, m in self.pending_items if p is None or not self.stuck(p)]

    @pending.setter
    def pending(self, models: list) -> None:
        """Models alone (no poses: room is kept for each)."""
        self.pending_items = [(None, m) for m in models]

    def stuck(self, obj: ObjectPose) -> bool:
        """`obj` cannot come out in this scene: its grasp attempts are used up, or every plan for it failed since
        the scene last changed (Attempts.exhausted); an item that only waits for room (no_room) is not stuck."""
        t = self.attempts_for(obj)
        return t is not None and t.exhausted(self.scene_epoch)

    # ---- perception and the map ------------------------------------------------------------------------------
    def perceived(self, poses: list[ObjectPose], map_points: np.ndarray | None, pending: list, sink_lo_hi) -> None:
        """A new perception: its poses and map; contact marks in the sink made before the last change of the
        scene go (the scan saw the sink anew); `pending` = the models the task still has to move."""
        self.poses = list(poses)
        self.unplannable = []
        self.pending_items = _items(pending)
        self.map.set_base(map_points)
        lo, hi = sink_lo_hi
        c, e = self.map.contact_points, self.map.contact_epochs
        old = np.all(c[:, :2] >= lo[:2], axis=1) & np.all(c[:, :2] <= hi[:2], axis=1) & (e < self.scene_epoch)
        self.map.keep_contacts(~old)
        self.seen_where_marked(poses)
        self._sink_drops_seen(poses)

    def picked_away(self, obj: ObjectPose, pending: list) -> None:
        """The perceived item `obj` was picked and placed, and no new perception followed (the placement view
        settled it, executive/verification.py): the other poses and the map stay as perceived; `pending` = the
        models the task still has to move. What failed to plan with the old scene is tried again."""
        self.poses = [p for p in self.poses if p is not obj]
        self.unplannable = []
        self.pending_items = _items(pending)

    def counter_item_moved(self, staged: Placed, pending) -> None:
        """The staged item `staged` was picked up from the counter and placed, and no new perception followed: the
        sink's poses and map stay as perceived, less a perceived item where it was staged (that was it: a
        perception that sees the counter too); `pending(poses)` = the models the task still has to move. What
        failed to plan with the old scene is tried again (the counter and its target changed)."""
        xyz = np.asarray(staged.T_base_obj, float)[:3, 3]
        self.poses = [p for p in self.poses if not same_item(p.cls, p.T_base_obj[:3, 3], staged.cls, xyz)]
        self.unplannable = []
        self.pending_items = _items(pending(self.poses))

    def region_perceived(self, poses: list[ObjectPose], map_points: np.ndarray | None, pending: list) -> None:
        """One region was perceived again (perception/region.py) and merged with the rest, which stays as
        perceived: `poses` and `map_points` are the merged ones. Contact marks stay (the sink was not seen
        anew); what failed to plan with the old scene is tried again."""
        self.poses = list(poses)
        self.unplannable = []
        self.pending_items = _items(pending)
        self.map.set_base(map_points)
        self.seen_where_marked(poses)

    # How far (m) outside the box of an unseen item's marks a recognised item of its class may have its centre and
    # still be taken for it (the marks are 2 cm voxels of its surface as a view saw it, or the keep-out around
    # where it fell)
    UNSEEN_REACH = 0.05

    def seen_where_marked(self, poses: list[ObjectPose]) -> int:
        """Marks that stood for an item fallen where no view recognised it (`mark_contact(..., unseen_cls=...)`)
        go once `poses` (a perception) hold an item of its class among them: the item is recognised there now, its
        model stands for it, and the marks of it would cage it (no object explains marks: every grasp of it, its
        lift, met its own marks, and it stayed there). Returns how many marks went."""
        gone = 0
        keep = []
        for cls, pts in self.unseen_items:
            lo, hi = pts.min(axis=0) - self.UNSEEN_REACH, pts.max(axis=0) + self.UNSEEN_REACH
            if any(p.cls == cls and np.all(p.T_base_obj[:3, 3] >= lo) and np.all(p.T_base_obj[:3, 3] <= hi)
                   for p in poses):
                gone += self.drop_contacts(near=pts, radius=1e-6)
            else:
                keep.append((cls, pts))
        self.unseen_items = keep
        return gone

    @property
    def map_points(self) -> np.ndarray | None:
        """The map plans keep clear of (BeliefMap.points)."""
        return self.map.points

    @property
    def map_base(self) -> np.ndarray | None:
        return self.map.base

    @property
    def contact_points(self) -> np.ndarray:
        return self.map.contact_points

    @property
    def marks(self) -> np.ndarray:
        return self.map.marks

    def set_map_base(self, points: np.ndarray | None) -> None:
        """Replace the perceived map points (e.g. less those an item picked away explained)."""
        self.map.set_base(points)

    def mark_contact(self, pts: np.ndarray | None, unseen_cls: str | None = None) -> int:
        """Keep `pts` as map points no object explains (a contact sliver, a keep-out under a drop site); marks in
        the sink last until the scene has changed and the sink been perceived again. `unseen_cls`: they stand for
        a fallen item of that class that no view recognised (they go when one is: seen_where_marked). Returns how
        many."""
        if pts is None or not len(pts):
            return 0
        pts = np.asarray(pts, float).reshape(-1, 3)
        self.map.add_contacts(pts, self.scene_epoch)
        if unseen_cls is not None:
            self.unseen_items.append((unseen_cls, pts.copy()))
        return len(pts)

    def drop_contacts(self, near: np.ndarray | None = None, radius: float = 0.0, where: np.ndarray | None = None) -> int:
        """Forget the contact marks within `radius` of any of the points `near` (N, 3), or those `where` (a mask
        over contact_points) says, every one without either: they block a move the arm must make. Returns how
        many went."""
        c = self.map.contact_points
        if where is not None:
            gone = np.asarray(where, bool).reshape(-1)
        elif near is None:
            gone = np.ones(len(c), bool)
        else:
            from scipy.spatial import cKDTree

            d, _ = cKDTree(np.asarray(near, float).reshape(-1, 3)).query(c, distance_upper_bound=radius) \
                if len(c) else (np.zeros(0), None)
            gone = np.isfinite(d)
        self.map.keep_contacts(~gone)
        return int(gone.sum())

    @contextlib.contextmanager
    def keeping_out(self, pts: np.ndarray | None):
        """Within the block, `pts` are part of the map too."""
        self.map.set_keep_out(pts)
        try:
            yield
        finally:
            self.map.set_keep_out(None)

    # ---- items -------------------------------------------------------------------------------------------------
    def attempts_for(self, obj: ObjectPose, create: bool = False) -> Attempts | None:
        """The attempts on the item at `obj` (the same item: same_item), created when asked."""
        for t in self.attempts:
            if same_item(t.cls, t.pos, obj.cls, obj.T_base_obj[:3, 3]):
                return t
        if create:
            t = Attempts(obj.cls, obj.T_base_obj[:3, 3].copy())
            self.attempts.append(t)
            return t
        return None

    def exhausted(self, obj: ObjectPose) -> bool:
        """No attempts left on `obj`, every plan for it failed in this scene, or it waits for room (no_room)."""
        t = self.attempts_for(obj)
        return t is not None and (t.exhausted(self.scene_epoch) or t.no_room == self._room_key())

    def _room_key(self) -> tuple:
        """What the room at the targets depends on: the scene (what is placed) and what keeps room there."""
        return self.scene_epoch, len(self.pending)

    def no_room(self, obj: ObjectPose, reason: str) -> None:
        """The task has no target for `obj` (its targets are full, or their room is kept for items still to come):
        it waits until that room changes, a placement (the scene changes) or an item keeping room that proves
        stuck (Belief.pending); then it is tried again. Not given up: the room kept for plates whose grasps
        all collide is room it may get."""
        t = self.attempts_for(obj, create=True)
        t.no_room = self._room_key()
        if reason not in t.reasons:
            t.reasons.append(reason)
        t.latest = Reason(reason)

    def record_attempt(self, obj: ObjectPose) -> None:
        """A grasp of `obj` is executed."""
        self.attempts_for(obj, create=True).count += 1

    def record_plan_failure(self, obj: ObjectPose, reason: str, strategy: str = "",
                            named: list[ObjectPose] | tuple = ()) -> None:
        """No plan for `obj` with the current scene: skipped until the scene changes. `strategy`: the one whose plan
        failed last; `named`: the items the failure named lying on `obj` or in its way (its reported reason)."""
        t = self.attempts_for(obj, create=True)
        t.plan_failed(self.scene_epoch)
        t.reasons.append(reason)
        t.latest = Reason.of(reason, strategy, named)

    def record_failure(self, obj: ObjectPose, reason: str) -> None:
        """An executed attempt on `obj` failed (it is counted when executed)."""
        t = self.attempts_for(obj, create=True)
        t.reasons.append(reason)
        t.latest = Reason(reason)

    def why_left(self, obj: ObjectPose) -> str:
        """Why `obj` is still where it is, for a run's last message: its latest failure with the items it named that
        are still where they were named (perceived, or put down there: scene_objects; executive/left_reason.py);
        "" when nothing failed on it."""
        t = self.attempts_for(obj)
        if t is None:
            return ""
        if t.latest is None:  # attempts counted, no failure recorded
            return ", ".join(sorted(set(t.reasons)))
        return t.latest.describe(self.scene_objects(), itself=obj)

    def record_missed_grasp(self, obj: ObjectPose, grasp: str) -> None:
        """The grasp `grasp` (its spec name) of `obj` closed on nothing: the item is not where that grasp expects
        it, and the same poses plan the same grasp again; later picks of the item avoid it."""
        t = self.attempts_for(obj, create=True)
        if grasp not in t.missed:
            t.missed.append(grasp)

    def record_stopped_lift(self, obj: ObjectPose, direction: np.ndarray) -> None:
        """A lift of `obj` moving along `direction` (base frame) was cut short by a protective stop, and the item was
        let go where it was taken: lifted that way again from there it meets the same thing. Its later plans lift
        it in other directions (Attempts.stopped_lifts)."""
        d = np.asarray(direction, float).reshape(3)
        n = float(np.linalg.norm(d))
        if n < 1e-9:
            raise ValueError("record_stopped_lift: the direction has no length")
        self.attempts_for(obj, create=True).stopped_lifts.append(d / n)

    def stopped_lifts(self, obj: ObjectPose) -> list:
        """The directions of `obj`'s lifts a protective stop cut short where it lies (record_stopped_lift)."""
        t = self.attempts_for(obj)
        return list(t.stopped_lifts) if t is not None else []

    def record_nest_felt(self, obj: ObjectPose) -> None:
        """A grip of `obj` (a plate) closed wider than planned by about the pitch of a nest: its pads took in the
        rim of the plate nested under it too (the pair is seen as one plate). Another pinch there closes across
        both rims again; the top one is slid off the other first (SlideTopOfNest)."""
        self.attempts_for(obj, create=True).nest_felt = True

    def nest_felt(self, obj: ObjectPose) -> bool:
        """Whether a grip of `obj` closed across two nested rims since it was last slid (record_nest_felt)."""
        t = self.attempts_for(obj)
        return t is not None and t.nest_felt

    def doubt(self, obj: ObjectPose) -> None:
        """A grasp of `obj` missed: its pose is in doubt. Its verification's parts are dropped, so the next
        perception does not keep it unchecked where the map around it did not change (Perceiver._kept: a grasp
        that closes on air changes no map point, and a pose 4 cm off was kept scan after scan while every grasp
        of its ring missed); it is tracked and verified again, or estimated afresh."""
        obj.checks.clear()

    def record_taken(self, obj: ObjectPose) -> None:
        """`obj` was taken from where it lay (its placement verified): the attempts recorded there were on it, not
        on what is seen there now (the plate it was nested on, which it hid: seen as one plate, the grasps that
        failed on the pair and the attempts they used are not that plate's)."""
        t = self.attempts_for(obj)
        self.attempts = [a for a in self.attempts if a is not t]  # by identity: == compares their position arrays
        for sd in self.sink_drops:  # one item of its class less in the sink
            if sd.cls == obj.cls and sd.holds(obj):
                sd.expect -= 1
        self._sink_drops_seen([])  # all of its class there before are out: the one that fell back in was among them

    def give_up_on(self, obj: ObjectPose, reason: str | None = None) -> None:
        """No attempts left for `obj` (e.g. its task has no target for it)."""
        t = self.attempts_for(obj, create=True)
        t.count = M.MAX_ATTEMPTS_PER_OBJECT
        if reason:
            t.reasons.append(reason)
            t.latest = Reason(reason)

    def may_set_aside(self, obj: ObjectPose) -> bool:
        """Whether `obj` (no target for it, named as blocking another item) may still be planned to be set aside:
        bounded per item (M.MAX_SET_ASIDE_PLANS), whatever its attempts (an item with no target was given up)."""
        t = self.attempts_for(obj)
        return t is None or t.set_aside_plans < M.MAX_SET_ASIDE_PLANS

    def record_set_aside(self, obj: ObjectPose) -> None:
        """A plan to set `obj` aside on the counter starts."""
        self.attempts_for(obj, create=True).set_aside_plans += 1

    def record_slide(self, obj: ObjectPose) -> Attempts:
        """A slide of `obj` starts (counted whether or not it completes: slides are bounded per item)."""
        t = self.attempts_for(obj, create=True)
        t.slides += 1
        return t

    def record_slide_stopped(self, t: Attempts, T_base_press: np.ndarray | None, direction: np.ndarray) -> None:
        """A slide of the item (pressing at `T_base_press`, along `direction`) stopped on the press or the way."""
        if T_base_press is not None:
            t.stopped_slides.append((np.array(T_base_press, float), np.array(direction, float)))

    def stopped_slides(self, obj: ObjectPose) -> list:
        """(T_base_press, direction) of the slides of `obj` that stopped since it last slid."""
        t = self.attempts_for(obj)
        return list(t.stopped_slides) if t is not None else []

    def record_slid(self, t: Attempts, T_after: np.ndarray) -> None:
        """The item slid to T_after: the same item over there; the scene changed."""
        t.pos = T_after[:3, 3].copy()
        t.stopped_slides = []
        if t.nest_felt:  # the top plate slid off the one its grips took in too: those grips say nothing of it alone
            t.nest_felt, t.missed = False, []
        t.stopped_lifts = []  # lifted from where it lies now, it meets other things
        self.scene_changed()

    def record_blocked(self, obj: ObjectPose, blocker: int | None) -> None:
        """The planner named `blocker` (an instance id) as lying on `obj` or in its way: that one is tried next."""
        if blocker is not None:
            self.blocked_by[obj.instance_id] = blocker
        self.prefer_instance = blocker

    def record_pinned(self, obj: ObjectPose, on_it: list[ObjectPose]) -> None:
        """`obj` cannot be lifted while `on_it` lie on it as they do (its pick failed pinned by them): it is not
        planned again until one of them (or it) moves, or marks appear around it (executive/waiting.py)."""
        self.waits.record(obj, on_it, self.map.marks)
        t = self.attempts_for(obj, create=True)
        why = self.waits.reason(obj)
        if why not in t.reasons:
            t.reasons.append(why)
        # the failure just recorded (record_plan_failure) is the one that found it pinned: it names what pins it
        t.latest = Reason.of(t.latest.kind if t.latest else "", t.latest.strategy if t.latest else "", on_it, True)

    def take_preferred(self) -> int | None:
        """The item to try next (once)."""
        p, self.prefer_instance = self.prefer_instance, None
        return p

    def scene_changed(self) -> None:
        self.scene_epoch += 1

    def record_unplannable(self, obj: ObjectPose) -> None:
        """No plan for `obj` with the current poses: the others first until the next perception."""
        self.unplannable.append(obj)

    def record_first_total(self, n: int) -> None:
        if self.first_total is None:
            self.first_total = n

    # ---- what left the gripper -----------------------------------------------------------------------------------
    def release(self, rel: Released) -> None:
        """An item was set down: the next perception verifies it."""
        self.released = rel

    def take_released(self) -> Released | None:
        rel, self.released = self.released, None
        return rel

    def record_dropped(self, where: np.ndarray, staged: Placed | None = None, cls: str | None = None,
                       held: np.ndarray | None = None) -> None:
        """An item left the gripper on the way (slipped, let go over the cell) about above `where` (the tool point).
        `staged`: the record it was picked up from when it was staged; it is not there any more (it fell near
        `where`, and the look there records it anew where it is found). Kept, it was picked up "again" from an
        empty spot until its attempts ran out, and the run ended with it "left on the counter". `held`: the item's
        model points (base frame) as it was held when it left the gripper, where the grasp is known: it falls
        from there, which for a plate held by its rim is 10 cm and more from the tool point."""
        self.dropped += 1
        self.drop_site = np.array(where, float)
        self.dropped_held = None if held is None else np.asarray(held, float).reshape(-1, 3)
        self.drops.append({"cls": cls, "xyz": np.round(np.asarray(where, float), 3).tolist(), "found": False,
                           "held": self.dropped_held})
        if staged is not None:
            self.unplace(staged)

    def dropped_at_target(self) -> None:
        """The item that dropped last left the gripper while being lowered onto its target: it is verified there as
        a placement is, not looked for as a drop (nor counted lost)."""
        self.dropped = max(self.dropped - 1, 0)
        self.drop_site = None
        self.dropped_held = None
        if self.drops:
            self.drops.pop()

    def record_drop_found(self) -> dict | None:
        """The item that dropped last is not lost: it fell back into the sink or was found where it fell. Returns
        its entry in `drops` (None if there is none)."""
        self.drops_found = min(self.drops_found + 1, self.dropped)
        d = next((d for d in reversed(self.drops) if not d["found"]), None)
        if d is not None:
            d["found"] = True
        return d

    def record_found_drop(self, p: Placed, drop: dict | None) -> None:
        """`p` is the record a drop-site look made of the dropped item `drop` (an entry of `drops`)."""
        if drop is not None:
            self.found_drops[p.instance_id] = drop

    def disprove_found_drop(self, p: Placed) -> bool:
        """The found-drop record `p` is not where the item lies (a later look showed its spot without it): the
        record goes, the drop is lost again (looked for anew: `drop_site`), and a look at the drop site does not
        take an item perceived at `p`'s spot for it (`disproved_spots`). False if `p` is no found-drop record."""
        drop = self.found_drops.pop(p.instance_id, None)
        if drop is None:
            return False
        self.unplace(p)
        self.seen_staged.discard(p.instance_id)
        self.missed_staged.discard(p.instance_id)
        self.disproved_spots.append(np.asarray(p.T_base_obj, float)[:3, 3].copy())
        if drop["found"]:
            drop["found"] = False
            self.drops_found = max(self.drops_found - 1, 0)
        self.drop_site = np.asarray(drop["xyz"], float)
        self.dropped_held = drop.get("held")
        return True

    def await_in_sink(self, cls: str, site: np.ndarray, expect: int, sink_lo_hi,
                      look_at: np.ndarray | None = None) -> SinkDrop:
        """The item that dropped last left the gripper above the sink: it fell back into it, or came to rest where
        the sink scans do not look (on the rim, over the edge). It counts as seen again once a perception of the
        sink holds `expect` items of its class (as many as before it was picked, less those taken out since),
        not before (Belief.perceived, record_taken). `site`: where the tool was (its drop's "xyz"); `look_at`:
        where the done check looks for it (where the item was; `site` if not given)."""
        sd = SinkDrop(cls, np.array(site, float), expect, sink_lo_hi,
                      look_at=None if look_at is None else np.array(look_at, float))
        self.sink_drops.append(sd)
        return sd

    def stop_awaiting(self, sd: SinkDrop) -> None:
        """The drop `sd` was found out of the sink (a look where it fell): no scan need see it back in."""
        if sd in self.sink_drops:
            self.sink_drops.remove(sd)

    def _sink_drops_seen(self, poses: list[ObjectPose]) -> None:
        for sd in list(self.sink_drops):
            if sd.expect <= 0 or sum(1 for p in poses if p.cls == sd.cls and sd.holds(p)) >= sd.expect:
                self.sink_drops.remove(sd)
                self._drop_seen(sd)

    def _drop_seen(self, sd: "SinkDrop") -> dict | None:
        d = next((d for d in self.drops if not d["found"] and d["cls"] == sd.cls
                  and np.allclose(d["xyz"], np.round(sd.site, 3))), None)
        if d is not None:
            d["found"] = True
            self.drops_found = min(self.drops_found + 1, self.dropped)
        return d

    def found_sink_drop(self, sd: "SinkDrop") -> dict | None:
        """The drop over the sink was found where the scans do not look (the done check's look at it); its entry
        in `drops` (None if none was open)."""
        if sd in self.sink_drops:
            self.sink_drops.remove(sd)
        return self._drop_seen(sd)

    def lost_drops(self) -> list[dict]:
        """The drops not seen again: each {"cls", "xyz" (where it was last held)}."""
        return [d for d in self.drops if not d["found"]]

    def unaccounted(self, done: int) -> tuple[int, int]:
        """First-scan items neither in the sink nor placed, with `done` placed: (lost, never there). Every item
        dropped on the way and not seen again is lost, whatever the first scan counted (it may have seen fewer
        items than there were: a stack seen as one; capped by it, a plate that fell to the floor went unreported);
        a drop seen again (found where it fell, or back in the sink) is not lost. More first-scan items missing
        than that were never there (a duplicate detection that no later scan confirmed)."""
        missing = max((self.first_total or 0) - done - len(self.unverified) - len(self.staged), 0)
        lost = len(self.lost_drops())
        return lost, max(missing - lost, 0)

    def record_unseen(self, obj: ObjectPose, record: Placed, site: np.ndarray) -> None:
        """A placement was not seen at its target: kept there as an obstacle (`record`), counted as unverified,
        and looked for around `site` (it may have tipped or fallen off)."""
        self.unverified.append(obj.cls)
        self.unseen_placement = record
        self.drop_site = np.array(site, float)
        self.dropped_held = None

    def take_drop_site(self) -> tuple[np.ndarray | None, Placed | None]:
        """(where to look for a dropped item, the record of the unseen placement it may be), once."""
        out = (self.drop_site, self.unseen_placement)
        self.drop_site, self.unseen_placement = None, None
        return out

    def take_dropped_held(self) -> np.ndarray | None:
        """The dropped item's model points as it was held when it fell (record_dropped), once; None if unknown."""
        out, self.dropped_held = self.dropped_held, None
        return out

    def found_unseen(self, record: Placed) -> None:
        """The item not seen at its target was found near it: its record there goes; no longer unverified."""
        self.unplace(record)
        if record.cls in self.unverified:
            self.unverified.remove(record.cls)

    def record_found(self, p: Placed) -> None:
        """A dropped item found outside its target: it waits there to be picked up again, as a staged one (its pose
        is what the view showed)."""
        self.staged.append(p)
        self.seen_staged.add(p.instance_id)

    # ---- what the robot put down ----------------------------------------------------------------------------
    def record_placed(self, task, obj: ObjectPose, target, T_base_obj: np.ndarray) -> Placed:
        """`obj` rests at T_base_obj at `target` (the task's record of it: footprint, height)."""
        p = task.placed_record(obj, target, T_base_obj, 10_000 + self._next_id)
        self._next_id += 1
        self.placed.append(p)
        return p

    def record_staged(self, p: Placed) -> None:
        """The placed record `p` is an item set down on the counter to be grasped again; an earlier item's
        attempts at that spot are not this one's."""
        self.attempts = [t for t in self.attempts
                         if not same_item(t.cls, t.pos, p.cls, p.T_base_obj[:3, 3])]
        self.staged.append(p)

    def needs_look(self, p: Placed) -> bool:
        """Whether the staged record `p` is only where it was put down: no view has shown where it settled."""
        return any(q.instance_id == p.instance_id for q in self.staged) and p.instance_id not in self.seen_staged

    def look_again(self, p: Placed) -> None:
        """A grasp of the staged item `p` closed on nothing or on something else: it does not lie as its record
        has it (the view's pose was off, or the pads pushed it); the next selection looks at it again, and that
        look does not keep the record for agreeing with the view within a pose fit's error (missed_on): the miss
        says it is off by more than the grasp tolerates. Without that, the same record planned the next grasp,
        which missed too, until its attempts ran out."""
        self.seen_staged.discard(p.instance_id)
        self.missed_staged.add(p.instance_id)

    def missed_on(self, p: Placed) -> bool:
        """Whether a grasp planned on the staged record `p` missed since a view was last taken of it."""
        return p.instance_id in self.missed_staged

    def looked_at(self, task, p: Placed, T_seen: np.ndarray | None) -> Placed:
        """A view was taken of the staged item `p`: it lies at `T_seen` (its record moves there, the same instance,
        footprint anew from `task`), or None when the view did not show it (the record stays). Not looked at
        again either way (until a grasp planned on it misses: look_again)."""
        self.seen_staged.add(p.instance_id)
        self.missed_staged.discard(p.instance_id)
        if T_seen is None:
            return p
        q = task.placed_record(as_pose(p), p.target, T_seen, p.instance_id)
        self.placed = [q if r.instance_id == p.instance_id else r for r in self.placed]
        self.staged = [q if r.instance_id == p.instance_id else r for r in self.staged]
        return q

    def unplace(self, p: Placed) -> None:
        """It left its place (a staged item picked up again, a placement found elsewhere)."""
        self.placed = [q for q in self.placed if q.instance_id != p.instance_id]
        self.staged = [q for q in self.staged if q.instance_id != p.instance_id]

    def obstacles(self) -> list[ObjectPose]:
        """Placed items as object poses (for the planner's collision world)."""
        return [as_pose(p) for p in self.placed]

    def scene_objects(self) -> list[ObjectPose]:
        """Perceived items plus what the robot put down; a perceived item where one was put down is that one;
        an item released but not verified yet is at its target, no longer where it was seen."""
        placed = self.obstacles()
        rel = self.released
        if rel is not None:
            placed.append(ObjectPose(rel.obj.obj_id, rel.obj.cls, rel.T_base_obj, 1.0, instance_id=99_999))
        seen = [p for p in self.poses if not (rel is not None and p is rel.obj)
                and not any(same_item(p.cls, p.T_base_obj[:3, 3], o.cls, o.T_base_obj[:3, 3]) for o in placed)]
        return seen + placed

    def provenance(self, obj: ObjectPose) -> str:
        """Where the belief's pose of `obj` comes from: "staged" / "placed" (a record of what the robot put down;
        "staged, seen": a staged item's record a view has replaced),
        "released" (put down, not verified yet), "perceived" (the latest perception), or "unknown"."""
        if any(p.instance_id == obj.instance_id for p in self.staged):
            return "staged, seen" if obj.instance_id in self.seen_staged else "staged"
        if any(p.instance_id == obj.instance_id for p in self.placed):
            return "placed"
        if obj.instance_id == 99_999 or (self.released is not None and obj is self.released.obj):
            return "released"
        return "perceived" if any(p is obj for p in self.poses) else "unknown"

    def staged_waiting(self) -> list[Placed]:
        """Staged items with attempts left."""
        return [st for st in self.staged if not self.exhausted(as_pose(st))]


def as_pose(p: Placed) -> ObjectPose:
    """A placed record as the object pose the planner and the tasks take."""
    return ObjectPose(p.obj_id, p.cls, p.T_base_obj, 1.0, instance_id=p.instance_id)


def _items(pending: list) -> list:
    """(pose, model) pairs from what a task says is pending (Task.pending_items, or models alone: room kept for
    each)."""
    return [x if isinstance(x, tuple) else (None, x) for x in pending]
