"""Work the pose search asked for twice is done once, on a hand-made scene: a screening start given twice is fitted
and scored once, and a scorer asked again for a pose it scored answers from what it computed; the answers are the
ones computed afresh."""

from __future__ import annotations

import numpy as np
import pytest

import kitchenbot.perception.pipeline as pl
import kitchenbot.perception.register as rg
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses

MUG = 5


@pytest.fixture(scope="module")
def mug_screening(perceiver, inventory, cell):
    """The arguments of the mug's screening in a scan of one mug (query, entry, model, scorer, config, up)."""
    views = render(inventory, [(MUG, resting_pose(inventory, MUG, 0.45, 0.05, 0.7, cell))], scan_poses(cell), cell,
                   noise=0.002)[0]
    calls = []
    screen = pl.screen_candidate

    def record(query, entry, model, scorer, cfg, up, *a, **k):
        if entry.obj_id == MUG:
            calls.append((query, entry, model, scorer, cfg, up))
        return screen(query, entry, model, scorer, cfg, up, *a, **k)

    mp = pytest.MonkeyPatch()
    mp.setattr(pl, "screen_candidate", record)
    try:
        poses = perceiver.perceive(views).poses
    finally:
        mp.undo()
    assert [p.obj_id for p in poses] == [MUG] and calls
    return calls[0], poses[0].T_base_obj


def test_same_starts_tells_starts_apart_exactly():
    T = np.eye(4)
    U = T.copy()
    U[0, 3] += 1e-12  # another start, however near
    first, where = rg.same_starts([(T, False), (U, False), (T.copy(), False), (T, True), (U, False)])
    assert first == [0, 1, 3]
    assert where == [0, 1, 0, 2, 1]


def test_a_start_given_twice_is_fitted_and_scored_once(mug_screening, monkeypatch):
    # The mug's pose found, handed to the screening twice (two poses found at one place): its stacking starts
    # (the pose shifted along its axis) come twice. Each is fitted once, and every start keeps its own entry with
    # the answer a screening without the repeat gives it.
    (query, entry, model, scorer, cfg, up), T_mug = mug_screening
    sizes = []
    icp = rg.icp_batch

    def counted(q, e, T0, *a, **k):
        sizes.append(len(T0))
        return icp(q, e, T0, *a, **k)

    monkeypatch.setattr(rg, "icp_batch", counted)
    once = rg.screen_candidate(query, entry, model, scorer, cfg, up, [T_mug])
    n_once = sum(sizes)
    sizes.clear()
    twice = rg.screen_candidate(query, entry, model, scorer, cfg, up, [T_mug, T_mug.copy()])
    assert sum(sizes) == n_once  # the repeated stacking starts were not fitted again
    stacks = [t for t in twice if t[1] == "stack"]
    assert len(stacks) == 2 * len([t for t in once if t[1] == "stack"]) > 0
    # every start answered as without the repeat (each stacking start's answer comes twice)
    key = lambda t: (t[0], t[1], t[2].tobytes())  # noqa: E731
    from collections import Counter
    c_once, c_twice = Counter(map(key, once)), Counter(map(key, twice))
    assert set(c_once) == set(c_twice)
    assert all(c_twice[k] == c_once[k] * (2 if k[1] == "stack" else 1) for k in c_once)


def test_a_pose_scored_again_is_not_computed_again(mug_screening, monkeypatch):
    (query, entry, model, scorer, cfg, up), T_mug = mug_screening
    fresh = rg.Scorer(entry, query.points, scorer.views, scorer.eps, inside_solid=scorer.inside_solid,
                      depths=scorer.depths)
    batches = []
    batch = rg.Scorer.batch

    def counted(self, T, coarse=False):
        batches.append(len(T))
        return batch(self, T, coarse)

    monkeypatch.setattr(rg.Scorer, "batch", counted)
    a = fresh(T_mug)
    b = fresh(T_mug.copy())
    c = fresh(T_mug, coarse=True)
    assert batches == [1, 1]  # the second full score of the same pose was remembered; the coarse one is another
    assert a == b and a == tuple(float(x[0]) for x in batch(fresh, T_mug[None]))
    moved = T_mug.copy()
    moved[2, 3] += 0.003
    assert fresh(moved) != a and len(batches) == 3
    assert c == tuple(float(x[0]) for x in batch(fresh, T_mug[None], True))


def test_a_pick_that_is_an_earlier_picks_pose_is_not_refined_again(perceiver, inventory, cell, monkeypatch):
    # The screening hands one pose up under two names (a yaw turn of the best hypothesis that is also the best
    # tilted one): the estimate refines it once, and finds what it finds without the repeat.
    views = render(inventory, [(MUG, resting_pose(inventory, MUG, 0.45, 0.05, 0.7, cell))], scan_poses(cell), cell,
                   noise=0.002)[0]
    screen = pl.screen_candidate

    def repeated(*a, **k):
        out = screen(*a, **k)
        return [out[0], (out[0][0], out[0][1] + "-again", out[0][2].copy())] + out[1:]

    refined = []
    refine = pl.refine

    def logged(query, entry, scorer, T, *a, **k):
        refined.append((query.points.tobytes(), entry.obj_id, np.asarray(T).tobytes(), k.get("upright", False),
                        k.get("local", False)))
        return refine(query, entry, scorer, T, *a, **k)

    monkeypatch.setattr(pl, "refine", logged)
    plain = perceiver.perceive(views).poses
    monkeypatch.setattr(pl, "screen_candidate", repeated)
    refined.clear()
    again = perceiver.perceive(views).poses
    assert len(refined) == len(set(refined))  # no pose refined twice with the same settings
    assert [p.obj_id for p in again] == [p.obj_id for p in plain] == [MUG]
    assert np.array_equal(again[0].T_base_obj, plain[0].T_base_obj) and again[0].score == plain[0].score
