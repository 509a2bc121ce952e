"""planning.lift.lift_fallbacks: the lift directions in the order plan_pick tries them, the ones away from what
the lifts ran into only after the others, and only when they ran into something."""

from __future__ import annotations

import numpy as np

from kitchenbot.world.cell import Cell
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.lift import base_directions, lift_fallbacks
from kitchenbot.transforms import make_T, rot_x


def test_up_first_then_along_a_tilted_item_then_away_from_the_walls():
    sink = Cell().sink_interior
    lo, hi = sink
    p = (np.asarray(lo) + 0.05)[:3]
    p[2] = -0.15
    T = make_T(t=p) @ rot_x(np.radians(20))
    got = list(lift_fallbacks(sink, T, [], set(), near_wall=True))
    assert np.allclose(got[0][0], [0, 0, 1]) and got[0][1] is True
    assert got[1][1] is True and np.allclose(got[1][0], T[:3, 2] * np.sign(T[2, 2]))  # along its axis
    # then between straight up and its axis (a third and two thirds of its tilt, in its vertical plane)
    axis = T[:3, 2] * np.sign(T[2, 2])
    for (d, along), f in zip(got[2:4], (1 / 3, 2 / 3)):
        assert along is True and np.isclose(np.degrees(np.arccos(d[2])), 20 * f)
        assert np.isclose(d[:2] @ axis[:2], np.linalg.norm(d[:2]) * np.linalg.norm(axis[:2]))
    assert all(not along for _, along in got[4:]) and len(got) == len(base_directions(sink, p, T)) + 2
    assert len(list(lift_fallbacks(sink, T, [], set(), near_wall=False))) == 4  # not near a wall: no tilts


def test_away_from_what_the_lifts_ran_into_once_the_others_are_used_up():
    sink = Cell().sink_interior
    p = np.array([0.5, 0.0, -0.15])
    T = make_T(t=p)
    glass = ObjectPose(0, "glass", make_T(t=(0.56, 0.0, -0.12)), 1.0, instance_id=2)
    ran_into: set[str] = set()
    gen = lift_fallbacks(sink, T, [glass], ran_into, near_wall=False)
    d, along = next(gen)
    assert along and np.allclose(d, [0, 0, 1])
    assert list(gen) == []  # nothing was in the way: no more
    gen = lift_fallbacks(sink, T, [glass], ran_into, near_wall=False)
    next(gen)
    ran_into.add("2")  # the straight lift ran into the glass (its planner name: the instance id)
    rest = [d for d, _ in gen]
    assert rest and all(d[0] < 0 for d in rest)  # tilted away from the glass (it lies towards +x)
