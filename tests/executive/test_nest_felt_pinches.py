"""Two dinner plates nested on one axis, seen as one (tests/executive/test_slide_top_of_nest.py): a rim pinch
closes across both rims (`grasp_missed`, wider by a nest pitch) and marks the plate (`Belief.nest_felt`). Where no
slide is left for it (every slide of it stopped), the direct pick came next and planned other pinches of the
pair, each closing across both rims again and spending the item's attempts. Now, once a grip has felt the nest,
the direct pick plans against the plate felt under it (`nested_under`, executive/strategies.py `_direct`): a pinch
that would close across both rims takes in another object and is not planned."""

from __future__ import annotations

import pytest

from kitchenbot.executive import machine as M
from kitchenbot.executive.failures import StepFailed, classify
from kitchenbot.executive.strategies import DirectPick, PlanFailure, PlanRequest

from tests.executive.test_slide_top_of_nest import _round, nested  # noqa: F401 (the fixture)

pytestmark = pytest.mark.timeout(300)


def test_after_a_grip_across_two_rims_no_pinch_across_them_is_planned(nested):  # noqa: F811
    runner, world, lower, upper = nested
    _round(runner)
    with pytest.raises(StepFailed) as e:
        runner._do_execute()
    assert e.value.kind == "grasp_missed"
    runner.failure = classify(e.value, "execute")
    assert runner._do_recover() == "rescan"
    obj = runner.item.obj
    assert runner.belief.nest_felt(obj)
    runner.belief.attempts_for(obj).slides = M.MAX_SLIDES_PER_OBJECT  # no slide left for it
    assert [runner._do_scan(), runner._do_perceive(), runner._do_select_grasp()] == ["scanned", "perceived",
                                                                                   "selected"]
    it, b = runner.item, runner.belief
    req = PlanRequest(it.obj, it.targets, it.staged, runner.task, b, runner.planner, runner.arm.joint_positions,
                      runner._escape, runner._note, runner._check_deadline, scene_objs=b.scene_objects())
    plan = DirectPick().plan(req)
    # before: another pinch of the pair was planned (`rimnarrow+0_06`), its pads closing where the plate under it lies
    assert isinstance(plan, PlanFailure), plan.pick.grasp.spec.name
    assert plan.kind == "no_collision_free_grasp", plan
