"""Grasp selection runs the numerical IK fallback (for poses the closed form gives no branch: wrist singularities)
only where it may find something: a grasp pose clearly out of the arm's reach (planning.ur_ik.surely_unreachable)
is not handed to it (it ran 7 seeds x up to 40 damped-least-squares steps for each such pose, over every grasp of an
item at the edge of the reach), and the answer is the same as with the fallback run everywhere."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.types import PlanningFailure


def _grasp_names(res):
    return type(res).__name__ if isinstance(res, PlanningFailure) else [g.spec.name for g in res]


def test_no_numerical_ik_for_grasps_surely_out_of_reach(planner, resting, home, monkeypatch):
    robot = planner.robot
    # a cup beyond the arm's reach, but near enough that many grasp poses pass the cheap wrist-distance filter
    cup = resting("cup", (0.95, 0.25), 1, z_floor=0.0)
    asked = []
    real_ik = robot.ik

    def counted(T, q, **kw):
        asked.append(np.array(T))
        return real_ik(T, q, **kw)

    monkeypatch.setattr(robot, "ik", counted)
    res = planner.select_grasps(home, [cup])
    assert not any(robot.surely_unreachable(T) for T in asked)
    # the fallback run everywhere (as before) gives the same answer, and it was asked about such poses
    certain = robot.surely_unreachable
    monkeypatch.setattr(robot, "surely_unreachable", lambda T: False)
    asked.clear()
    planner._fits.clear()  # the selection memo keys on the scene, not on the robot's IK patched here: ask afresh
    before = planner.select_grasps(home, [cup])
    assert sum(certain(T) for T in asked) >= 3
    assert _grasp_names(before) == _grasp_names(res)
