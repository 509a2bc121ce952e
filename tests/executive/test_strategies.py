"""The strategies for getting an item out (executive/strategies.py), on hand-made situations: a planner that
answers each request as a real one would in that situation (the failure kinds of planning.types), and the real
tasks, belief and Fallbacks order. What is checked: which strategy plans, in which order they are tried, what is
counted, and what the failure names when none plans."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from kitchenbot.executive.belief import Belief
from kitchenbot.executive.failures import StepFailed
from kitchenbot.executive.strategies import (
    STRATEGIES,
    PlanRequest,
    plan_item,
    strategies_for,
)
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import (
    CartesianPathFailed,
    NoCollisionFreeGrasp,
    NoFeasiblePlacement,
    PlannerTimeout,
    StartInCollision,
)
from kitchenbot.tasks import make_task
from kitchenbot.transforms import make_T

MOUTH_DOWN = np.diag([1.0, -1.0, -1.0])


@pytest.fixture(scope="module")
def inv():
    return Inventory.builtin()


def item(inv, name, R=np.eye(3), k=1):
    m = inv.by_name(name)
    return ObjectPose(m.obj_id, m.cls, make_T(R, (0.5, 0.0, -0.15)), 1.0, instance_id=k)


@dataclass
class _Spec:
    name: str = "g"


@dataclass
class _Grasp:
    spec: _Spec = field(default_factory=_Spec)


@dataclass
class _Ok:
    end: np.ndarray = field(default_factory=lambda: np.zeros(6))
    grasp: _Grasp = field(default_factory=_Grasp)
    T_base_obj: np.ndarray = field(default_factory=lambda: np.eye(4))
    details: dict = field(default_factory=dict)
    direction: tuple = (1.0, 0.0)
    distance: float = 0.06
    T_base_obj_after: np.ndarray = field(default_factory=lambda: np.eye(4))
    trajectories: tuple = ()
    ok = True


class Situation:
    """A planner for one situation: `pick(targets, n)` answers the n-th pick request for those targets (staging
    targets have kind "stage"); place and slide answer ok unless told otherwise."""

    def __init__(self, pick, place=None, slide_ok=True, onward=None):
        self.pick, self.place, self.slide_ok = pick, place, slide_ok
        self.onward = onward  # staging target -> does the next pick from there reach a target? (None: all do)
        self.calls: list[str] = []

    def plan_pick(self, q, objects, *, target=None, map_points=None, place_target=None, avoid_grasps=()):
        staging = all(t.kind == "stage" for t in place_target)
        self.calls.append("pick:stage" if staging else "pick")
        self.avoided = list(avoid_grasps)
        r = self.pick(staging, self.calls.count("pick"))
        if r.ok and r.grasp.spec.name in avoid_grasps:  # a real planner offers the next grasp, if any
            return NoFeasiblePlacement("test: no other grasp reaches a target")
        return r

    def plan_place(self, q, grasp, targets, *, objects=None, map_points=None):
        self.calls.append("place")
        return self.place(targets) if self.place else _Ok()

    def onward_staging(self, q, stage, obj, targets, objects=(), *, map_points=None):
        self.calls.append("onward")
        return [t for t in stage if self.onward is None or self.onward(t)]

    def plan_slide(self, q, objects, obj, *, map_points=None):
        self.calls.append("slide")
        return _Ok() if self.slide_ok else NoCollisionFreeGrasp("test: no room to slide")


def request(task, belief, obj, planner, escape=lambda: False, staged=None):
    return PlanRequest(obj, task.targets(obj, belief), staged, task, belief, planner, lambda: np.zeros(6), escape,
                       lambda *a, **k: None, lambda: None)


def test_every_task_lists_known_strategies_direct_pick_first():
    from kitchenbot.tasks import TASKS

    for cls in TASKS.values():  # only slide_top_of_nest comes before it (it applies after a grip felt a nest)
        assert [n for n in cls.strategies if n != "slide_top_of_nest"][0] == "direct_pick"
        assert set(cls.strategies) <= set(STRATEGIES)
    assert "stage_when_blocked" in TASKS["sink-to-dishwasher"].strategies
    assert "stage_when_blocked" not in TASKS["sink-pick"].strategies


def test_an_unknown_strategy_is_a_clear_error(inv):
    task = make_task("sink-pick", inv, Cell())
    task.strategies = ("direct_pick", "juggle")
    with pytest.raises(ValueError, match="unknown strategy 'juggle'"):
        strategies_for(task)


def test_direct_pick_plans_when_it_can(inv):
    task, b = make_task("sink-pick", inv, Cell()), Belief()
    planner = Situation(lambda staging, n: _Ok())
    counts: dict = {}
    plan = plan_item(request(task, b, item(inv, "cup"), planner), strategies_for(task), counts)
    assert plan.strategy == "direct_pick" and not plan.staging
    assert counts == {"direct_pick": {"tried": 1, "planned": 1}} and planner.calls == ["pick", "place"]


def test_when_the_place_fails_for_the_grasp_picked_the_next_grasp_is_tried(inv):
    """The grasp filter checks a release pose, not the whole place (transfer, lowering, retreat past the
    neighbours): a grasp it kept may give no place plan while the next one does."""
    task, b = make_task("sink-to-dishwasher", inv, Cell()), Belief()
    names = iter(["rim_01", "rim_02", "rim_03"])
    planner = Situation(lambda staging, n: _Ok(grasp=_Grasp(_Spec(next(names)))),
                        place=lambda targets: CartesianPathFailed("test: retreat blocked") if
                        planner.calls.count("place") < 2 else _Ok())
    plan = plan_item(request(task, b, item(inv, "side_plate"), planner), strategies_for(task), counts := {})
    assert plan.strategy == "direct_pick" and plan.pick.grasp.spec.name == "rim_02"
    assert planner.calls == ["pick", "place", "pick", "place"] and counts["direct_pick"] == {"tried": 1, "planned": 1}
    # no grasp places: the place failure is what is reported, not "no other grasp"
    names = iter(["rim_01", "rim_02", "rim_03"])
    planner = Situation(lambda staging, n: _Ok(grasp=_Grasp(_Spec(next(names)))),
                        place=lambda targets: CartesianPathFailed("test: retreat blocked"))
    sp = make_task("sink-pick", inv, Cell())
    with pytest.raises(StepFailed) as e:
        plan_item(request(sp, b, item(inv, "side_plate"), planner), strategies_for(sp), {})
    assert e.value.details["planning_kind"] == "cartesian_path_failed" and "retreat" in str(e.value)
    assert planner.calls.count("place") == 3


def test_an_upside_down_cup_for_a_stack_is_staged_for_a_regrasp(inv):
    """No grasp of it as it lies reaches upright: the pick for its targets finds no feasible placement; the
    staging targets (on the counter) are reachable."""
    task, b = make_task("cup-stacking", inv, Cell()), Belief()
    planner = Situation(lambda staging, n: _Ok() if staging else NoFeasiblePlacement("test: none reaches upright"))
    counts: dict = {}
    plan = plan_item(request(task, b, item(inv, "cup", MOUTH_DOWN), planner), strategies_for(task), counts)
    assert plan.strategy == "stage_for_regrasp" and plan.staging
    assert counts["stage_for_regrasp"] == {"tried": 1, "planned": 1} and counts["direct_pick"]["planned"] == 0
    assert planner.calls == ["pick", "onward", "pick:stage", "place"]


def test_an_item_is_staged_only_where_its_next_pick_reaches_a_target(inv):
    """The staging targets are kept only where the item, set down there, offers a grasp reaching one of its
    targets (Planner.onward_staging): only those are planned; with none, the item is not staged at all (it
    would stay on the counter, every pick from there without a feasible placement)."""
    task, b = make_task("cup-stacking", inv, Cell()), Belief()
    asked: list = []

    def pick(staging, n):
        return _Ok() if staging else NoFeasiblePlacement("test: none reaches upright")

    obj = item(inv, "cup", MOUTH_DOWN)
    all_stage = task.staging_targets(obj, b, task.targets(obj, b))
    assert len(all_stage) >= 2
    keep = all_stage[1].T_base_obj
    planner = Situation(pick, onward=lambda t: np.allclose(t.T_base_obj, keep))
    real_pick = planner.plan_pick

    def plan_pick(q, objects, *, target=None, map_points=None, place_target=None, avoid_grasps=()):
        asked.append(list(place_target))
        return real_pick(q, objects, target=target, map_points=map_points, place_target=place_target)

    planner.plan_pick = plan_pick
    plan = plan_item(request(task, b, obj, planner), strategies_for(task), {})
    assert plan.staging and len(asked[-1]) == 1 and np.allclose(asked[-1][0].T_base_obj, keep)
    planner = Situation(pick, onward=lambda t: False)
    with pytest.raises(StepFailed) as e:
        plan_item(request(task, b, obj, planner), strategies_for(task), {})
    assert e.value.details["planning_kind"] == "no_feasible_placement" and "pick:stage" not in planner.calls


def test_an_item_already_staged_is_not_staged_again(inv):
    task, b = make_task("cup-stacking", inv, Cell()), Belief()
    planner = Situation(lambda staging, n: _Ok() if staging else NoFeasiblePlacement("test"))
    with pytest.raises(StepFailed) as e:
        plan_item(request(task, b, item(inv, "cup", MOUTH_DOWN), planner, staged=object()), strategies_for(task), {})
    assert e.value.details["planning_kind"] == "no_feasible_placement" and "pick:stage" not in planner.calls


def test_a_cup_staged_upright_out_of_reach_of_its_racks_is_staged_once_more_on_its_side(inv):
    """sink-to-dishwasher: a cup staged upright on the counter whose grasps reach none of its rack spots (a level
    side grasp reaches the upper rack's near part only, and that is full) is staged again, on its side only (from
    there a grasp from above turns it mouth-down anywhere); one staged on its side is not staged a third time."""
    from kitchenbot.tasks.base import Placed

    task, b = make_task("sink-to-dishwasher", inv, Cell()), Belief()
    asked: list = []

    def pick(staging, n):
        return _Ok() if staging else NoFeasiblePlacement("test: no grasp reaches a rack spot")

    planner = Situation(pick)
    real_pick = planner.plan_pick

    def plan_pick(q, objects, *, target=None, map_points=None, place_target=None):
        asked.append(list(place_target))
        return real_pick(q, objects, target=target, map_points=map_points, place_target=place_target)

    planner.plan_pick = plan_pick
    m = inv.by_name("cup")
    up = ObjectPose(m.obj_id, m.cls, make_T(np.eye(3), (0.0, 0.45, 0.05)), 1.0, instance_id=10_000)
    staged = Placed(m.obj_id, m.cls, up.T_base_obj, np.zeros(2), np.zeros(2), 0.1, None, 10_000)
    plan = plan_item(request(task, b, up, planner, staged=staged), strategies_for(task), counts := {})
    assert plan.strategy == "stage_for_regrasp" and plan.staging
    stage = asked[-1]
    assert stage and all(t.kind == "stage" and abs(t.T_base_obj[2, 2]) < 1e-6 for t in stage)  # on its side only
    assert counts["stage_for_regrasp"]["planned"] == 1
    lying = stage[0].T_base_obj
    on_side = ObjectPose(m.obj_id, m.cls, lying, 1.0, instance_id=10_001)
    staged2 = Placed(m.obj_id, m.cls, lying, np.zeros(2), np.zeros(2), 0.1, None, 10_001)
    planner.calls.clear()
    with pytest.raises(StepFailed):
        plan_item(request(task, b, on_side, planner, staged=staged2), strategies_for(task), {})
    assert "pick:stage" not in planner.calls


def test_a_stop_within_the_margin_is_escaped_then_the_pick_planned_again(inv):
    task, b = make_task("sink-pick", inv, Cell()), Belief()
    planner = Situation(lambda staging, n: StartInCollision("test: stopped there") if n == 1 else _Ok())
    escaped = []
    plan = plan_item(request(task, b, item(inv, "cup"), planner, escape=lambda: escaped.append(1) or True),
                     strategies_for(task), counts := {})
    assert plan.strategy == "escape_then_pick" and escaped == [1] and counts["direct_pick"]["planned"] == 0


def test_a_plate_whose_failure_names_an_item_on_it_is_not_slid_that_item_goes_first(inv):
    # the lower plate of a stack: no collision-free grasp, the plate on it named; a slide would push both
    task, b = make_task("sink-pick", inv, Cell()), Belief()
    on_it = NoCollisionFreeGrasp("test: the plate on it crowds every pinch", {"blocking": 7, "blocking_all": [(7, 0.02)]})
    planner = Situation(lambda staging, n: on_it)
    with pytest.raises(StepFailed) as e:
        plan_item(request(task, b, item(inv, "dinner_plate"), planner), strategies_for(task), counts := {})
    assert "slide" not in planner.calls and counts.get("slide_off_stack", {}).get("tried", 0) == 0
    assert e.value.details.get("blocking") == 7  # blocker_first: the plate on it is selected next


class _Stacked(Situation):
    """A Situation whose items lie on others as `on` says: {instance id below: [items lying on it]}."""

    def __init__(self, pick, on):
        super().__init__(pick)
        self.on = on

    def items_on(self, target, objects):
        return list(self.on.get(target.instance_id, []))


def test_a_plate_whose_failure_names_the_plate_under_it_is_slid(inv):
    """The top plate of a messy stack: its pinches meet the rim of the plate under it, and the failure names that
    plate (it crowds them). That plate cannot go first (the top plate lies on it): the top plate is slid. A plate
    whose failure names a neighbour it does not lie on still waits for that one (blocker_first)."""
    task, b = make_task("sink-pick", inv, Cell()), Belief()
    top, under, beside = item(inv, "dinner_plate", k=3), item(inv, "dinner_plate", k=2), item(inv, "cup", k=5)
    crowded = NoCollisionFreeGrasp("test: the rim under it crowds every pinch", {"blocking": 2, "blocking_all": [(2, "plate")]})
    planner = _Stacked(lambda staging, n: crowded, {2: [top]})
    req = request(task, b, top, planner)
    req.scene_objs = [top, under, beside]
    plan = plan_item(req, strategies_for(task), counts := {})
    assert plan.strategy == "slide_off_stack" and counts["slide_off_stack"] == {"tried": 1, "planned": 1}
    by_cup = NoCollisionFreeGrasp("test: the cup beside it crowds every pinch", {"blocking": 5, "blocking_all": [(5, "cup")]})
    planner = _Stacked(lambda staging, n: by_cup, {2: [top]})
    req = request(task, b, top, planner)
    req.scene_objs = [top, under, beside]
    with pytest.raises(StepFailed) as e:
        plan_item(req, strategies_for(task), counts := {})
    assert "slide" not in planner.calls and e.value.details.get("blocking") == 5


def test_a_nested_plate_with_no_grasp_is_slid_off_its_stack_a_cup_is_not(inv):
    task, b = make_task("sink-pick", inv, Cell()), Belief()
    planner = Situation(lambda staging, n: NoCollisionFreeGrasp("test: no pinch under its lip"))
    plan = plan_item(request(task, b, item(inv, "dinner_plate"), planner), strategies_for(task), counts := {})
    assert plan.strategy == "slide_off_stack" and plan.slide is not None and counts["slide_off_stack"]["planned"] == 1
    with pytest.raises(StepFailed):
        plan_item(request(task, b, item(inv, "cup"), Situation(lambda s, n: NoCollisionFreeGrasp("t"))),
                  strategies_for(task), {})
    # slid as often as allowed: no more
    from kitchenbot.executive import machine as M

    plate = item(inv, "dinner_plate")
    b.attempts_for(plate, create=True).slides = M.MAX_SLIDES_PER_OBJECT
    with pytest.raises(StepFailed):
        plan_item(request(task, b, plate, planner), strategies_for(task), {})


def test_a_named_blocker_is_passed_on_and_counted(inv):
    task, b = make_task("sink-pick", inv, Cell()), Belief()
    planner = Situation(lambda staging, n: CartesianPathFailed("test: the lift hits a glass", {"blocking": 7}))
    counts: dict = {}
    with pytest.raises(StepFailed) as e:
        plan_item(request(task, b, item(inv, "cup"), planner), strategies_for(task), counts)
    assert e.value.details["blocking"] == 7 and counts["blocker_first"] == {"tried": 1, "planned": 1}
    task.strategies = tuple(s for s in task.strategies if s != "blocker_first")  # a task without it: no blocker
    with pytest.raises(StepFailed) as e:
        plan_item(request(task, b, item(inv, "cup"), planner), strategies_for(task), {})
    assert e.value.details["blocking"] is None


def test_stage_when_blocked_only_after_the_lift_was_blocked_before(inv):
    """sink-to-dishwasher: a cup whose rack-reaching grasps have their lift blocked. The first time it waits
    (the blocker may be picked first); when blocked again, it is staged."""
    task, b = make_task("sink-to-dishwasher", inv, Cell()), Belief()
    cup = item(inv, "cup")
    planner = Situation(lambda staging, n: _Ok() if staging else CartesianPathFailed("test: lift blocked"))
    with pytest.raises(StepFailed):
        plan_item(request(task, b, cup, planner), strategies_for(task), {})
    assert "pick:stage" not in planner.calls
    b.record_plan_failure(cup, "cartesian_path_failed")
    plan = plan_item(request(task, b, cup, planner), strategies_for(task), counts := {})
    assert plan.strategy == "stage_when_blocked" and plan.staging and counts["stage_when_blocked"]["planned"] == 1
    # sink-pick does not list it
    sp = make_task("sink-pick", inv, Cell())
    with pytest.raises(StepFailed):
        plan_item(request(sp, b, cup, Situation(planner.pick)), strategies_for(sp), {})


def test_an_unplaceable_grasp_is_staged_in_the_dishwasher_task(inv):
    task, b = make_task("sink-to-dishwasher", inv, Cell()), Belief()
    planner = Situation(lambda staging, n: _Ok(),
                        place=lambda targets: _Ok() if targets[0].kind == "stage" else NoFeasiblePlacement("t"))
    plan = plan_item(request(task, b, item(inv, "cup"), planner), strategies_for(task), counts := {})
    assert plan.strategy == "stage_when_blocked" and counts["direct_pick"] == {"tried": 1, "planned": 0}


def test_a_grasp_that_closed_on_nothing_is_not_planned_again_for_that_item(inv):
    """The same poses plan the same grasp: one that closed on nothing on an item (grasp_missed) is passed to the
    planner as a grasp to avoid for that item, and for no other."""
    task, b = make_task("sink-pick", inv, Cell()), Belief()
    cup, glass = item(inv, "cup"), item(inv, "glass", k=2)
    glass.T_base_obj[:3, 3] += (0.2, 0.0, 0.0)
    b.record_missed_grasp(cup, "side_03")
    b.record_missed_grasp(cup, "side_03")
    planner = Situation(lambda staging, n: _Ok())
    plan_item(request(task, b, cup, planner), strategies_for(task), {})
    assert planner.avoided == ["side_03"]
    plan_item(request(task, b, glass, planner), strategies_for(task), {})
    assert planner.avoided == []


def test_a_cup_whose_retreat_from_the_rack_is_blocked_for_every_grasp_is_staged(inv):
    """sink-to-dishwasher: every grasp that reaches a rack spot has its place plan fail on a straight line (the
    open pads' retreat between the rack's neighbours): staged on the counter, where the next pick offers other
    grasps. A transfer that found no path is not a reason to stage."""
    task, b = make_task("sink-to-dishwasher", inv, Cell()), Belief()
    names = iter(f"side_{k:02d}" for k in range(10))
    planner = Situation(lambda staging, n: _Ok(grasp=_Grasp(_Spec(next(names)))),
                        place=lambda targets: _Ok() if targets[0].kind == "stage"
                        else CartesianPathFailed("retreat: ends within the collision margin"))
    plan = plan_item(request(task, b, item(inv, "cup"), planner), strategies_for(task), counts := {})
    assert plan.strategy == "stage_when_blocked" and plan.staging
    assert planner.calls.count("place") == 3 + 1  # the three grasps of the direct pick, then the staging place
    planner = Situation(lambda staging, n: _Ok(grasp=_Grasp(_Spec(next(names)))),
                        place=lambda targets: _Ok() if targets[0].kind == "stage" else PlannerTimeout("t"))
    with pytest.raises(StepFailed):
        plan_item(request(task, b, item(inv, "cup"), planner), strategies_for(task), {})


class _HiddenGate(Situation):
    """A planner with the real occlusion gate (planning.grasps.too_hidden) and the real default settings: an item
    hidden more than `settings.max_occlusion` is not planned (`no_graspable_object`), others are."""

    def __init__(self):
        from kitchenbot.planning.settings import PlanningSettings

        super().__init__(lambda staging, n: _Ok())
        self.settings = PlanningSettings()
        self.occlusion_seen: list[float] = []

    def plan_pick(self, q, objects, *, target=None, map_points=None, place_target=None, avoid_grasps=()):
        from kitchenbot.planning.grasps import too_hidden
        from kitchenbot.planning.types import NoGraspableObject

        self.occlusion_seen.append(self.settings.max_occlusion)
        if too_hidden(target, self.settings):
            self.calls.append("pick")
            return NoGraspableObject("test: too hidden")
        return super().plan_pick(q, objects, target=target, map_points=map_points, place_target=place_target,
                                 avoid_grasps=avoid_grasps)


def _glass_on_bowl(inv, planner):
    """A glass lying on a bowl, seen poorly (against the sink's wall): hidden 0.7 by the planner's measure, more
    than the first rounds plan (0.6), less than the last round's (0.85)."""
    s = planner.settings
    glass = ObjectPose(inv.by_name("glass").obj_id, "glass", make_T(np.eye(3), (0.5, 0.0, -0.08)), 1.0,
                       instance_id=15, visible_fraction=0.3 * s.visible_fraction_unoccluded)
    bowl = ObjectPose(inv.by_name("bowl").obj_id, "bowl", make_T(np.eye(3), (0.5, 0.0, -0.15)), 1.0,
                      instance_id=3, visible_fraction=0.2 * s.visible_fraction_unoccluded)
    return glass, bowl


@pytest.mark.parametrize("task_name", ["sink-pick", "sink-to-dishwasher"])
def test_a_hidden_item_named_as_lying_on_another_is_planned_as_the_last_round_plans_it(inv, task_name):
    """The bowl's plan named the glass on it as its blocker; the glass itself was too hidden to plan, so both
    waited (before: until the run's last round, or to the end). Now the glass, a named blocker of an item still
    in the sink, is planned with the last round's occlusion limit, for its pick only."""
    task, b = make_task(task_name, inv, Cell()), Belief()
    planner = _HiddenGate()
    glass, bowl = _glass_on_bowl(inv, planner)
    b.poses = [glass, bowl]
    before = planner.settings.max_occlusion
    # not (yet) named as anyone's blocker: it waits as before
    with pytest.raises(StepFailed) as e:
        plan_item(request(task, b, glass, planner), strategies_for(task), {})
    assert e.value.details["planning_kind"] == "no_graspable_object"
    b.record_blocked(bowl, glass.instance_id)
    plan = plan_item(request(task, b, glass, planner), strategies_for(task), counts := {})
    assert plan.strategy == "pick_hidden_blocker" and counts["pick_hidden_blocker"] == {"tried": 1, "planned": 1}
    assert planner.occlusion_seen[-1] > before and planner.settings.max_occlusion == before  # restored
    # the item under it gone from the sink: no reason any more
    b.poses = [glass]
    with pytest.raises(StepFailed):
        plan_item(request(task, b, glass, planner), strategies_for(task), {})
    # hidden more than even the last round plans: still not planned
    buried = ObjectPose(glass.obj_id, "glass", glass.T_base_obj, 1.0, instance_id=15,
                        visible_fraction=0.1 * planner.settings.visible_fraction_unoccluded)
    b.poses = [buried, bowl]
    with pytest.raises(StepFailed):
        plan_item(request(task, b, buried, planner), strategies_for(task), {})


def test_an_item_set_aside_is_planned_as_a_staging_onto_the_counter(inv):
    """The runner gives an item with no room in the racks that blocks another counter spots instead of targets
    (strategies.aside_targets, tests/executive/test_set_aside.py): it is planned as a staging there, not as a
    direct pick onto spots taken for its targets."""
    task, b = make_task("sink-to-dishwasher", inv, Cell()), Belief()
    cup = item(inv, "cup")
    planner = Situation(lambda staging, n: _Ok())
    req = request(task, b, cup, planner)
    req.targets = task.staging_targets(cup, b)
    plan = plan_item(req, strategies_for(task), counts := {})
    assert plan.strategy == "set_aside_blocker" and plan.staging
    assert planner.calls == ["pick:stage", "place"]
    assert counts["set_aside_blocker"] == {"tried": 1, "planned": 1} and "direct_pick" not in counts
    # its own targets: the direct pick, as before
    plan = plan_item(request(task, b, cup, planner), strategies_for(task), counts := {})
    assert plan.strategy == "direct_pick" and not plan.staging


def test_a_mug_that_fell_on_the_counter_is_staged_the_robot_s_own_staging_on_its_side_is_not(inv):
    """A mug slipped on its way to the rack and was found lying on its side on the counter (recovery: its record
    has a "drop" target, "counter (it fell there)"); as it lies there no grasp reaches a rack spot. It was never
    set down there: it is staged as an item from the sink is (standing, in the drop zone). It used to be read as
    "already staged on its side" and left on the counter (``no_feasible_placement`` on every pick). A mug the robot
    itself set down on its side (a "stage" target) is still not staged again: the bound on stagings stays."""
    from kitchenbot.planning.types import PlaceTarget
    from kitchenbot.tasks.base import Placed
    from kitchenbot.transforms import rot_x

    task, b = make_task("sink-to-dishwasher", inv, Cell()), Belief()
    planner = Situation(lambda staging, n: _Ok() if staging else NoFeasiblePlacement("test: none reaches a rack"))
    m = inv.by_name("mug")
    T = make_T(rot_x(np.pi / 2)[:3, :3], (0.60, 0.29, 0.045))  # on its side, beside the stacking area
    mug = ObjectPose(m.obj_id, m.cls, T, 1.0, instance_id=10_000)
    fell = Placed(m.obj_id, m.cls, T, np.zeros(2), np.zeros(2), 0.09,
                  PlaceTarget(T.copy(), "drop", support="counter (it fell there)"), 10_000)
    plan = plan_item(request(task, b, mug, planner, staged=fell), strategies_for(task), counts := {})
    assert plan.strategy == "stage_for_regrasp" and plan.staging and counts["stage_for_regrasp"]["planned"] == 1
    assert planner.calls == ["pick", "onward", "pick:stage", "place"]

    planner.calls.clear()
    set_down = Placed(m.obj_id, m.cls, T, np.zeros(2), np.zeros(2), 0.09,
                      PlaceTarget(T.copy(), "stage", support="counter (regrasp)"), 10_000)
    with pytest.raises(StepFailed) as e:
        plan_item(request(task, b, mug, planner, staged=set_down), strategies_for(task), {})
    assert e.value.details["planning_kind"] == "no_feasible_placement" and "pick:stage" not in planner.calls
