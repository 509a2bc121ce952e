"""Release poses for a place target (Planner._place_tcp_options): every IK branch is considered, so the answer
does not depend on the configuration the question is asked from (the grasp filter asks from the arm before the
pick, plan_place from the lifted arm; they must agree)."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.collision import Held
from kitchenbot.planning.grasps import expand_grasps
from kitchenbot.planning.types import PlaceTarget
from kitchenbot.tasks.base import inverted
from kitchenbot.transforms import inv


def _level_side_grasp(model):
    return next(g for g in expand_grasps(model) if g.name == "side80_00")


def test_release_options_do_not_depend_on_the_reference_configuration(planner, home):
    cup = planner.inventory.by_name("cup")
    g = _level_side_grasp(cup)
    upper = planner.cell.spec.dishwasher.upper
    release = planner.world.scene([], np.zeros((0, 3)), Held(cup, inv(g.T_obj_tcp), g.width)).for_release(None)
    # a cup turned over with a level side grasp, in the upper rack's near half: the branch nearest the home
    # configuration collides at every yaw and release height, another branch does not (with
    # only the nearest branch this target was unreachable)
    target = PlaceTarget(inverted(cup, (0.51, -0.40), upper.floor_z), "slot", "t", free_yaw=True)
    other = home + np.array([-1.2, 0.3, -0.4, 0.5, 0.8, 1.0])  # far from the configurations that reach the rack
    answers = []
    for q_ref in (home, other):
        opts = planner._place_tcp_options(target, g.T_obj_tcp, q_ref, release, obj_id=cup.obj_id)
        assert opts, "a level side grasp reaches the near half of the upper rack"
        for T_obj, T_tcp, q in opts:
            assert release.valid(q)
            np.testing.assert_allclose(planner.robot.fk_tcp(q), T_tcp, atol=1e-6)
            np.testing.assert_allclose(T_obj @ g.T_obj_tcp, T_tcp, atol=1e-9)
            assert T_obj[2, 2] < -0.99  # upside down
        # nearest the reference configuration first
        d = [float(np.max(np.abs(q - q_ref))) for _, _, q in opts]
        assert d == sorted(d)
        answers.append(sorted((round(float(T[2, 3]), 4), tuple(np.round(Tt[:3, 2], 3))) for T, Tt, _ in opts))
        first = planner._place_tcp_options(target, g.T_obj_tcp, q_ref, release, first_only=True, obj_id=cup.obj_id)
        assert len(first) == 1
    assert answers[0] == answers[1]  # the same release poses (height and tool direction), asked from either
