"""The grid that settles "within r of a model's surface" (planning.collision._near_by_grid): one per model, shared
by every radius, its cells' distances computed when a point first falls in them. Whether a point is near (what
CollisionWorld.explained asks of each map point) must be the exact distance's answer at every radius, for points
the grid settles (surely near, surely far) and points it leaves to the exact query alike."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning import collision as col
from kitchenbot.planning.collision import SceneObject, _surface_distance
from kitchenbot.transforms import rot_z, trans


def _points_around(model, rng, n=4000):
    """Points in the object frame around the model: on its surface (a little noise), in its box, and beyond the
    grid's reach."""
    bb = model.mesh.get_axis_aligned_bounding_box()
    lo, hi = np.asarray(bb.get_min_bound()), np.asarray(bb.get_max_bound())
    surf = np.asarray(model.points, float)
    surf = surf[rng.choice(len(surf), min(n // 2, len(surf)), replace=False)] + rng.normal(0, 0.006, (min(n // 2, len(surf)), 3))
    box = rng.uniform(lo - 0.06, hi + 0.06, (n // 2, 3))
    return np.vstack([surf, box])


def test_near_by_the_grid_is_the_exact_answer_at_every_radius(planner, monkeypatch):
    rng = np.random.default_rng(11)
    model = planner.inventory[next(iter(planner.inventory.models))]
    monkeypatch.setattr(col, "_NEAR_GRIDS", {})
    T = trans(0.5, -0.1, 0.05) @ rot_z(0.7)
    Pl = _points_around(model, rng)
    P = Pl @ T[:3, :3].T + T[:3, 3]
    exact = _surface_distance(model, Pl)
    calls = []
    real = col._surface_distance
    monkeypatch.setattr(col, "_surface_distance", lambda m, Q: calls.append(len(Q)) or real(m, Q))
    ob = col._ObjectPoints(P, SceneObject("x", model, T), 0.015)
    idx = np.arange(len(P))
    for r in (0.005, 0.0123, 0.015, 0.027, 0.04, 0.055):  # fit radii, the explain radius, OWN_REACH and beyond it
        fresh = col._ObjectPoints(P, SceneObject("x", model, T), r)
        got = fresh.near(idx, r)
        assert np.array_equal(got, exact <= r), r
        assert 0 < got.sum() < len(P)
    # the grid settled most points: far fewer exact queries than points asked about
    settled, far = col._near_by_grid(model, Pl, 0.015)
    assert (settled | far).mean() > 0.6
    # the cells' distances are kept: asking again computes nothing
    n = len(calls)
    assert np.array_equal(ob.near(idx, 0.02), exact <= 0.02)
    assert len(calls) == n + 1  # only the exact distances of the points the grid left open (one query)
    col._near_by_grid(model, Pl, 0.03)
    assert len(calls) == n + 1
