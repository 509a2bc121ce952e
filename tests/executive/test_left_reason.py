"""The run's message names each item left with its latest failure and what that failure named, while that still
holds (executive/left_reason.py). Hand-made beliefs: three plates X, Y, Z apart in the sink; the plans fail through
plan_item (a planner that refuses every pick as told), and the failure is recovered as the rules do (the runner's
record_plan_failure and prefer_blocker actions), no motion.

Found on a sink-to-dishwasher run: a plate first waited for the bowls lying on its foot; the bowls were all placed,
the plate then failed otherwise (its lift ran into another plate, too hidden, no free slot), and the run's message
still said "pinned by the bowl lying on it": every reason ever recorded was listed."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.failures import StepFailed, classify
from kitchenbot.executive.strategies import BlockerFirst, DirectPick, PlanRequest, plan_item
from kitchenbot.planning.types import CartesianPathFailed

from .test_pinned_chain import _placed, _select, _setup


def _plan_fails(runner, obj, by, pinned):
    """`obj`'s plan fails (plan_item, direct_pick) naming `by` in its lift's way, pinning it or not; the failure is
    recovered as the rules for a planning failure do (on the selected item: `obj`)."""
    assert runner.item.obj is obj

    class Refuses:
        def plan_pick(self, *a, **kw):
            return CartesianPathFailed("test: lift", {"blocking": by.instance_id,
                                                      "blocking_all": [(by.instance_id, by.cls)],
                                                      **({"pinned": True} if pinned else {})})

    b = runner.belief
    req = PlanRequest(obj, [], None, None, b, Refuses(), lambda: np.zeros(6), lambda: False,
                      lambda *a, **k: None, lambda: None, b.scene_objects())
    with pytest.raises(StepFailed) as e:
        plan_item(req, [DirectPick(), BlockerFirst()], {})
    f = classify(e.value, "plan")
    runner._act_record_plan_failure(f, {})
    runner._act_prefer_blocker(f, {})


def test_an_item_that_waited_for_a_placed_blocker_is_reported_with_its_later_failure(make_runner):
    """X waits pinned by Y; Y is placed; X is planned again and its lift now runs into Z (not pinned): the message
    names X's latest failure (its strategy, Z in its way), not "pinned by" the plate placed long before."""
    runner, X, Y, Z = _setup(make_runner)
    assert _select(runner) is X
    _plan_fails(runner, X, Y, pinned=True)
    assert "pinned by the plate lying on it" in runner._why_left([X])  # while Y lies on it
    assert _select(runner) is Y
    _placed(runner, Y)
    assert _select(runner) is X  # Y is gone: X no longer waits
    _plan_fails(runner, X, Z, pinned=False)
    msg = runner._why_left([X, Z])
    assert msg.startswith("2 object(s) left in the sink: plate (cartesian_path_failed in direct_pick; in its way: "
                          "the plate)"), msg
    assert "pinned" not in msg, msg


def test_a_blocker_placed_after_the_last_failure_is_no_longer_named(make_runner):
    """X's last failure named Y in its way; Y was placed after it and X not planned again: the message does not
    name Y as in X's way, it says that what the failure named has gone."""
    runner, X, Y, Z = _setup(make_runner)
    assert _select(runner) is X
    _plan_fails(runner, X, Y, pinned=False)
    assert "in its way: the plate" in runner._why_left([X])
    _placed(runner, Y)
    msg = runner._why_left([X])
    assert msg == ("1 object(s) left in the sink: plate (cartesian_path_failed in direct_pick; what it named "
                   "(the plate) has gone since)"), msg


def test_the_latest_failure_replaces_the_earlier_ones_and_the_history_stays(make_runner):
    """An executed attempt's failure after a planning failure is the one reported; the kinds of both stay in the
    item's history (a strategy reads it: a lift blocked a second time)."""
    runner, X, Y, Z = _setup(make_runner)
    b = runner.belief
    assert _select(runner) is X
    _plan_fails(runner, X, Y, pinned=False)
    b.record_failure(X, "grasp_missed")
    assert runner._why_left([X]) == "1 object(s) left in the sink: plate (grasp_missed)"
    assert b.attempts_for(X).reasons == ["cartesian_path_failed", "grasp_missed"]
