"""motion.segment_free: the yes/no form of the dense re-check (check_segment), its states asked coarse to fine. It
must answer as check_segment does, on free and colliding joint segments and polylines through a pile of items in
the sink, in a plain scene and in a grasp scene (pad contacts allowed near the target)."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.grasps import object_name
from kitchenbot.planning.motion import check_segment, coarse_to_fine, reach_bounds, segment_free

from .test_grasp_swivel import Q, _pile


def test_coarse_to_fine_orders_every_index_once_ends_first():
    for n in (1, 2, 3, 7, 64, 129, 500):
        o = coarse_to_fine(n)
        assert sorted(o.tolist()) == list(range(n))
        assert o[0] == 0 and o[min(1, n - 1)] == n - 1
    assert coarse_to_fine(9).tolist() == [0, 8, 4, 2, 6, 1, 3, 5, 7]


def test_segment_free_answers_as_the_dense_check(planner, inventory):
    objects, cup = _pile(inventory)
    scene = planner.scene(objects, own=[cup])
    grasp_scene = scene.for_grasp(object_name(cup, 0))
    rng = np.random.default_rng(3)
    r = reach_bounds(scene)
    lo, hi = planner.robot.lower, planner.robot.upper
    seen = {True: 0, False: 0}
    for s in (scene, grasp_scene):
        for _ in range(60):
            # from where the arm was over the pile to random configurations near it, and short polylines
            k = int(rng.integers(2, 4))
            P = np.vstack([Q] + [np.clip(Q + rng.normal(0.0, 0.6, 6), lo, hi) for _ in range(k - 1)])
            for step in (0.004, 0.015):
                want = check_segment(s, P, r, step) < 0
                assert segment_free(s, P, r, step) == want, (P, step)
                seen[want] += 1
    assert seen[True] > 10 and seen[False] > 10, seen
