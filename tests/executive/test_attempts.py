"""Attempt bookkeeping: an object that cannot be planned waits for the scene to change, grasp attempts do not
come back."""

import numpy as np

from kitchenbot.executive import machine as M
from kitchenbot.executive.belief import Attempts


def test_planning_failures_are_forgotten_when_the_scene_changes():
    t = Attempts("plate", np.zeros(3))
    for _ in range(M.MAX_PLAN_FAILURES_PER_SCENE):
        assert not t.exhausted(0)
        t.plan_failed(0)
    assert t.exhausted(0)  # blocked in this scene: try the others
    assert not t.exhausted(1)  # something was placed since: try it again
    t.plan_failed(1)
    assert t.plan_failures == 1 and not t.exhausted(1)


def test_executed_attempts_are_never_forgotten():
    t = Attempts("cup", np.zeros(3))
    t.count = M.MAX_ATTEMPTS_PER_OBJECT
    assert t.exhausted(0) and t.exhausted(5)
