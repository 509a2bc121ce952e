"""A plate with a cup standing on it: every lift of the plate drags the cup (the held plate is within the margin of
an item lying on it at the grasp), whatever the direction or the grasp. The planner says so once
(Planner._pinned_by) instead of trying each lift direction and each sidestep from the same blocked first state, and
gives the same answer: lift blocked, the cup named as what to take first."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.pick_place import Planner
from kitchenbot.transforms import make_T

OFF = 0.03  # m the cup stands off the plate's centre: the lifts tilted away from it have a direction


@pytest.fixture
def cup_on_plate(planner, inventory):
    """A dinner plate flat on the sink floor; a cup standing in its well 3 cm off its centre, its base 0.8 mm over the highest point of the
    plate's mesh under the cup's footprint."""
    plate_m, cup_m = inventory.by_name("dinner_plate"), inventory.by_name("cup")
    floor = planner.cell.sink_interior[0][2]
    zp = floor + plate_m.extents[2] / 2 + 0.001
    plate = ObjectPose(plate_m.obj_id, plate_m.cls, make_T(t=(0.45, 0.0, zp)), 1.0, instance_id=1)
    Vc, Vp = np.asarray(cup_m.mesh.vertices), np.asarray(plate_m.mesh.vertices)
    foot = np.linalg.norm(Vc[:, :2], axis=1).max()
    under = Vp[np.linalg.norm(Vp[:, :2] - [OFF, 0.0], axis=1) <= foot + 0.002, 2].max() + zp
    cup = ObjectPose(cup_m.obj_id, cup_m.cls, make_T(t=(0.45 + OFF, 0.0, under + 0.0008 - Vc[:, 2].min())), 1.0,
                     instance_id=2)
    assert planner._lies_on(cup, plate) and not planner._lies_on(plate, cup)
    return plate, cup


def _lift_lines(monkeypatch, planner):
    calls = []
    line = Planner._line

    def counted(self, scene, q0, T_goal, name, **kw):
        if name == "lift":
            calls.append(name)
        return line(self, scene, q0, T_goal, name, **kw)

    monkeypatch.setattr(Planner, "_line", counted)
    return calls


def test_a_plate_under_a_cup_is_refused_once_with_the_cup_named(monkeypatch, planner, home, cup_on_plate):
    plate, cup = cup_on_plate
    calls = _lift_lines(monkeypatch, planner)
    pick = planner.plan_pick(home, [plate, cup], target=plate)
    assert not pick.ok and pick.kind == "cartesian_path_failed", str(pick)
    assert pick.details.get("blocking") == cup.instance_id
    assert pick.details.get("candidates_tried") == 1  # no other grasp changes it
    assert calls == []  # no lift line planned from the blocked first state


def test_the_same_answer_as_trying_every_lift(monkeypatch, planner, home, cup_on_plate):
    plate, cup = cup_on_plate
    once = planner.plan_pick(home, [plate, cup], target=plate)
    calls = _lift_lines(monkeypatch, planner)
    monkeypatch.setattr(Planner, "_pinned_by", staticmethod(lambda *a: None))
    every = planner.plan_pick(home, [plate, cup], target=plate)
    assert len(calls) > 3  # the directions and sidesteps, each failing at the grasp
    assert (every.kind, every.message, every.details.get("blocking")) == (once.kind, once.message, once.details.get("blocking"))
    assert every.details.get("candidates_tried") == once.details.get("candidates_tried")
    assert planner.plan_pick(home, [plate, cup], target=cup).ok  # the cup comes out first


def test_the_pinned_failure_says_so(monkeypatch, planner, home, cup_on_plate):
    """The executive keeps a pinned item waiting until what pins it moves (executive/waiting.py): the failure says
    it is pinned, and by what; a lift that failed line by line does not."""
    plate, cup = cup_on_plate
    once = planner.plan_pick(home, [plate, cup], target=plate)
    assert once.details.get("pinned") is True
    assert [i for i, _ in once.details["blocking_all"]] == [cup.instance_id]
    monkeypatch.setattr(Planner, "_pinned_by", staticmethod(lambda *a: None))
    every = planner.plan_pick(home, [plate, cup], target=plate)
    assert not every.details.get("pinned")
