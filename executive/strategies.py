"""Strategies for getting an item out, tried in order like MoveIt Task Constructor's ``Fallbacks`` stage.

Each strategy says when it applies (``applies(failure, obj, belief)``: the failure of the direct attempt so far,
None before any) and plans its motions (``plan(req)``): an :class:`ItemPlan`, a :class:`PlanFailure` (it was
tried and failed; the newest failure is what the run reports), or None (not possible here; nothing changes).
A task lists the strategies it uses by name (``Task.strategies``); :func:`plan_item` runs them; the run
report counts each (``RunReport.strategies``: tried / planned).

What each strategy does and which tasks use it: docs/executive.md, "Strategies" (generated from the ``when``
and ``does`` of the classes below by ``kitchenbot docs``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from kitchenbot.executive import machine as M
from kitchenbot.executive.belief import Belief
from kitchenbot.executive.failures import StepFailed
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.seen_through import seen_through
from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.world.attitude import is_lying

SLIDABLE = ("plate",)  # classes that nest flat in stacks and are slid sideways to free them


@dataclass
class PlanFailure:
    kind: str  # the planner's failure kind (planning.types)
    message: str
    stage: str  # pick | place
    strategy: str
    blocking: int | None = None  # the instance the planner named as lying on the item or in its lift's way
    # every instance so named, and whether the item is pinned by them (its lift fails at the grasp, whatever the
    # grasp: planning.pick_place, Planner._pinned_by), so it fails so until one of them moves
    blocking_all: tuple = ()
    pinned: bool = False


@dataclass
class ItemPlan:
    strategy: str
    pick: Any = None  # planning.types.PickPlan
    place: Any = None  # planning.types.PlacePlan
    slide: Any = None  # planning.types.SlidePlan (instead of a pick and place)
    staging: bool = False  # the place sets it down on the counter for a regrasp


@dataclass
class PlanRequest:
    """What a strategy plans with: the item, its targets, the task, the belief and the planner."""

    obj: ObjectPose
    targets: list
    staged: Any  # the Placed record it is picked up from when it was staged, else None
    task: Any
    belief: Belief
    planner: Any
    joints: Callable[[], np.ndarray]  # the arm's joint positions now
    escape: Callable[[], bool]  # move the tool out of the collision margin; False if no way out
    note: Callable[..., None]  # journal a command / note: note(kind, name, **payload)
    check_deadline: Callable[[], None]
    scene_objs: list = field(default_factory=list)


# Grasps tried per direct attempt: the grasp filter checks that a grasp reaches a release pose of a target (and
# its pre-place pose), not the whole place plan (the transfer search, the lowering, the retreat past the
# neighbours); when that fails for the grasp picked, the next grasp that reaches a target is tried.
PLACE_GRASPS = 3


def _direct(req: PlanRequest, name: str, targets=None, staging: bool = False) -> ItemPlan | PlanFailure:
    """Pick (only grasps that can also reach one of `targets`) then place (the first feasible target); when the
    place does not plan, the pick again without that grasp (at most PLACE_GRASPS grasps)."""
    targets = req.targets if targets is None else targets
    obj, b = req.obj, req.belief
    q = req.joints()
    others = [p for p in req.scene_objs
              if p is not obj and not (obj.instance_id >= 0 and p.instance_id == obj.instance_id)]
    t = b.attempts_for(obj)
    missed = list(t.missed) if t is not None else []  # grasps that closed on nothing on this item
    failed: list[str] = []  # grasps whose place did not plan
    first: PlanFailure | None = None
    stopped = b.stopped_lifts(obj)  # lifts of it a protective stop cut short: it is lifted otherwise
    for _ in range(PLACE_GRASPS):
        req.note("command", "plan_pick", cls=obj.cls, targets=[t.T_base_obj[:3, 3] for t in targets],
                 **({"staging": True} if staging else {}), **({"without": missed + failed} if missed or failed else {}),
                 **({"lifts_stopped": [d.tolist() for d in stopped]} if stopped else {}))
        avoid = missed + failed
        pick = req.planner.plan_pick(q, req.scene_objs, target=obj, map_points=b.map_points, place_target=targets,
                                     **({"avoid_grasps": tuple(avoid)} if avoid else {}),
                                     **({"stopped_lifts": tuple(stopped)} if stopped else {}))
        req.check_deadline()
        if not pick.ok:
            # the first place failure says more than "no other grasp" after it
            return first or PlanFailure(pick.kind, f"no pick plan for the {obj.cls}: {pick}", "pick", name,
                                        pick.details.get("blocking"),
                                        tuple(i for i, _ in pick.details.get("blocking_all", ())),
                                        bool(pick.details.get("pinned")))
        req.note("command", "plan_place", grasp=pick.grasp.spec.name, staging=staging)
        place = req.planner.plan_place(pick.end, pick.grasp, targets, objects=others, map_points=b.map_points)
        req.check_deadline()
        if place.ok:
            return ItemPlan(name, pick=pick, place=place, staging=staging)
        req.note("note", "no place plan with this grasp", grasp=pick.grasp.spec.name, reason=str(place))
        first = first or PlanFailure(place.kind, f"no place plan for the {obj.cls}: {place}", "place", name)
        failed.append(pick.grasp.spec.name)
    return first


# The last round on the items every plan failed for (Execution._try_harder): more grasps tried per pick (the
# first few of a crowded item often all have their lifts blocked), items seen less are still candidates (one
# hidden beside others, with nothing on it, is not seen better by waiting), and RRT-Connect gets more work.
HARDER_GRASPS = 3  # x max_grasp_candidates
HARDER_MAX_OCCLUSION = 0.85  # hidden fraction still planned (settings.max_occlusion is the first rounds')
HARDER_RRT = 4  # x planner_max_iterations (or x planner_timeout on wall-clock budgets)


class Strategy:
    name = "strategy"
    when = ""  # when it applies, in words (docs)
    does = ""  # what it plans, in words (docs)

    def applies(self, failure: PlanFailure | None, obj: ObjectPose, belief: Belief, req: PlanRequest) -> bool:
        raise NotImplementedError

    def plan(self, req: PlanRequest) -> ItemPlan | PlanFailure | None:
        raise NotImplementedError


class DirectPick(Strategy):
    name = "direct_pick"
    when = "first, always (only `slide_top_of_nest` comes before it, where it applies)"
    does = "a pick whose grasp also reaches one of the targets (the grasp filter), then the place at the first " \
           "target that plans; when none plans with that grasp, the pick again without it (at most " \
           f"{PLACE_GRASPS} grasps)"

    def applies(self, failure, obj, belief, req):
        return failure is None and not _setting_aside(req)

    def plan(self, req):
        return _direct(req, self.name)


def _setting_aside(req: PlanRequest) -> bool:
    """The item is to be set down on the counter, not at a target of its own: every target is a staging spot
    (the runner chose it to set aside, aside_targets; tasks' own targets are never staging spots)."""
    return req.staged is None and bool(req.targets) and all(t.kind == "stage" for t in req.targets)


def aside_targets(task, belief: Belief, obj: ObjectPose) -> list | None:
    """Counter spots to set `obj` down on when its task has no target for it (the racks have no room for it)
    but it lies on, or in the lift's way of, an item that has one (`blocker_first` named it): a deadlock
    otherwise, since the room kept for that item can be what leaves none for `obj` (a cup over a plate, the
    lower rack's last room kept for the plate). Set down there as a staging (SetAsideBlocker), it is picked up
    again when a target has room. None when the task does not set aside, there is no room on the counter, or
    `obj` was planned to be set aside often enough (Belief.may_set_aside)."""
    if "set_aside_blocker" not in task.strategies or not belief.may_set_aside(obj) \
            or not isinstance(task.targets(obj, belief), NoFreeSlot):
        return None
    spots = task.staging_targets(obj, belief)
    return None if isinstance(spots, NoFreeSlot) or not spots else list(spots)


class SetAsideBlocker(Strategy):
    """An item its task has no target for (the racks have no room for it) that lies on, or in the lift's way of,
    an item that has one: set down on the counter as a staging, so that item can be picked (it was a deadlock:
    the room kept for that item could be what left none for this one). Picked up again from the counter when a
    target has room."""

    name = "set_aside_blocker"
    when = "the item has no target (`no_free_slot`) and an item still in the sink that has one was blocked by it " \
           "(`blocker_first` named it): the runner gives it counter spots instead (`Task.staging_targets`)"
    does = "a pick and a place onto the counter (a staging: it is picked up again when a target has room)"

    def applies(self, failure, obj, belief, req):
        return failure is None and _setting_aside(req)

    def plan(self, req):
        return _direct(req, self.name, staging=True)


class EscapeThenPick(Strategy):
    name = "escape_then_pick"
    when = "the pick's start is within the collision margin (`start_in_collision`: the arm was stopped there)"
    does = "a straight move out of the margin (`Planner.plan_escape`; else back along the last motion), then " \
           "the direct pick again"

    def applies(self, failure, obj, belief, req):
        return failure is not None and failure.stage == "pick" and failure.kind == "start_in_collision"

    def plan(self, req):
        if not req.escape():
            return None
        return _direct(req, self.name)


def _seen_through_pins(req: PlanRequest, failure: PlanFailure) -> list[ObjectPose]:
    """The items named as pinning `req.obj` (its lift fails at the grasp against them) whose poses the points seen
    of `req.obj` contradict: they lie inside those poses' bodies (planning.seen_through)."""
    if not failure.pinned or not failure.blocking_all:
        return []
    pins = [p for p in req.scene_objs if p.instance_id >= 0 and p.instance_id in failure.blocking_all]
    return seen_through(req.planner.inventory, req.obj, pins)


class PickPastSeenThrough(Strategy):
    """An item pinned by an item said to lie on it, where the views saw the pinned item's own surface inside the
    body of the one on it: that pose cannot be right (a few points of another item fitted as a vessel resting on
    this one; every grasp of that phantom collides with the real items under it, so neither could go first and
    both stayed). The pick is planned again without those poses; what the views saw of them stays in the map as
    voxel obstacles (no pose explains those points any more), so the lift still avoids everything seen."""

    name = "pick_past_seen_through"
    when = "the item's lift is pinned (`cartesian_path_failed` at the grasp) by items lying on it, and at least " \
           "a twentieth (50 points or more) of the points seen of the item lie 5 mm or more inside the hull of one " \
           "of those items as posed (`planning.seen_through`): the camera saw through it"
    does = "the direct pick again without those poses (their points stay in the map as voxel obstacles)"

    def __init__(self):
        self._gone: list[ObjectPose] = []  # what applies() found, for plan() (plan_item calls one then the other)

    def applies(self, failure, obj, belief, req):
        self._gone = []
        if failure is None or failure.stage != "pick" or failure.kind != "cartesian_path_failed":
            return False
        self._gone = _seen_through_pins(req, failure)
        return bool(self._gone)

    def plan(self, req):
        gone, self._gone = self._gone, []
        if not gone:
            return None
        req.note("note", "a pose the views saw through is not trusted to pin the item", cls=req.obj.cls,
                 pins=[(p.cls, p.instance_id) for p in gone])
        kept = [p for p in req.scene_objs if not any(p is g for g in gone)]
        return _direct(PlanRequest(**{**req.__dict__, "scene_objs": kept}), self.name)


class StageForRegrasp(Strategy):
    """Set the item down on the counter (in a pose the task chooses for its targets) and grasp it again from
    there, where its next pick offers other grasps. Not for one its targets do not turn (Task.needs_regrasp).
    An item already staged standing (upright or upside down) is staged once more only on its side, where the
    task offers that: from standing, a level side grasp reaches a rack's near part only, and when that is full
    its targets stay out of reach; from its side a grasp from above turns it mouth-down anywhere. One staged on
    its side is not staged again (at most two stagings per item). Only the robot's own stagings count: an item
    that slipped and was found on the counter lies where it fell, which no staging chose (_set_down_there)."""

    name = "stage_for_regrasp"
    when = "no grasp of the item as it lies reaches a target (`no_feasible_placement` in the pick), the targets " \
           "turn it over (`Task.needs_regrasp`) and it is not already staged (staged standing: once more, on its " \
           "side; an item that fell on the counter and was found there counts as not staged)"
    does = "a pick and a place onto the counter (`Task.staging_targets`: upright, upside down or on its side), " \
           "only at spots (and turns) from which a grasp reaches a target (`Planner.onward_staging`), from where " \
           "the next pick offers other grasps; verified there and picked again first"

    def applies(self, failure, obj, belief, req):
        return failure is not None and failure.stage == "pick" and failure.kind == "no_feasible_placement"

    def plan(self, req):
        if not req.task.needs_regrasp(req.targets, req.obj):
            return None
        staged = req.staged if _set_down_there(req.staged) else None  # where it fell is no staging
        if staged is not None and not _staged_standing(staged):
            return None
        stage = req.task.staging_targets(req.obj, req.belief, req.targets)
        if isinstance(stage, NoFreeSlot):
            return None
        if staged is not None:
            stage = [t for t in stage if is_lying(t.T_base_obj)]
            if not stage:
                return None
        # only where the next pick can carry it on to a target (planning.regrasp): the targets the task gives it
        # resting there (how it lies decides them: a bowl standing goes on its rim, one mouth-down mouth-down)
        def targets_there(there: ObjectPose) -> list:
            t = req.task.targets(there, req.belief)
            return [] if isinstance(t, NoFreeSlot) else list(t)

        stage = req.planner.onward_staging(req.joints(), stage, req.obj, targets_there, req.scene_objs,
                                           map_points=req.belief.map_points)
        if not stage:
            req.note("note", "no staging spot from which a grasp reaches a target", cls=req.obj.cls)
            return None
        r = _direct(req, self.name, stage, staging=True)
        return None if isinstance(r, PlanFailure) and r.stage == "pick" else r


def _set_down_there(staged) -> bool:
    """Whether a staged item's record (tasks.base.Placed) is one of the robot setting it down there, not of where
    it fell (a slip found on the counter: Belief.record_found, a "drop" target). Only the robot's own stagings
    count towards the bound on stagings: a mug that slipped on its way to the rack and lies on its side where it
    fell, out of reach of every rack spot, read as "staged on its side already" and was never moved again
    (``no_feasible_placement`` on every pick; tests/executive/test_fallen_item_staged.py)."""
    if staged is None:
        return False
    return getattr(getattr(staged, "target", None), "kind", None) != "drop"


def _staged_standing(staged) -> bool:
    """Whether a staged item's record (tasks.base.Placed) has it standing on the counter, not on its side."""
    T = getattr(staged, "T_base_obj", None)
    return T is not None and not is_lying(np.asarray(T, float))


class StageWhenBlocked(StageForRegrasp):
    """For tasks whose targets admit few grasps (rack poses): stage also when every grasp that reaches a target
    has its lift blocked a second time (the first time the blocker is tried first), or when the full place plan
    fails for every grasp the grasp filter accepted: no release (`no_feasible_placement`), or a straight line
    (`cartesian_path_failed`: the lowering, or the open pads' retreat past the rack's neighbours). The grasp filter
    checks the release pose only; with the grasps the item offers where it lies, the lowering or the retreat ran
    into the rack each time, and from the counter the next pick offers others (a cup grasped from above on its
    side releases with the pads level, not hanging between its neighbours)."""

    name = "stage_when_blocked"
    when = "as stage_for_regrasp, also when every grasp that reaches a target has its lift blocked a second " \
           "time (`cartesian_path_failed` again), or the place fails for every grasp tried: no release " \
           "(`no_feasible_placement`) or its lowering or retreat blocked (`cartesian_path_failed`)"
    does = "as stage_for_regrasp"

    PLACE_KINDS = ("no_feasible_placement", "cartesian_path_failed")

    def applies(self, failure, obj, belief, req):
        if failure is None:
            return False
        if failure.stage == "place":
            return failure.kind in self.PLACE_KINDS
        t = belief.attempts_for(obj)
        return failure.kind == "cartesian_path_failed" and t is not None and failure.kind in t.reasons


def _may_slide(belief, obj) -> bool:
    """Whether `obj` has been slid fewer than MAX_SLIDES_PER_OBJECT times (the slide strategies' shared limit)."""
    t = belief.attempts_for(obj)
    return t is None or t.slides < M.MAX_SLIDES_PER_OBJECT


def _lies_on_named(req: PlanRequest, instance_id: int | None) -> bool:
    """Whether `req.obj` lies on the perceived item `instance_id` (the planner's `items_on`): that item is under
    it, so it cannot be taken first."""
    if instance_id is None or instance_id < 0 or instance_id == req.obj.instance_id:
        return False
    under = [p for p in req.scene_objs if p.instance_id == instance_id]
    return any(any(o is req.obj or (req.obj.instance_id >= 0 and o.instance_id == req.obj.instance_id)
                   for o in req.planner.items_on(p, req.scene_objs)) for p in under)


class SlideOffStack(Strategy):
    """Nested in a stack (the top plate): no pinch fits under its lip. Slide it sideways with the closed fingers;
    the next scan sees it overhanging the one below, where a lip pinch fits. At most MAX_SLIDES_PER_OBJECT.

    The top plate of a messy stack (plates landed off-centre and tipped) fails naming the plate under it: its
    pinches collide with that plate's rim, so the planner names it as crowding them (`crowded_by`). That plate
    cannot go first (this one lies on it, and its own failure names this one), so such a failure does not keep the
    slide from applying; a failure naming an item lying on the plate, or one beside it, still does (that item is
    taken first: `blocker_first`)."""

    name = "slide_off_stack"
    when = "a plate with no collision-free grasp (`no_collision_free_grasp`: nested in a stack) that the failure " \
           "names nothing lying on or blocking but what it lies on itself (the plate under it), not staged, " \
           f"slid fewer than {M.MAX_SLIDES_PER_OBJECT} times"
    does = "press on its well with the closed fingers and slide it 6 cm sideways (`Planner.plan_slide`); the " \
           "next scan sees it overhanging the one below, where a lip pinch fits"

    def applies(self, failure, obj, belief, req):
        if failure is None or failure.stage != "pick" or failure.kind != "no_collision_free_grasp":
            return False
        if obj.cls not in SLIDABLE or req.staged is not None or not _may_slide(belief, obj):
            return False
        # A plate under another item of its stack fails so too, naming the one on it (docs/planning.md): sliding
        # it would drag what lies on it (the arm stops on a loaded push); that one is taken first (blocker_first).
        # The top plate names the plate it lies on (its pinches meet that one's rim): that one cannot go first.
        return failure.blocking is None or failure.blocking < 0 or _lies_on_named(req, failure.blocking)

    def plan(self, req):
        req.note("command", "plan_slide", cls=req.obj.cls)
        return _slide_plan(self.name, req)


class SlideTopOfNest(Strategy):
    """Two plates nested so closely that perception sees one: every grasp of the pair is collision-free as
    planned, but a rim pinch closes across both rims (the opening wider than planned by about the nest's pitch:
    a `grasp_missed`), and so does every other pinch there, whatever its bite, until the item's attempts are
    spent and both plates stay in the sink. Once a grip has felt that (`Belief.nest_felt`), the plate is slid
    sideways before it is gripped again: the closed fingers drag the top plate (the one they press on), and the
    next scan sees it overhanging the one below, where a pinch takes it alone. Tried before the direct pick
    (which would plan a pinch across the pair again); where no slide plans, the direct pick goes on as before."""

    name = "slide_top_of_nest"
    when = "a plate a grip of which closed across two rims (`grasp_missed` wider than planned by 0.8 of its nest " \
           f"pitch: a nest seen as one plate) since it was last slid, not staged, slid fewer than " \
           f"{M.MAX_SLIDES_PER_OBJECT} times; before the direct pick"
    does = "press on its well with the closed fingers and slide it 6 cm sideways (`Planner.plan_slide`): the top " \
           "plate follows the fingers, and the next scan sees it overhanging the one below; the grasps missed " \
           "on the pair are allowed again"

    def applies(self, failure, obj, belief, req):
        return (failure is None and obj.cls in SLIDABLE and req.staged is None and belief.nest_felt(obj)
                and _may_slide(belief, obj))

    def plan(self, req):
        under = nested_under(req.planner, req.obj)
        if under is None:
            return None
        req.note("command", "plan_slide", cls=req.obj.cls, nest_felt=True)
        # the plate the grip felt is planned for as lying one nest pitch under it (no scan shows it): the slide
        # lifts the fingers as the top plate climbs out of its well, to where a grasp of it alone is free
        return _slide_plan(self.name, req, scene_objs=[*req.scene_objs, under])


def nested_under(planner, obj: ObjectPose) -> ObjectPose | None:
    """The plate of `obj`'s kind nested under it, as a grip across both rims says it lies: `obj`'s pose moved
    one nest pitch along its own axis, the way that points down (mouth up or down: a nest is stacked along the
    axis; unseen: no points, no instance id); None when its model is unknown or does not nest."""
    model = planner.inventory.models.get(obj.obj_id)
    if model is None or model.nest_pitch <= 0:
        return None
    T = np.array(obj.T_base_obj, float)
    down = T[:3, 2] if T[2, 2] < 0 else -T[:3, 2]
    T[:3, 3] += model.nest_pitch * down
    return ObjectPose(obj.obj_id, obj.cls, T, 0.0, visible_fraction=0.0)


def _slide_plan(name: str, req: PlanRequest, scene_objs: list[ObjectPose] | None = None, **kw) -> ItemPlan | None:
    """Strategy `name`'s slide of `req.obj` (`Planner.plan_slide` with `kw`) among `scene_objs` (default: the
    request's), or None (the reason noted)."""
    objs = req.scene_objs if scene_objs is None else scene_objs
    stopped = req.belief.stopped_slides(req.obj)  # not planned again unchanged
    slide = req.planner.plan_slide(req.joints(), objs, req.obj, map_points=req.belief.map_points,
                                   **({"avoid": stopped} if stopped else {}), **kw)
    req.check_deadline()
    if not slide.ok:
        req.note("note", "no slide", reason=str(slide))
        return None
    req.note("result", "planned slide", direction=slide.direction, distance=slide.distance,
             to=slide.T_base_obj_after[:3, 3])
    return ItemPlan(name, slide=slide)


def _blocked_below(req: PlanRequest, failure: PlanFailure) -> list[ObjectPose]:
    """The perceived items in the sink that `req.obj` lies on and blocks: named by this failure (its grasps are
    crowded by the item under it) or whose own failure named `req.obj` (it lies in their lift's way)."""
    obj, b = req.obj, req.belief
    if obj.instance_id < 0:
        return []
    blocked = {k for k, v in b.blocked_by.items() if v == obj.instance_id}
    if failure.blocking is not None and failure.blocking >= 0:
        blocked.add(failure.blocking)
    under = [p for p in req.scene_objs if p.instance_id in blocked and p.instance_id != obj.instance_id]
    return [p for p in under if any(o is obj for o in req.planner.items_on(p, [*req.scene_objs]))]


class SlideOffBlocked(Strategy):
    """Two items that block each other: this one lies on the other (in its lift's way, so that one cannot go
    first) and cannot be picked itself (every grasp collides, or its lift is blocked: a lying cup wedged between
    the cup under it and the basin's wall). Pushed off the one below with the closed fingers pressing on its top;
    where it touches a wall, along that wall (the only way out of a corner). Lying items and plates only: an
    item standing on its base or rim would tip over when pushed at its top."""

    name = "slide_off_blocked"
    when = "the item's pick failed (no collision-free grasp, or its lift blocked) and it lies on an item it " \
           "blocks (`blocker_first` named either one as the other's blocker): neither can go first; lying or a " \
           f"plate, not staged, slid fewer than {M.MAX_SLIDES_PER_OBJECT} times"
    does = "press on its top with the closed fingers (off its centre where the palm would meet a wall) and slide " \
           "it off the item below, along a wall it touches where that is the way out (`Planner.plan_slide` " \
           "with `off`: it no longer lies on that item; no grasp of it needed there)"

    KINDS = ("no_collision_free_grasp", "cartesian_path_failed")

    def __init__(self):
        self._below: list[ObjectPose] = []  # what applies() found, for plan() (plan_item calls one then the other)

    def applies(self, failure, obj, belief, req):
        self._below = []
        if failure is None or failure.stage != "pick" or failure.kind not in self.KINDS or req.staged is not None:
            return False
        if not _may_slide(belief, obj):
            return False
        if obj.cls not in SLIDABLE and not is_lying(np.asarray(obj.T_base_obj, float)):
            return False
        self._below = _blocked_below(req, failure)
        return bool(self._below)

    def plan(self, req):
        # the items below as the failure named them too (asked again without the failure, plan() slid "off"
        # nothing where only this failure named the item below: the slide then ignored what it was for)
        below, self._below = self._below, []
        if not below:
            below = _blocked_below(req, PlanFailure("", "", "pick", self.name))
        if not below:
            return None
        req.note("command", "plan_slide", cls=req.obj.cls, off=[p.instance_id for p in below])
        return _slide_plan(self.name, req, then_pickable=False, off=below)


WALL_NEAR = 0.04  # m: an item this close to a basin wall (its mesh) is slid away from it by slide_from_wall


def _wall_room(planner, obj: ObjectPose) -> float | None:
    """Least room (m) between the item's mesh (its pose as perceived) and the basin's four walls; None when its
    model is unknown."""
    if obj.obj_id not in planner.inventory.models:
        return None
    T = np.asarray(obj.T_base_obj, float)
    V = np.asarray(planner.inventory[obj.obj_id].mesh.vertices) @ T[:3, :3].T + T[:3, 3]
    lo, hi = planner.cell.sink_interior
    return float(min(np.min(V[:, :2] - np.asarray(lo, float)[:2]), np.min(np.asarray(hi, float)[:2] - V[:, :2])))


class SlideFromWall(Strategy):
    """A vessel lying on its side close to a basin wall with every grasp in collision: the grasps across its
    body that come from above are those whose pads miss its handle, and beside a wall those put the wrist over
    the counter or the outer pad into the wall. Pushed sideways (the closed fingers pressing on its top) to where
    a grasp is free (`Planner.plan_slide` checks a grasp of it there), then picked on the next round. Lying
    items only: one standing on its base or rim tips over when pushed at its top; plates are slide_off_stack's."""

    name = "slide_from_wall"
    when = "a lying item other than a plate with no collision-free grasp (`no_collision_free_grasp`, no " \
           f"neighbour named as crowding it) within {WALL_NEAR * 100:.0f} cm of a basin wall, not staged, slid " \
           f"fewer than {M.MAX_SLIDES_PER_OBJECT} times"
    does = "press on its top with the closed fingers and slide it up to 6 cm, most room first, only to where a " \
           "grasp of it is free (`Planner.plan_slide` with `then_pickable`); picked on the next round"

    def applies(self, failure, obj, belief, req):
        if failure is None or failure.stage != "pick" or failure.kind != "no_collision_free_grasp":
            return False
        if failure.blocking is not None and failure.blocking >= 0:
            return False  # a neighbour crowds its grasps: that one goes first (blocker_first)
        if obj.cls in SLIDABLE or req.staged is not None or not is_lying(np.asarray(obj.T_base_obj, float)):
            return False
        if not _may_slide(belief, obj):
            return False
        room = _wall_room(req.planner, obj)
        return room is not None and room < WALL_NEAR

    def plan(self, req):
        req.note("command", "plan_slide", cls=req.obj.cls, from_wall=True)
        return _slide_plan(self.name, req)


class PickHiddenBlocker(Strategy):
    """An item judged too hidden to plan (`no_graspable_object`: more than `settings.max_occlusion` of it unseen)
    that the planner named as lying on another item or in its lift's way. What lies on another is not buried
    under it, and waiting does not show it better (it is hidden by the sink's wall or beside others); the item
    under it waits for it meanwhile, and a pile where the blocker is the hidden one waited until the run's last
    round (`harder_settings`), or to the end. Its pick is planned as that round plans it, for this item only."""

    name = "pick_hidden_blocker"
    when = "the item is too hidden to plan (`no_graspable_object`) and an earlier failure of an item still in " \
           "the sink named it as lying on that item or in its lift's way (`blocker_first`)"
    does = "the direct pick again with items hidden up to " \
           f"{HARDER_MAX_OCCLUSION:.0%} planned (as the last round plans them: `harder_settings`)"

    def applies(self, failure, obj, belief, req):
        if failure is None or failure.stage != "pick" or failure.kind != "no_graspable_object":
            return False
        if obj.instance_id < 0 or req.planner.settings.max_occlusion >= HARDER_MAX_OCCLUSION:
            return False
        under = {k for k, v in belief.blocked_by.items() if v == obj.instance_id}
        return any(p.instance_id in under for p in belief.poses)

    def plan(self, req):
        s = req.planner.settings
        req.planner.settings = s.model_copy(update={"max_occlusion": HARDER_MAX_OCCLUSION})
        req.note("note", "planned as a blocker though hidden", cls=req.obj.cls,
                 visible=round(float(req.obj.visible_fraction), 2))
        try:
            return _direct(req, self.name)
        finally:
            req.planner.settings = s


class BlockerFirst(Strategy):
    """The planner named the item lying on this one or in the way of its lift: that one is selected next (an
    item the task does not want is moved out of the way by the task's targets for it); this one waits. One pinned
    by what lies on it (its lift fails at the grasp, whatever the grasp) is not planned again until that moves;
    where it would be tried, the deepest item of its chain is (executive/waiting.py)."""

    name = "blocker_first"
    when = "the newest failure names an item lying on this one or in its lift's way (`details.blocking`)"
    does = "no motion: that item is selected next (moved out of the way by the task's targets for it, even one " \
           "the task does not want), or the deepest item of its chain where it is pinned too; this one waits " \
           "(pinned: not planned again until an item pinning it, or it, moves, or the map around it gains points)"

    def applies(self, failure, obj, belief, req):
        return failure is not None and failure.blocking is not None and failure.blocking >= 0

    def plan(self, req):
        return None  # a decision, not a motion: plan_item passes the blocker on with the failure, and the
        #              recovery records it in the belief (Belief.record_blocked)


STRATEGIES: dict[str, type[Strategy]] = {s.name: s for s in (
    SlideTopOfNest, DirectPick, EscapeThenPick, PickPastSeenThrough, StageForRegrasp, StageWhenBlocked, SlideOffStack,
    SlideOffBlocked,
    SlideFromWall, PickHiddenBlocker, SetAsideBlocker, BlockerFirst)}


def strategies_for(task) -> list[Strategy]:
    """The task's strategies, in its order (Task.strategies names them)."""
    try:
        return [STRATEGIES[n]() for n in task.strategies]
    except KeyError as e:
        raise ValueError(f"task {task.name!r}: unknown strategy {e.args[0]!r}; expected one of "
                         f"{sorted(STRATEGIES)}") from None


def plan_item(req: PlanRequest, strategies: list[Strategy], counts: dict) -> ItemPlan:
    """Fallbacks: the first strategy that applies and plans wins. A strategy applies to the failure of the direct
    attempt (direct_pick, escape_then_pick); with none planned, the newest failure is raised as a planning
    StepFailed, naming the blocking item when blocker_first applies to it."""
    direct: PlanFailure | None = None
    last: PlanFailure | None = None
    for s in strategies:
        if isinstance(s, BlockerFirst) or not s.applies(direct, req.obj, req.belief, req):
            continue
        c = counts.setdefault(s.name, {"tried": 0, "planned": 0})
        c["tried"] += 1
        r = s.plan(req)
        if isinstance(r, ItemPlan):
            c["planned"] += 1
            return r
        if isinstance(r, PlanFailure):
            last = r
            if s.name in ("direct_pick", "escape_then_pick"):
                direct = r
    f = last or PlanFailure("no_strategy", f"no strategy applies to the {req.obj.cls}", "pick", "none")
    blocking = None
    for s in strategies:
        if isinstance(s, BlockerFirst) and s.applies(f, req.obj, req.belief, req):
            c = counts.setdefault(s.name, {"tried": 0, "planned": 0})
            c["tried"] += 1
            c["planned"] += 1
            blocking = f.blocking
    pinned = {"pinned_by": f.blocking_all} if blocking is not None and f.pinned and f.blocking_all else {}
    # strategy, named: the strategy whose plan failed last and every item its failure named lying on the item or in
    # its way (the item's reported reason: executive/left_reason.py)
    raise StepFailed("planning", f.message, planning_kind=f.kind, blocking=blocking, strategy=f.strategy,
                     named=tuple(f.blocking_all), **pinned)


def harder_settings(s):
    """PlanningSettings for the last round (see HARDER_*): a copy, `s` is not changed."""
    up = {"max_grasp_candidates": min(100, s.max_grasp_candidates * HARDER_GRASPS),
          "max_occlusion": max(s.max_occlusion, HARDER_MAX_OCCLUSION)}
    if s.planner_max_iterations is not None:
        up["planner_max_iterations"] = s.planner_max_iterations * HARDER_RRT
    else:
        up["planner_timeout"] = min(60.0, s.planner_timeout * HARDER_RRT)
    return s.model_copy(update=up)


def strategies_markdown(tasks: dict) -> str:
    """The strategies and the tasks that use them, as a markdown table (docs/executive.md)."""
    lines = ["| strategy | applies when | plans | tasks |", "|---|---|---|---|"]
    for name, cls in STRATEGIES.items():
        users = ", ".join(f"`{t}`" for t, c in tasks.items() if name in c.strategies) or "-"
        lines.append(f"| `{name}` | {cls.when} | {cls.does} | {users} |")
    return "\n".join(lines)
