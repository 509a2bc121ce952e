"""Two dinner plates nested flat in the sink, seen as one plate (tests/executive/test_nested_plates.py): a rim pinch
closes across both rims, wider than planned by about the nest's pitch, and lets go. Before, the item's next
attempts were other pinches on the pair (each closing across both rims again, in the simulator and in the fresh
runs where this left both plates in the sink); now the grip that felt two rims marks the plate
(``Belief.nest_felt``, executive/recovery.py ``_closed_on_a_nest``) and the next plan slides it sideways with the
closed fingers before any other grasp (``slide_top_of_nest``, executive/strategies.py): the top plate follows
the fingers off the lower one. Oracle perception: the executive's mechanism is under test."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.failures import StepFailed, classify
from kitchenbot.fakes.placement import drop_onto

from tests.executive.test_nested_plates import nested_plates_runner


@pytest.fixture
def nested(small_config, tmp_path, monkeypatch):
    """The pair of test_nested_plates.py, but the upper plate on the lower one's axis (a nest as it settles: the
    lower plate is where the pitch down the upper one's axis puts it)."""
    import tests.executive.test_nested_plates as tn

    make = tn._nested_plates

    def concentric(cfg):
        world, (lower, upper) = make(cfg)
        T = world.objects[upper].T_base_obj.copy()
        T[:2, 3] = world.objects[lower].T_base_obj[:2, 3]
        world.set_pose(upper, drop_onto(world, upper, T))
        return world, (lower, upper)

    monkeypatch.setattr(tn, "_nested_plates", concentric)
    return nested_plates_runner(small_config(), "sink-pick", tmp_path / "journal.sqlite", hidden_while_held=False)


def _round(runner) -> None:
    assert [runner._do_scan(), runner._do_perceive(), runner._do_select_grasp(), runner._do_plan()] == [
        "scanned", "perceived", "selected", "planned"]


def test_a_grip_across_two_rims_slides_the_top_plate_off_before_any_other_grasp(nested):
    runner, world, lower, upper = nested
    _round(runner)
    assert runner.item.slide is None  # nothing felt yet: the direct pick, a rim pinch
    with pytest.raises(StepFailed) as e:
        runner._do_execute()
    assert e.value.kind == "grasp_missed"
    wider = e.value.details["opening"] - e.value.details["expected"]
    pitch = runner.planner.inventory[runner.item.obj.obj_id].nest_pitch
    assert wider >= 0.8 * pitch  # the pads took in the lower plate's rim too
    runner.failure = classify(e.value, "execute")
    assert runner._do_recover() == "rescan"
    assert runner.belief.nest_felt(runner.item.obj)
    lower_before = world.objects[lower].T_base_obj.copy()
    _round(runner)
    assert runner.item.slide is not None, "another grasp of the pair planned"  # before: a pinch of another kind
    assert runner._do_execute() == "executed"
    assert runner.arm.log.collisions == 0
    T_u, T_l = world.objects[upper].T_base_obj, world.objects[lower].T_base_obj
    assert np.allclose(T_l, lower_before)  # the fingers dragged the top plate only
    assert np.linalg.norm(T_u[:2, 3] - T_l[:2, 3]) > 0.03  # off the lower one: perception sees two plates
    t = next(a for a in runner.belief.attempts if a.slides == 1)  # the record moved with the plate
    assert np.linalg.norm(t.pos[:2] - T_u[:2, 3]) < 0.02
    assert not t.nest_felt and t.missed == []  # the grips on the pair say nothing of it alone


def test_a_grip_a_little_off_its_width_or_on_nothing_is_no_nest(nested):
    """A pinch closing a few mm wider than planned (the pose a little off) or on nothing is no second rim."""
    runner, world, lower, upper = nested
    _round(runner)
    width = runner.item.pick.grasp.spec.width
    pitch = runner.planner.inventory[runner.item.obj.obj_id].nest_pitch
    for details in ({"opening": width + 0.5 * pitch, "expected": width}, {"opening": 0.0}):
        runner.failure = classify(StepFailed("grasp_missed", "off its width", **details), "execute")
        runner._act_record_failure(runner.failure, {})
        assert not runner.belief.nest_felt(runner.item.obj)
    runner.failure = classify(StepFailed("grasp_missed", "two rims", opening=width + pitch, expected=width), "execute")
    runner._act_record_failure(runner.failure, {})
    assert runner.belief.nest_felt(runner.item.obj)
