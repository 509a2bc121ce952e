"""The unexplained map voxels of one pick and place, computed once where the question is the same (twenty-sixth
session): the held item is the query's `exclude` too (plan_place, plan_move, escape), and was listed twice among the
objects that explain the map, a different cache key from the pick's same question (every point of it a tie between
the two copies, settled by a tree over the whole map); and an instance's own points' distances to its fitted model
are computed once for the fit radius and every reach asked. The answers are those computed afresh."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kitchenbot.planning import collision as col
from kitchenbot.planning.collision import SceneObject, _surface_distance
from kitchenbot.planning.types import Grasp
from kitchenbot.transforms import trans


def _seen(model, T, n, rng, off=(0.0, 0.0, 0.0)):
    """`n` of the model's points where the item lies (a little off and noisy, as perceived)."""
    mp = np.asarray(model.points, float)
    p = mp[rng.choice(len(mp), min(n, len(mp)), replace=False)] @ T[:3, :3].T + T[:3, 3]
    return p + np.asarray(off) + rng.normal(0, 0.002, p.shape)


def _pile(planner, resting):
    rng = np.random.default_rng(11)
    items = [resting("bowl", (0.50, 0.0), 1), resting("mug", (0.60, -0.10), 2), resting("side_plate", (0.42, -0.12), 3)]
    out = []
    for o in items:
        pts = _seen(planner.inventory[o.obj_id], o.T_base_obj, 800, rng, (0.004, -0.003, 0.0))
        out.append(replace(o, points=pts))
    stray = np.array([0.55, -0.25, 0.12]) + rng.normal(0, 0.01, (200, 3))  # something nobody perceived
    return out, np.vstack([o.points for o in out] + [stray])


def test_the_held_item_listed_once_asks_the_picks_question_again(planner, resting, monkeypatch):
    """plan_place's scene (the others, the held item excluded and held) asks the voxels of the same explaining set
    as the pick's lift scene (every object, the target excluded and held): one computation, the same voxels.
    Before, the held item was listed twice (as `exclude` and as the held one): a second computation."""
    objs, P = _pile(planner, resting)
    target = objs[0]
    spec = planner.inventory[target.obj_id].grasps[0]
    T_tcp = target.T_base_obj @ spec.T_obj_tcp
    g = Grasp(spec, target, T_tcp, np.zeros(6), np.zeros(6), T_tcp)
    planner._voxel_cache.clear()
    col._EXPLAIN_MEMO.__init__()
    calls = []
    real = planner.world.unexplained_voxels
    monkeypatch.setattr(planner.world, "unexplained_voxels", lambda *a, **k: calls.append(1) or real(*a, **k))
    lift = planner.scene(objs, P, exclude=target, held=g, own=[target])  # _plan_pick_with's held scene
    others = [o for o in objs if o is not target]
    place = planner.scene(others, P, exclude=target, held=g, own=[target])  # plan_place's
    assert len(calls) == 1
    assert len(lift.voxels) > 0 and np.array_equal(place.voxels, lift.voxels)
    # and the held item listed twice explains what it explains listed once (the answer the cache now gives)
    so = planner._scene_objects(objs)
    inst = [o.points for o in objs]
    once = planner.world.explained(P, so, instance_points=inst, self_explaining=[True, False, False])
    twice = planner.world.explained(P, so + so[:1], instance_points=inst + inst[:1],
                                    self_explaining=[True, False, False, True])
    assert np.array_equal(once, twice)


def test_own_points_distances_are_computed_once_for_every_reach(planner, resting, monkeypatch):
    """An instance's own points near its fitted model at several reaches (the fit radius's own reach differs
    between items and scans) and its fit radius: one distance query over its points, the answers those computed
    afresh. A moved pose is a new question."""
    objs, _ = _pile(planner, resting)
    o = objs[1]
    m = planner.inventory[o.obj_id]
    so = SceneObject("2", m, trans(0.006, 0.0, 0.0) @ o.T_base_obj)
    ip = o.points
    bb = m.mesh.get_axis_aligned_bounding_box()
    lo, hi = np.asarray(bb.get_min_bound()), np.asarray(bb.get_max_bound())
    col._EXPLAIN_MEMO.__init__()
    rows = []
    monkeypatch.setattr(col, "_surface_distance", lambda mm, Q: rows.append(len(Q)) or _surface_distance(mm, Q))
    T = so.T_base_obj
    il = (ip - T[:3, 3]) @ T[:3, :3]
    for reach in (0.04, 0.012, 0.007, 0.025):
        got = col._EXPLAIN_MEMO.own_points_near(so, ip, lo, hi, reach)
        inb = np.all((il >= lo - reach) & (il <= hi + reach), axis=1)
        want = ip[inb][_surface_distance(m, il[inb]) <= reach]
        assert np.array_equal(got, want), reach
    d = _surface_distance(m, il)
    spread = max(col.FIT_RADIUS_MIN, np.ceil(col.FIT_SPREAD * float(np.percentile(d, 90)) / col.FIT_RADIUS_STEP - 1e-9)
                 * col.FIT_RADIUS_STEP)
    assert col._EXPLAIN_MEMO.fit_radii(so, ip, 0.015, col.OWN_REACH) == (min(0.015, spread), min(col.OWN_REACH, spread))
    assert rows == [len(ip)]  # one query for the reaches and the fit (before: one per reach, one for the fit)
    moved = SceneObject("2", m, trans(0.0, 0.01, 0.0) @ so.T_base_obj)
    col._EXPLAIN_MEMO.own_points_near(moved, ip, lo, hi, 0.012)
    assert rows == [len(ip), len(ip)]
