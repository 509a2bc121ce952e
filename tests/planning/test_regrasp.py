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


def _ortho(R) -> np.ndarray:
    U, _, Vt = np.linalg.svd(np.asarray(R, float))
    return U @ Vt


def test_a_mug_carried_by_its_handle_is_set_down_at_another_turn_where_the_first_turns_refuse_the_place(
        planner, home):
    """A mug lying on its side across a tilted side plate (over a dinner plate, beside another tilted one), wanted
    mouth-down in the upper rack: no grasp of it as it lies reaches the rack, so it is staged on the counter.
    Where the plates leave it only its handle free, the pick for the staging takes the handle, and the mug arrives
    with a level approach fixed by the turn it is set down at. At the first turn of each spot that leads on (the
    only one kept before), the straight retreat from the release pulls the wrist back into the upper arm (or has
    no IK): every grasp's place failed and the mug stayed in the sink, the plates under it pinned. Other turns of
    the same spots also lead on and do place: they are kept too (opposite turn first), and one is set down."""
    inv = planner.inventory
    task = make_task("sink-to-dishwasher", inv, planner.cell)
    mug_m, side, dinner = inv.by_name("mug"), inv.by_name("side_plate"), inv.by_name("dinner_plate")
    mug = ObjectPose(mug_m.obj_id, mug_m.cls, make_T(_ortho([[-0.31, 0.10, -0.95], [0.95, -0.02, -0.32],
                                                             [-0.05, -1.0, -0.09]]), (0.486, -0.087, -0.102)),
                     1.0, instance_id=5)
    scene = [mug,
             ObjectPose(side.obj_id, side.cls, make_T(_ortho([[0.89, 0.46, -0.06], [-0.44, 0.79, -0.43],
                                                              [-0.15, 0.41, 0.9]]), (0.381, -0.029, -0.126)),
                        1.0, instance_id=0),
             ObjectPose(dinner.obj_id, dinner.cls, make_T(t=(0.401, -0.059, -0.184)), 1.0, instance_id=1),
             ObjectPose(dinner.obj_id, dinner.cls, make_T(_ortho([[0.99, -0.15, -0.04], [0.11, 0.89, -0.45],
                                                                  [0.1, 0.44, 0.89]]), (0.501, 0.038, -0.12)),
                        1.0, instance_id=2)]
    b = Belief()
    targets = list(task.targets(mug, b))
    stage = task.staging_targets(mug, b, targets)
    out = planner.onward_staging(home, stage, mug, lambda there: list(task.targets(there, b)), scene)
    for t in out:  # every turn kept leads on
        there = ObjectPose(mug.obj_id, mug.cls, _resting(t.T_base_obj), 1.0)
        assert t.kind == "stage" and not t.free_yaw
        assert reaches_from(planner, mug, there.T_base_obj, list(task.targets(there, b)), scene[1:], None, home)
    failed: list[str] = []
    place = None
    for _ in range(3):  # as the executive does (strategies._direct): the next grasp where the place fails
        pick = planner.plan_pick(home, scene, target=mug, place_target=out, avoid_grasps=tuple(failed))
        if not pick.ok:
            break
        place = planner.plan_place(pick.end, pick.grasp, out, objects=scene[1:])
        if place.ok:
            break
        failed.append(pick.grasp.spec.name)
    assert place is not None and place.ok, f"set down at none of the staging turns kept: {place}; {failed}"
