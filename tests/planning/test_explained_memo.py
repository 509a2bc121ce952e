"""CollisionWorld.explained memoises its per-object work by the points' content (planning.collision._ExplainMemo):
one pick or place asks about the same map and poses several times, with a different object explaining its own
points each time. The answers must be those computed afresh, and an ask that differs only in which object
explains its own points must not compute the other objects' surface distances again."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning import collision as col
from kitchenbot.planning.collision import OWN_REACH, SceneObject, _owners, _surface_distance
from kitchenbot.transforms import rot_z, trans


def _fresh(points, objects, explain_radius=0.015, instance_points=(), instance_reach=OWN_REACH,
           self_explaining=None):
    """`explained` without the memo, every distance computed afresh (as in the fourteenth session, but no box
    explains a point of no instance by itself: only the model's surface near it does, sixteenth session)."""
    from scipy.spatial import cKDTree

    P = np.asarray(points, float).reshape(-1, 3)
    hit = np.zeros(len(P), bool)
    n = len(objects)
    own_ok = [True] * n if self_explaining is None else [bool(x) for x in self_explaining] + [True] * n
    owner = _owners(P, instance_points, n)
    inst = []
    for k, o in enumerate(objects):
        bb = o.model.mesh.get_axis_aligned_bounding_box()
        lo, hi = np.asarray(bb.get_min_bound()), np.asarray(bb.get_max_bound())
        Pl = (P - o.T_base_obj[:3, 3]) @ o.T_base_obj[:3, :3]
        in_box = np.all((Pl >= lo - explain_radius) & (Pl <= hi + explain_radius), axis=1)
        cand = in_box & ~hit
        if cand.any():
            hit[np.flatnonzero(cand)[_surface_distance(o.model, Pl[cand]) <= explain_radius]] = True
        if own_ok[k]:
            mine = np.flatnonzero((owner == k) & ~hit)
            if len(mine):
                hit[mine[_surface_distance(o.model, Pl[mine]) <= instance_reach]] = True
            ip = instance_points[k] if k < len(instance_points) else None
            if ip is not None and len(ip):
                ip = np.asarray(ip, float).reshape(-1, 3)
                il = (ip - o.T_base_obj[:3, 3]) @ o.T_base_obj[:3, :3]
                inb = np.all((il >= lo - instance_reach) & (il <= hi + instance_reach), axis=1)
                ip, il = ip[inb], il[inb]
                if len(ip):
                    inst.append(ip[_surface_distance(o.model, il) <= instance_reach])
    if inst and not hit.all():
        may = ~hit & (owner < 0)
        if may.any():
            d, _ = cKDTree(np.vstack(inst)).query(P[may], distance_upper_bound=explain_radius)
            idx = np.flatnonzero(may)
            hit[idx[np.isfinite(d)]] = True
    return hit


def _pile(planner, resting):
    """Three items on the sink floor perceived a little off, their observed points (instances), a fringe of
    points of no instance and a stray cluster: every branch of `explained` has work."""
    rng = np.random.default_rng(5)
    items = [resting("mug", (0.50, 0.02), 1), resting("bowl", (0.58, -0.08), 2), resting("side_plate", (0.44, -0.12), 3)]
    objs, inst, pts = [], [], []
    for o in items:
        m = planner.inventory[o.obj_id]
        mp = np.asarray(m.points, float)
        seen = mp[rng.choice(len(mp), min(900, len(mp)), replace=False)]
        seen = seen @ o.T_base_obj[:3, :3].T + o.T_base_obj[:3, 3] + rng.normal(0, 0.002, seen.shape)
        c = o.T_base_obj[:3, 3]
        off = trans(*(c + [0.012, -0.006, 0.0])) @ rot_z(np.radians(25)) @ trans(*(-c)) @ o.T_base_obj
        objs.append(SceneObject(str(o.instance_id), m, off))
        inst.append(seen)
        pts.append(seen)
    fringe = np.vstack(inst) + rng.normal(0, 0.01, (len(np.vstack(inst)), 3))
    stray = np.array([0.52, -0.3, 0.1]) + rng.normal(0, 0.02, (300, 3))
    P = np.vstack(pts + [fringe[::3], stray])
    return P, objs, inst


def test_memoised_explained_is_the_fresh_answer_and_reuses_the_distances(planner, resting, monkeypatch):
    w = planner.world
    P, objs, inst = _pile(planner, resting)
    col._EXPLAIN_MEMO.__init__()  # nothing from other tests
    calls = []
    real = col._surface_distance
    monkeypatch.setattr(col, "_surface_distance", lambda m, Q: calls.append(len(Q)) or real(m, Q))
    asks = [None, [True, False, False], [False, True, False], [False, False, False], [True, False, False]]
    for k, own in enumerate(asks):
        n0 = sum(calls)
        got = w.explained(P, objs, instance_points=inst, self_explaining=own)
        want = _fresh(P, objs, instance_points=inst, self_explaining=own)
        assert got.dtype == bool and np.array_equal(got, want), own
        assert 0 < want.sum() < len(P)
        if k in (3, 4):  # every distance these need was asked before: none computed again
            assert sum(calls) == n0
    # the same through unexplained_voxels (and a subset of the map: a different point set, computed afresh)
    for own in asks:
        for Q in (P, P[::2]):
            v = w.unexplained_voxels(Q, objs, instance_points=inst, self_explaining=own)
            keep = np.ones(len(Q), bool)
            for b in w.cell.boxes:
                keep &= ~np.all((Q >= b.lower - 0.015) & (Q <= b.upper + 0.015), axis=1)
            keep[keep] = ~_fresh(Q[keep], objs, instance_points=inst, self_explaining=own)
            assert np.array_equal(v, w.occupied_voxels(Q[keep], 3))


def test_a_moved_object_is_computed_afresh(planner, resting):
    """The memo's key holds each object's pose: the same map with one object moved gives the moved answer."""
    w = planner.world
    P, objs, inst = _pile(planner, resting)
    before = w.explained(P, objs, instance_points=inst)
    moved = list(objs)
    moved[1] = SceneObject(objs[1].name, objs[1].model, trans(0.0, 0.0, 0.05) @ objs[1].T_base_obj)
    got = w.explained(P, moved, instance_points=inst)
    assert np.array_equal(got, _fresh(P, moved, instance_points=inst))
    assert not np.array_equal(got, before)


def test_owners_are_kept_per_instance_and_are_the_one_tree_answer(monkeypatch):
    """The owners of a map's points (which instance's observed points each one is) for instance lists that differ
    by one instance (plan_place's held item, the retreat's placed one) query only the changed instance's points;
    the answer is `_owners`' one tree over all instances, ties between two instances (the same points twice)
    included."""
    import scipy.spatial

    rng = np.random.default_rng(3)
    inst = [rng.uniform(-0.1, 0.1, (400, 3)) + c for c in ([0.5, 0.0, 0.1], [0.6, -0.1, 0.1], [0.45, 0.1, 0.12])]
    near = [ip[::4] + rng.normal(0, 3e-5, ip[::4].shape) for ip in inst]  # the map's copies, a little off
    P = np.vstack(near + [rng.uniform(0.3, 0.8, (3000, 3))])
    held = inst[1] + [0.0, 0.0, 0.3]  # the held item: its points where it was (a list of four)
    P = np.vstack([P, held[::5]])
    rows = []
    real = scipy.spatial.cKDTree

    class Counting(real):
        def query(self, x, *a, **k):
            rows.append(len(x))
            return super().query(x, *a, **k)

    monkeypatch.setattr(scipy.spatial, "cKDTree", Counting)
    memo = col._PointsMemo(np.ascontiguousarray(P))
    lists = [inst, inst + [held], inst + [held + [0.001, 0, 0]], inst + [held]]
    for k, ips in enumerate(lists):
        n0 = sum(rows)
        got = memo.owners(ips, len(ips))
        assert np.array_equal(got, _owners(P, ips, len(ips))), k
        assert (got >= 0).sum() >= 250
        if k == 2:  # only the new instance's points near the map asked: not the whole map again
            assert 0 < sum(rows) - n0 - len(P) < len(P) // 4
    # a tie: the same points in two instances (one tree picks either): the one tree's answer
    twice = inst + [inst[0].copy()]
    assert np.array_equal(memo.owners(twice, 4), _owners(P, twice, 4))
