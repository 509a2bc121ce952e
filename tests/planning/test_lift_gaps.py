"""A lift's signed gaps are computed once per pair for both checks that read them (planning/lift_gaps.py).

Hand-made: a stand-in scene whose signed gaps along a lift are given per pair (as Scene.signed_gaps returns them:
one value per half-step sample, m, negative where the fitted poses overlap) and which counts what it is asked. The
held item touches a trusted plate, whose gap opens steadily, and a bowl whose pose is doubtful, whose gap opens to
4 mm and narrows back to 2.5 mm above the start's: more than the fits' reach (Planner.FIT_POSE_REACH) but within the
doubtful pose's error (doubtful_support.POSE_ERROR). _remade_in_fit reads both profiles and then hands the bowl's to
_may_meet_doubtful_again, which refuses the lift for it. Before, that second check asked the scene for the bowl's
profile again (the same samples, pair and span): ~12 mesh collision checks per sample, twice."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.doubtful_support import POSE_ERROR
from kitchenbot.planning.lift_gaps import LiftGaps, half_steps
from kitchenbot.planning.pick_place import Planner

PLATE = ("held", "obj:side_plate_0")
BOWL = ("held", "obj:bowl_1")
Q = np.array([[0.1 * k, -1.5, 2.0, -1.5, -1.1, 0.1] for k in range(4)])  # a lift of 4 states: 7 half-step samples
MM = 0.001


class GapsScene:
    """A scene stand-in: Scene.signed_gaps from given profiles; every call recorded."""

    def __init__(self, profiles: dict):
        self.profiles = profiles
        self.asked: list[tuple[tuple[str, str], np.ndarray, float]] = []

    def signed_gaps(self, Q, pair, span):
        self.asked.append((tuple(pair), np.asarray(Q, float).copy(), span))
        return np.clip(np.asarray(self.profiles[tuple(pair)], float), -span, span)


def _scene():
    return GapsScene({PLATE: np.array([0.0, 0.5, 1.0, 1.6, 2.2, 2.9, 3.5]) * MM,  # parting steadily
                      BOWL: np.array([0.0, 1.0, 2.5, 4.0, 3.2, 2.5, 3.0]) * MM})  # parts, narrows to +2.5 mm


def test_the_doubtful_neighbours_gaps_are_computed_once_for_both_checks():
    planner = object.__new__(Planner)  # the two checks read only the class's constants
    scene = _scene()
    hit = planner._remade_in_fit(scene, Q, [PLATE, BOWL], doubtful={"obj:bowl_1"})
    assert hit == BOWL  # refused for the doubtful bowl's error, as before
    assert [p for p, _, _ in scene.asked] == [PLATE, BOWL]  # each pair's profile once (before: the bowl's twice)
    for _, samples, span in scene.asked:
        assert np.array_equal(samples, half_steps(Q)) and span == 2 * POSE_ERROR
    # a caller that asks both checks itself hands them one LiftGaps: the bowl's profile again read, not recomputed
    scene = _scene()
    gaps = LiftGaps(scene, Q)
    assert planner._remade_in_fit(scene, Q, [PLATE], gaps=gaps) is None  # the trusted plate parts steadily
    assert planner._may_meet_doubtful_again(scene, Q, [PLATE, BOWL], {"obj:bowl_1"}, gaps) == BOWL
    assert planner._may_meet_doubtful_again(scene, Q, [PLATE, BOWL], {"obj:bowl_1"}, gaps) == BOWL
    assert [p for p, _, _ in scene.asked] == [PLATE, BOWL]


def test_without_the_doubt_the_same_profiles_pass():
    """The same lift, the bowl trusted: 2.5 mm back above the start is beyond the fits' reach; the lift passes."""
    planner = object.__new__(Planner)
    scene = _scene()
    assert planner._remade_in_fit(scene, Q, [PLATE, BOWL]) is None
    assert [p for p, _, _ in scene.asked] == [PLATE, BOWL]


def test_lift_gaps_are_kept_per_pair_and_per_lift():
    """Another pair is another profile; another lift (a LiftGaps of other configurations) asks the scene again."""
    scene = _scene()
    gaps = LiftGaps(scene, Q)
    assert np.array_equal(gaps.of(BOWL), scene.profiles[BOWL])
    assert np.array_equal(gaps.of(PLATE), scene.profiles[PLATE])
    assert np.array_equal(gaps.of(list(BOWL)), scene.profiles[BOWL])  # the same pair given as a list
    assert len(scene.asked) == 2
    other = LiftGaps(scene, Q[:2])
    other.of(BOWL)
    assert len(scene.asked) == 3 and np.array_equal(scene.asked[-1][1], half_steps(Q[:2]))
    assert len(half_steps(Q)) == 2 * len(Q) - 1
