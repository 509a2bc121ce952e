"""Staging for a regrasp only where the next pick reaches a target (planning/regrasp.py), on a hand-made
situation: a mug standing in the sink, wanted mouth-down in the upper rack (only a level side grasp from the
counter turns it over, and whether one reaches the rack depends on which way its handle points there)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kitchenbot.executive.belief import Belief
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.regrasp import _resting, reaches_from
from kitchenbot.tasks import make_task
from kitchenbot.transforms import make_T, trans
from kitchenbot.world.gripper import DROP_HEIGHT


def _standing(planner, name, xy, instance_id):
    m = planner.inventory.by_name(name)
    lo, _ = planner.cell.sink_interior
    return ObjectPose(m.obj_id, m.cls, make_T(t=(xy[0], xy[1], lo[2] + m.extents[2] / 2 + 0.001)), 1.0,
                      instance_id=instance_id)


def test_a_mug_is_staged_only_at_a_turn_from_which_a_grasp_reaches_the_rack(planner, home):
    task = make_task("sink-to-dishwasher", planner.inventory, planner.cell)
    mug = _standing(planner, "mug", (0.34, 0.0), 3)
    b = Belief()
    targets = task.targets(mug, b)
    stage = task.staging_targets(mug, b, targets)
    out = planner.onward_staging(home, stage, mug, targets, [mug])
    assert out, "a standing mug has counter turns from which a side grasp turns it over into the upper rack"
    for t in out:  # its handle matters: the turn is fixed, and from there a grasp reaches a rack spot
        assert t.kind == "stage" and not t.free_yaw and t.flip_ok is False
        assert reaches_from(planner, mug, _resting(t.T_base_obj), targets, [], None, home)
    # targets nothing can reach (moved 3 m away): no staging at all, it would only leave the mug on the counter
    far = [replace(t, T_base_obj=trans(3.0, 0.0, 0.0) @ t.T_base_obj) for t in targets]
    assert planner.onward_staging(home, stage, mug, far, [mug]) == []


def test_a_round_cup_keeps_its_free_turn_and_is_checked_once_per_spot(planner, home, monkeypatch):
    import kitchenbot.planning.regrasp as rg

    task = make_task("sink-to-dishwasher", planner.inventory, planner.cell)
    cup = _standing(planner, "cup", (0.34, 0.0), 4)
    b = Belief()
    targets = task.targets(cup, b)
    stage = task.staging_targets(cup, b, targets)
    seen = []
    monkeypatch.setattr(rg, "reaches_from", lambda pl, o, T, *a: seen.append(T) or True)
    out = planner.onward_staging(home, stage, cup, targets, [cup])
    assert out == list(stage) and len(seen) == len(stage)  # same targets (free turn kept), one check each
    assert all(np.isclose(T[2, 3], t.T_base_obj[2, 3] - DROP_HEIGHT) for T, t in zip(seen, stage))  # at rest
