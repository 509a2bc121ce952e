"""The fine check remembers, for one map, what it computed from the same inputs (Perceiver._fine_parts): the
checks are repeated after every retry and for the neighbours of each pose that fails, and the parts of a pose
whose inputs did not change are not computed again. Anything a part reads that changes (a neighbour moved,
another map) is computed afresh, to the same values a perceiver with no memo gives."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception import pipeline
from kitchenbot.perception.map import InstanceMap
from kitchenbot.perception.register import Hypothesis
from kitchenbot.perception.verify import Verification
from kitchenbot.transforms import make_T, rot_x


def _cup_surface(entry, T, seed: int = 0) -> np.ndarray:
    """Points of the posed model's surface seen from above and the side, with 0.5 mm of noise."""
    rng = np.random.default_rng(seed)
    P, N = entry.dense_points, entry.dense_normals
    keep = N @ np.array([0.6, 0.0, 0.8]) > 0.2
    return P[keep] @ T[:3, :3].T + T[:3, 3] + rng.normal(0, 0.0005, (keep.sum(), 3)) * (N[keep] @ T[:3, :3].T)


@pytest.fixture
def two_cups(perceiver):
    """Two lying cups end to end along one axis (the second 3 cm further on), as one map."""
    entry = perceiver.database[4]
    T = make_T(rot_x(np.pi / 2)[:3, :3], np.array([0.4, 0.0, 0.05]))
    T2 = T @ make_T(np.eye(3), np.array([0.0, 0.0, -0.03]))
    a, b = _cup_surface(entry, T), _cup_surface(entry, T2, seed=1)
    points = np.vstack([a, b])
    ids = np.r_[np.zeros(len(a), int), np.ones(len(b), int)]
    m = InstanceMap(points, ids, np.zeros(len(points), int), np.zeros((len(points), 2), int),
                    np.array([[0.8, 0.0, 0.6]]))
    return m, ids, T, T2


def _checked(perceiver, m, ids, T, T2) -> list[dict]:
    """The fine check of a cup at T and one at T2 (fresh hypotheses): each one's verification parts."""
    hyps = [Hypothesis(4, T.copy(), verification=Verification(seen=1.0, explained=1.0, free_space=0.0, normals=1.0)),
            Hypothesis(4, T2.copy(), verification=Verification(seen=1.0, explained=1.0, free_space=0.0, normals=1.0))]
    perceiver._fine_check(m, [(h, k, np.nonzero(ids == k)[0]) for k, h in enumerate(hyps)])
    return [h.verification.parts() for h in hyps]


def test_the_fine_check_is_not_computed_again_for_the_same_inputs(perceiver, two_cups, monkeypatch):
    m, ids, T, T2 = two_cups
    calls = []
    real = pipeline.fine_fit
    monkeypatch.setattr(pipeline, "fine_fit", lambda *a, **k: calls.append(1) or real(*a, **k))
    perceiver._fine_ctx = None  # a new scan
    first = _checked(perceiver, m, ids, T, T2)
    n = len(calls)
    assert n >= 2
    # The same poses again (new hypothesis objects, the same values): nothing computed, the same parts.
    assert _checked(perceiver, m, ids, T, T2) == first
    assert len(calls) == n
    # The second cup moved 1 cm along the axis: judged afresh ...
    T3 = T2 @ make_T(np.eye(3), np.array([0.0, 0.0, -0.01]))
    moved = _checked(perceiver, m, ids, T, T3)
    assert len(calls) > n
    assert moved[1] != first[1]
    # ... to what a perceiver with nothing remembered computes.
    perceiver._fine_ctx = None
    assert _checked(perceiver, m, ids, T, T3) == moved


def test_a_new_map_is_not_judged_by_what_another_map_gave(perceiver, two_cups):
    m, ids, T, T2 = two_cups
    perceiver._fine_ctx = None
    first = _checked(perceiver, m, ids, T, T2)
    # The same poses over a map with the second cup's points 1 cm off its pose: its parts are read on them.
    shifted = m.points.copy()
    shifted[ids == 1] += 0.01 * T2[:3, 0]
    m2 = InstanceMap(shifted, m.ids, m.view, m.pixel, m.cam_centres)
    second = _checked(perceiver, m2, ids, T, T2)
    assert second[1]["fine"] < first[1]["fine"]
    perceiver._fine_ctx = None
    assert _checked(perceiver, m2, ids, T, T2) == second


def test_straightness_is_not_judged_again_beside_a_neighbour_out_of_its_reach(perceiver, two_cups, monkeypatch):
    """A pose checked again because a new pose came near (the key of its parts changed) but whose `straight` part
    reads the same inputs (its own points, none claimed by the newcomer, the same pose and neighbours within
    reach) gets the value it was given: straightness is its costliest part (scipy fits)."""
    m, ids, T, T2 = two_cups
    calls = []
    real = pipeline.straightness
    monkeypatch.setattr(pipeline, "straightness", lambda *a, **k: calls.append(1) or real(*a, **k))
    perceiver._fine_ctx = None
    first = _checked(perceiver, m, ids, T, T2)
    n = len(calls)
    assert n == 2
    # A third cup 1.2 diameters from the first across their axis: near enough to change the parts' key (two diameters),
    # too far to be either cup's neighbour in its checks (half the two diameters) or to claim their points.
    d = perceiver.inventory[4].diameter
    T4 = make_T(T[:3, :3], T[:3, 3] + np.array([1.2 * d, 0.0, 0.0]))  # beside it, across the cups' axis
    hyps = [Hypothesis(4, Tk.copy(), verification=Verification(seen=1.0, explained=1.0, free_space=0.0, normals=1.0))
            for Tk in (T, T2, T4)]
    found = [(h, k, np.nonzero(ids == k)[0]) for k, h in enumerate(hyps[:2])] + [(hyps[2], 2, np.zeros(0, int))]
    fine_fits = []
    real_fit = pipeline.fine_fit
    monkeypatch.setattr(pipeline, "fine_fit", lambda *a, **k: fine_fits.append(1) or real_fit(*a, **k))
    perceiver._fine_check(m, found)
    assert [h.verification.parts() for h in hyps[:2]] == first
    assert len(calls) == n
    # (the parts were looked at anew: the key holds the new pose; the fine fit, remembered as it was, is not
    # computed either)
    assert fine_fits == []
    perceiver._fine_ctx = None
