"""A chain of items pinned by what lies on them (executive/waiting.py), on hand-made beliefs: three plates X, Y, Z,
X pinned by Y, Y pinned by Z (the planner's pinned lift failure: ``details["pinned_by"]``). The selection is
driven through the runner's own steps (select, the planning failure's recovery actions, a placement), no motion."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.failures import Failure
from kitchenbot.perception.types import ObjectPose


def _plates(runner):
    """Three plates apart in the sink, X highest (the task's first), then Y, then Z."""
    inv = runner.planner.inventory
    plate = next(m for m in inv.models.values() if m.cls == "plate")
    lo, hi = (np.asarray(v, float) for v in runner.robot.cell.sink_interior)
    c = (lo + hi) / 2
    out = []
    for k, (dx, z) in enumerate([(-0.12, 0.06), (0.0, 0.04), (0.12, 0.02)]):
        T = np.eye(4)
        T[:3, 3] = (c[0] + dx, c[1], lo[2] + z)
        out.append(ObjectPose(plate.obj_id, "plate", T, 1.0, instance_id=k))
    return out


def _setup(make_runner):
    runner, _ = make_runner(task="sink-pick", journal=False)
    X, Y, Z = _plates(runner)
    b = runner.belief
    b.poses = [X, Y, Z]
    b.pending = []
    return runner, X, Y, Z


def _select(runner):
    assert runner._do_select_grasp() == "selected"
    return runner.item.obj


def _pinned(runner, by):
    """The selected item's plan failed: pinned by `by` (as plan_item raises it), recovered as the rules do."""
    f = Failure("planning", "test: lift pinned", "plan",
                {"planning_kind": "cartesian_path_failed", "blocking": by.instance_id,
                 "pinned_by": (by.instance_id,)})
    runner._act_record_plan_failure(f, {})
    runner._act_prefer_blocker(f, {})


def _placed(runner, obj):
    """`obj` was picked and placed; no new perception (the placement view settled it)."""
    b = runner.belief
    b.picked_away(obj, [])
    b.scene_changed()


def test_a_pinned_item_waits_and_the_chain_goes_to_its_deepest_item(make_runner):
    runner, X, Y, Z = _setup(make_runner)
    assert _select(runner) is X
    _pinned(runner, Y)
    assert _select(runner) is Y  # blocker first
    _pinned(runner, Z)
    assert _select(runner) is Z
    _placed(runner, Z)
    # X is the task's first, but Y (what pins it) has not moved: X is not planned again; Y (no longer pinned) is
    assert _select(runner) is Y
    _placed(runner, Y)
    assert _select(runner) is X  # what pinned it went: planned again


def test_the_deepest_item_is_tried_first_when_a_chain_is_known(make_runner):
    """A placement elsewhere leaves the chain as it was: X waits for Y, Y for Z; the selection goes straight to Z
    (before: X was planned again, failed on Y, then Y failed on Z)."""
    runner, X, Y, Z = _setup(make_runner)
    W = ObjectPose(Z.obj_id, "plate", Z.T_base_obj.copy(), 1.0, instance_id=3)
    W.T_base_obj[1, 3] += 0.1
    W.T_base_obj[2, 3] -= 0.01  # the task's last
    runner.belief.poses.append(W)
    assert _select(runner) is X
    _pinned(runner, Y)
    assert _select(runner) is Y
    _pinned(runner, Z)
    assert _select(runner) is Z
    runner.belief.record_unplannable(Z)  # Z failed to plan in this scene (no blocker named)
    assert _select(runner) is W
    _placed(runner, W)
    assert _select(runner) is Z


def test_a_pinned_item_is_planned_again_when_what_pins_it_moves_or_the_map_around_it_changes(make_runner):
    runner, X, Y, Z = _setup(make_runner)
    assert _select(runner) is X
    _pinned(runner, Y)
    assert _select(runner) is Y
    runner.belief.record_unplannable(Y)
    runner.belief.scene_changed()
    runner.belief.unplannable = []
    assert _select(runner) is Y  # X still waits for Y
    moved = ObjectPose(Y.obj_id, "plate", Y.T_base_obj.copy(), 1.0, instance_id=Y.instance_id)
    moved.T_base_obj[0, 3] += 0.01  # re-perceived 1 cm off: it may no longer pin X
    runner.belief.poses = [X, moved, Z]
    assert _select(runner) is X

    runner, X, Y, Z = _setup(make_runner)
    assert _select(runner) is X
    _pinned(runner, Y)
    assert _select(runner) is Y
    runner.belief.unplannable = []  # a new scene (as after a placement elsewhere)
    assert _select(runner) is Y
    runner.belief.unplannable = []
    runner.belief.mark_contact(np.asarray(X.T_base_obj[:3, 3], float).reshape(1, 3) + (0.02, 0.0, 0.03))
    assert _select(runner) is X  # new points in the map around it: planned again


def test_an_item_left_waiting_is_reported_with_its_reason(make_runner):
    """What pins X cannot be tried (its attempts are used up): X is no candidate (the run does not loop on it) and
    the run's message names it with why it was left."""
    runner, X, Y, Z = _setup(make_runner)
    b = runner.belief
    assert _select(runner) is X
    _pinned(runner, Y)
    b.give_up_on(Y, "grasp_missed")
    b.scene_changed()
    cands = runner._candidates()
    assert not any(p is X for p in cands) and not any(p is Y for p in cands)
    msg = runner._why_left([X, Y])
    assert "pinned by the plate lying on it" in msg and "plate (" in msg


def test_plan_item_passes_on_what_pins_the_item():
    """A direct pick that fails pinned raises the planning failure with ``pinned_by`` (every item named); one that
    is only blocked (not pinned) without it."""
    import pytest

    from kitchenbot.executive.belief import Belief
    from kitchenbot.executive.failures import StepFailed
    from kitchenbot.executive.strategies import BlockerFirst, DirectPick, PlanRequest, plan_item
    from kitchenbot.planning.types import CartesianPathFailed

    obj = ObjectPose(1, "plate", np.eye(4), 1.0, instance_id=0)
    for pinned in (True, False):
        class Refuses:
            def plan_pick(self, *a, **kw):
                return CartesianPathFailed("test: lift", {"blocking": 1, "blocking_all": [(1, "cup"), (2, "glass")],
                                                          **({"pinned": True} if pinned else {})})

        req = PlanRequest(obj, [], None, None, Belief(), Refuses(), lambda: np.zeros(6), lambda: False,
                          lambda *a, **k: None, lambda: None)
        with pytest.raises(StepFailed) as e:
            plan_item(req, [DirectPick(), BlockerFirst()], {})
        assert e.value.details["blocking"] == 1
        assert e.value.details.get("pinned_by") == ((1, 2) if pinned else None)


def test_a_ring_of_waits_ends_with_each_item_reported(make_runner):
    """X pinned by Y and Y pinned by X (a ring: estimated poses of a tilted pile each lying on the other): neither
    is a candidate any more (the run does not loop between them), Z still is; once Z is placed nothing is, and
    the run's message names both with why they were left (nothing silently lost)."""
    runner, X, Y, Z = _setup(make_runner)
    assert _select(runner) is X
    _pinned(runner, Y)
    assert _select(runner) is Y
    _pinned(runner, X)
    assert _select(runner) is Z
    _placed(runner, Z)
    runner.belief.unplannable = []
    assert runner._candidates() == []
    msg = runner._why_left([X, Y])
    assert msg.count("pinned by the plate lying on it") == 2, msg


def test_a_rescan_that_finds_the_pinned_item_and_what_pins_it_where_they_were_keeps_it_waiting(make_runner):
    """A full re-scan replaces the perceived map with one of several times the points (sink-pick: 14k -> 49k points
    within 20 cm of a leaning plate pinned by the plate its lower rim is tucked under), and new pose objects within
    a millimetre of the old ones. The pinned verdict depends on the poses alone, so X keeps waiting and its chain
    (Y) is tried; before, the denser map ended the wait and X was planned again, to fail pinned by Y again. A new
    contact mark around it still ends the wait (the test above)."""
    runner, X, Y, Z = _setup(make_runner)
    b = runner.belief
    rng = np.random.default_rng(0)
    c = np.asarray(X.T_base_obj[:3, 3], float)
    b.set_map_base(c + rng.uniform(-0.15, 0.15, (1000, 3)) * (1.0, 1.0, 0.1))
    assert _select(runner) is X
    _pinned(runner, Y)
    assert _select(runner) is Y
    runner.belief.record_unplannable(Y)  # Y failed in this scene (no blocker named): X waits, nothing to try there
    again = []
    for p in (X, Y, Z):  # the re-scan's poses: new objects, 0.4 mm off
        T = np.array(p.T_base_obj, float)
        T[:3, 3] += (0.0004, -0.0002, 0.0001)
        again.append(ObjectPose(p.obj_id, p.cls, T, 1.0, instance_id=p.instance_id))
    lo_hi = tuple(np.asarray(v, float) for v in runner.robot.cell.sink_interior)
    b.perceived(again, c + rng.uniform(-0.15, 0.15, (4000, 3)) * (1.0, 1.0, 0.1), [], lo_hi)
    assert _select(runner) is again[1]  # Y (what pins X), not X
