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


def test_a_stopped_lift_is_not_given_again_and_tilts_all_round_follow():
    """`stopped`: a lift of this item a protective stop cut short (its item let go where it was taken): no direction
    within STOPPED_LIFT_ANGLE of it, and after the others, tilts at every heading (the first towards the middle)."""
    from kitchenbot.planning.lift import AROUND_TILTS, AROUND_TURNS, STOPPED_LIFT_ANGLE, repeats_stopped

    sink = Cell().sink_interior
    lo, hi = sink
    p = np.array([0.4, 0.1, -0.15])  # off the sink's middle
    T = make_T(t=p) @ rot_x(np.radians(6))  # resting tilted a little: its own axis is within the angle of up
    up = np.array([0.0, 0.0, 1.0])
    assert len(list(lift_fallbacks(sink, T, [], set(), near_wall=False))) == 4  # up, its axis, two between
    got = [d for d, _ in lift_fallbacks(sink, T, [], set(), near_wall=False, stopped=(up,))]
    assert len(got) == len(AROUND_TILTS) * AROUND_TURNS
    assert all(float(d @ up) < np.cos(STOPPED_LIFT_ANGLE) for d in got)
    to_mid = (np.asarray(lo) + np.asarray(hi))[:2] / 2 - p[:2]
    assert np.isclose(np.degrees(np.arccos(got[0][2])), AROUND_TILTS[0])
    assert float(got[0][:2] @ to_mid) > 0.99 * np.linalg.norm(got[0][:2]) * np.linalg.norm(to_mid)
    # a tilted stopped lift leaves straight up in place, first
    tilted = np.array([np.sin(np.radians(25)), 0.0, np.cos(np.radians(25))])
    got = [d for d, _ in lift_fallbacks(sink, T, [], set(), near_wall=False, stopped=(tilted,))]
    assert np.allclose(got[0], up) and not any(repeats_stopped(d, (tilted,)) for d in got)
    assert repeats_stopped(0.02 * tilted, (tilted,)) and not repeats_stopped(np.zeros(3), (tilted,))
