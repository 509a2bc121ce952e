"""Pose tracking across re-scans (perception/track.py) on synthetic views with known poses: a scene scanned again
unchanged keeps its poses with no global search; an item that moved is estimated afresh, the others tracked."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception import pipeline
from kitchenbot.perception.metrics import adi
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses
from kitchenbot.perception.track import KEEP_MIN_POINTS, KEEP_SHARE, KEEP_TOL, MapChange, moved, unchanged
from kitchenbot.transforms import make_T


@pytest.fixture
def screens(monkeypatch):
    """Counts the global search's hypothesis screenings (one per CAD candidate of an instance estimated)."""
    calls = []
    real = pipeline.screen_candidate

    def counted(*a, **kw):
        calls.append(a[1].obj_id)
        return real(*a, **kw)

    monkeypatch.setattr(pipeline, "screen_candidate", counted)
    return calls


def _scene(inventory, cell, mug_xy=(0.38, -0.11)):
    return [(4, resting_pose(inventory, 4, 0.45, 0.09, 0.3, cell)),  # cup
            (2, resting_pose(inventory, 2, 0.56, -0.06, 0.0, cell)),  # side plate
            (5, resting_pose(inventory, 5, *mug_xy, 1.0, cell))]  # mug


def _match(poses, placed, inventory):
    """For each placed item, the ADI error of the pose of its model nearest to it (inf if none)."""
    out = []
    for oid, T in placed:
        errs = [adi(p.T_base_obj, T, inventory[oid].points) for p in poses if p.obj_id == oid]
        out.append(min(errs, default=np.inf))
    return out


def test_a_scene_scanned_again_unchanged_keeps_its_poses_without_a_global_search(perceiver, inventory, cell,
                                                                                 screens):
    placed = _scene(inventory, cell)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    first = perceiver.perceive(views)
    assert len(first.poses) == 3 and first.tracked == 0 and len(screens) > 0
    # the same scene, scanned again (other sensor noise), with the poses believed after the first scan
    again, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002, rng=np.random.default_rng(7))
    screens.clear()
    r = perceiver.perceive(again, priors=first.poses)
    assert screens == [] and r.tracked == 3
    assert sorted(p.obj_id for p in r.poses) == sorted(p.obj_id for p in first.poses)
    for p in r.poses:
        q = next(q for q in first.poses if q.obj_id == p.obj_id)
        assert np.linalg.norm(p.T_base_obj[:3, 3] - q.T_base_obj[:3, 3]) < 0.005
        assert p.verification >= perceiver.settings.verify_threshold
    assert max(_match(r.poses, placed, inventory)) < 0.01


def test_an_item_that_moved_is_estimated_afresh_and_the_others_tracked(perceiver, inventory, cell, screens):
    placed = _scene(inventory, cell)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    first = perceiver.perceive(views)
    assert len(first.poses) == 3
    after = _scene(inventory, cell, mug_xy=(0.40, -0.02))  # the mug was knocked 9 cm
    views2, _ = render(inventory, after, scan_poses(cell), cell, noise=0.002, rng=np.random.default_rng(7))
    screens.clear()
    r = perceiver.perceive(views2, priors=first.poses)
    assert r.tracked == 2
    assert 5 in screens  # the mug went through the global search
    err = _match(r.poses, after, inventory)
    assert max(err) < 0.1 * inventory[5].diameter, err


def test_a_pose_that_went_beyond_the_tolerances_counts_as_moved():
    T = make_T(np.eye(3), [0.4, 0.0, 0.1])
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    yaw30 = make_T(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), [0.4, 0.0, 0.1])
    assert not moved(T, make_T(np.eye(3), [0.405, 0.0, 0.1]), symmetric=False)
    assert moved(T, make_T(np.eye(3), [0.42, 0.0, 0.1]), symmetric=False)
    assert moved(T, yaw30, symmetric=False)
    assert not moved(T, yaw30, symmetric=True)  # a turn about a symmetric model's axis is no move


def test_a_tracked_pose_the_fine_check_rejects_is_estimated_afresh(perceiver, inventory, cell, monkeypatch):
    """A tracked pose that fails the fine check (forced here: the check is made to reject every tracked pose)
    must not make its item vanish from the scan: its instance gets the full estimate, like one no prior explains."""
    placed = _scene(inventory, cell)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    first = perceiver.perceive(views)
    assert len(first.poses) == 3
    real = pipeline.Perceiver._fine_parts

    def rejects_tracked(self, m, tree, tol, hyp, own, found, along=()):
        real(self, m, tree, tol, hyp, own, found, along)
        if hyp.verification is not None and hyp.source.startswith("track"):
            hyp.verification.fine = 0.0

    monkeypatch.setattr(pipeline.Perceiver, "_fine_parts", rejects_tracked)
    again, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002, rng=np.random.default_rng(7))
    r = perceiver.perceive(again, priors=first.poses)
    assert sorted(p.obj_id for p in r.poses) == sorted(oid for oid, _ in placed)
    assert max(_match(r.poses, placed, inventory)) < 0.01


def test_a_tracked_query_computes_no_point_features_and_gives_the_same_poses(perceiver, inventory, cell,
                                                                            monkeypatch):
    """Tracking only registers and scores its query (points, normals, colour): the point encoder (FPFH, most of
    the query's cost) is not run for it, and the poses are bitwise those of a query built with the features."""
    placed = _scene(inventory, cell)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    first = perceiver.perceive(views)
    again, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002, rng=np.random.default_rng(7))
    encoded = []
    real_encode = perceiver.pt_enc.encode

    def counted(P, N, voxel):
        encoded.append(len(P))
        return real_encode(P, N, voxel)

    monkeypatch.setattr(perceiver.pt_enc, "encode", counted)
    r = perceiver.perceive(again, priors=first.poses)
    assert r.tracked == 3 and encoded == []
    # the same scan with every tracked query built with its point features (as before): the same poses
    real_query = pipeline.Perceiver._query
    monkeypatch.setattr(pipeline.Perceiver, "_query",
                        lambda self, inst, views, point_features=True: real_query(self, inst, views))
    r2 = perceiver.perceive(again, priors=first.poses)
    assert r2.tracked == 3 and len(encoded) == 3
    key = lambda p: (p.obj_id, tuple(p.T_base_obj[:3, 3]))  # noqa: E731
    for p, q in zip(sorted(r.poses, key=key), sorted(r2.poses, key=key)):
        assert p.obj_id == q.obj_id and np.array_equal(p.T_base_obj, q.T_base_obj)
        assert p.score == q.score and p.verification == q.verification


@pytest.fixture
def fine_checked(monkeypatch):
    """Counts the fine check's per-pose work (Perceiver._fine_parts), by model id."""
    calls = []
    real = pipeline.Perceiver._fine_parts

    def counted(self, m, tree, tol, hyp, own, found, along=()):
        calls.append(hyp.obj_id)
        return real(self, m, tree, tol, hyp, own, found, along)

    monkeypatch.setattr(pipeline.Perceiver, "_fine_parts", counted)
    return calls


def test_a_scene_scanned_again_unchanged_keeps_its_poses_as_they_were_unchecked(perceiver, inventory, cell,
                                                                                screens, fine_checked):
    """With the map the priors were perceived on, a re-scan of an unchanged scene keeps every prior as it was:
    the same pose, score and verification, no refinement, no fine check (before: each was refined and checked)."""
    placed = _scene(inventory, cell)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    first = perceiver.perceive(views)
    assert len(first.poses) == 3
    again, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002, rng=np.random.default_rng(7))
    screens.clear()
    fine_checked.clear()
    r = perceiver.perceive(again, priors=first.poses, prior_map=first.map_points)
    assert screens == [] and fine_checked == []
    assert r.tracked == 3 and r.kept == 3
    for p in r.poses:
        q = next(q for q in first.poses if q.obj_id == p.obj_id)
        assert np.array_equal(p.T_base_obj, q.T_base_obj)
        assert p.score == q.score and p.verification == q.verification and p.checks == q.checks
    # without the map (as before this change) every pose is refined and checked again
    r2 = perceiver.perceive(again, priors=first.poses)
    assert r2.tracked == 3 and r2.kept == 0 and sorted(fine_checked) == sorted(p.obj_id for p in r2.poses)


def test_after_an_item_is_taken_away_only_the_poses_around_its_place_are_checked_again(perceiver, inventory, cell,
                                                                                       screens, fine_checked):
    """The mug is taken away (a pick): the side plate, whose surroundings held the mug, is tracked and checked
    again; the cup, far from the mug, is kept as it was. No global search for either."""
    placed = _scene(inventory, cell)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    first = perceiver.perceive(views)
    assert len(first.poses) == 3
    after = [it for it in placed if it[0] != 5]
    priors = [p for p in first.poses if p.obj_id != 5]  # the belief after the pick
    again, _ = render(inventory, after, scan_poses(cell), cell, noise=0.002, rng=np.random.default_rng(7))
    screens.clear()
    fine_checked.clear()
    r = perceiver.perceive(again, priors=priors, prior_map=first.map_points)
    assert screens == [] and r.tracked == 2 and r.kept == 1
    assert fine_checked == [2]  # the side plate only
    cup = next(p for p in r.poses if p.obj_id == 4)
    assert np.array_equal(cup.T_base_obj, next(q for q in first.poses if q.obj_id == 4).T_base_obj)
    assert sorted(p.obj_id for p in r.poses) == [2, 4]
    assert max(_match(r.poses, after, inventory)) < 0.01


def test_surroundings_are_unchanged_within_the_noise_and_changed_by_a_hole_or_new_points():
    rng = np.random.default_rng(0)
    g = np.stack(np.meshgrid(np.arange(0, 0.2, 0.002), np.arange(0, 0.2, 0.002)), -1).reshape(-1, 2)
    before = np.column_stack([g, np.zeros(len(g))])
    noisy = before + rng.normal(0, 0.001, before.shape)
    centre, r = np.array([0.1, 0.1, 0.0]), 0.08
    assert unchanged(noisy, before, centre, r)
    hole = noisy[np.linalg.norm(noisy[:, :2] - [0.1, 0.13], axis=1) > 0.03]  # an item taken away
    assert not unchanged(hole, before, centre, r)
    added = np.vstack([noisy, before[np.linalg.norm(before[:, :2] - [0.1, 0.13], axis=1) < 0.03] + [0, 0, 0.02]])
    assert not unchanged(added, before, centre, r)  # something put there
    assert unchanged(hole, before, np.array([0.02, 0.02, 0.0]), 0.03)  # far from the change


def test_a_pose_whose_grasp_missed_is_not_kept_unchecked(perceiver, inventory, cell):
    """A side plate believed 4 cm from where it lies (a wrong fit the belief carried): a grasp of it closes on
    air, which changes no map point, so the next scan kept the wrong pose as it was and every grasp of its ring
    missed in turn. After the miss the belief doubts the pose (executive Belief.doubt: its verification's parts
    dropped): the next perception checks it again and does not return the wrong pose."""
    from dataclasses import replace

    from kitchenbot.executive.belief import Belief

    placed, first, again, plate, off = _plate_believed_off(perceiver, inventory, cell)
    wrong = replace(plate, T_base_obj=off, checks=dict(plate.checks))
    priors = [wrong if p is plate else p for p in first.poses]
    # (kept as it was, the mechanism of the misses, until the refit of a pose that leaves part of its item beside
    # it: test_a_kept_pose_that_leaves_part_of_its_item_unexplained_is_fitted_again)
    b = Belief(poses=priors)
    b.doubt(wrong)
    r = perceiver.perceive(again, priors=b.poses, prior_map=first.map_points)
    assert not any(np.array_equal(p.T_base_obj, off) for p in r.poses)
    assert r.kept == 2


def test_a_kept_pose_that_leaves_part_of_its_item_unexplained_is_fitted_again(perceiver, inventory, cell):
    """A side plate believed 4 cm from where it lies, its surroundings unchanged: the prior was kept as it was
    (no check), and the crescent of the plate beyond the believed rim, which no model explains alone, stayed an
    unrecognised thing beside it, scan after scan (before: the wrong pose returned). The cluster lies within the
    pose's reach: fitted with the pose's own points, the plate is found where it lies; the cup and the mug, with
    nothing left over beside them, are kept as they were (perception/refit.py)."""
    from dataclasses import replace

    placed, first, again, plate, off = _plate_believed_off(perceiver, inventory, cell)
    priors = [replace(plate, T_base_obj=off, checks=dict(plate.checks)) if p is plate else p for p in first.poses]
    r = perceiver.perceive(again, priors=priors, prior_map=first.map_points)
    assert not any(np.array_equal(p.T_base_obj, off) for p in r.poses)
    assert sorted(p.obj_id for p in r.poses) == [2, 4, 5]
    assert max(_match(r.poses, placed, inventory)) < 0.01
    for p in r.poses:
        if p.obj_id != 2:  # the good poses are not churned
            assert np.array_equal(p.T_base_obj, next(q for q in first.poses if q.obj_id == p.obj_id).T_base_obj)


def _plate_believed_off(perceiver, inventory, cell):
    """The three-item scene perceived once, a second scan of it unchanged, its side plate's pose and that pose
    4 cm off along x: (the placed items, first result, second views, plate pose, the pose off)."""
    placed = _scene(inventory, cell)
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    first = perceiver.perceive(views)
    assert len(first.poses) == 3
    plate = next(p for p in first.poses if p.obj_id == 2)
    off = plate.T_base_obj.copy()
    off[0, 3] += 0.04
    again, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002, rng=np.random.default_rng(7))
    return placed, first, again, plate, off


def _unchanged_per_prior(now, before, centre, radius, tol=KEEP_TOL, share=KEEP_SHARE):
    """The comparison as each prior made it before `MapChange`: trees of both maps' points within its reach."""
    from scipy.spatial import cKDTree

    def within(P, r):
        return P[np.sum((P - centre) ** 2, axis=1) <= r ** 2]

    a, b = within(now, radius), within(before, radius)
    if len(a) < KEEP_MIN_POINTS or len(b) < KEEP_MIN_POINTS:
        return False
    for P, Q in ((a, within(before, radius + tol)), (b, within(now, radius + tol))):
        if len(Q) == 0 or np.isfinite(cKDTree(Q).query(P, distance_upper_bound=tol)[0]).mean() < share:
            return False
    return True


def test_one_comparison_of_the_two_maps_answers_every_prior_as_its_own_comparison_did(monkeypatch):
    """`MapChange` compares the maps once per scan; for every centre and radius its answer is the answer of the
    comparison each prior made of the points within its reach (a hole, points added, points moved by a few
    millimetres, the border of the radius at the tolerance), and it builds one tree per map, not two per prior."""
    from kitchenbot.perception import track as track_mod

    rng = np.random.default_rng(3)
    g = np.stack(np.meshgrid(np.arange(0, 0.3, 0.003), np.arange(0, 0.3, 0.003)), -1).reshape(-1, 2)
    before = np.column_stack([g, 0.01 * np.sin(20 * g[:, 0])])
    now = before + rng.normal(0, 0.0012, before.shape)
    now = now[np.linalg.norm(now[:, :2] - [0.20, 0.12], axis=1) > 0.035]  # an item taken away
    patch = before[np.linalg.norm(before[:, :2] - [0.08, 0.22], axis=1) < 0.03]
    now = np.vstack([now, patch + [0, 0, 0.03], patch[::3] + [0.0, 0.0, 0.005]])  # something put there; a shift
    trees = []
    real = track_mod.cKDTree

    def counted(*a, **kw):
        trees.append(len(a[0]))
        return real(*a, **kw)

    monkeypatch.setattr(track_mod, "cKDTree", counted)
    change = MapChange(now, before)
    assert len(trees) == 2
    answers = []
    for centre in rng.uniform([0.0, 0.0, 0.0], [0.3, 0.3, 0.01], (60, 3)):
        for radius in (0.01, 0.04, 0.09, 0.16):
            for share in (0.9, KEEP_SHARE, 0.99):
                want = _unchanged_per_prior(now, before, centre, radius, share=share)
                assert change.unchanged(centre, radius, share) == want, (centre, radius, share)
                answers.append(want)
    assert len(trees) == 2  # no tree per question
    assert any(answers) and not all(answers)  # both answers were asked for


def _sink_of_five(inventory, cell):
    lo, hi = cell.sink_interior
    c = (lo + hi) / 2
    return [(1, resting_pose(inventory, 1, c[0] - 0.07, c[1] - 0.10, 0.0, cell)),  # dinner plate
            (3, resting_pose(inventory, 3, c[0] + 0.09, c[1] + 0.10, 0.0, cell)),  # bowl
            (4, resting_pose(inventory, 4, c[0] - 0.10, c[1] + 0.12, 0.3, cell)),  # cup
            (5, resting_pose(inventory, 5, c[0] + 0.10, c[1] - 0.05, 1.0, cell)),  # mug, partly on the plate
            (6, resting_pose(inventory, 6, c[0] + 0.0, c[1] + 0.02, 0.0, cell))]  # glass


def _after_taking(first, oid):
    """The belief after a pick, as the executive hands it to the next scan: every pose (the picked one too: it
    is dropped only when a perception follows) and the map less the points the picked item explained."""
    from scipy.spatial import cKDTree

    taken = next(p for p in first.poses if p.obj_id == oid)
    d, _ = cKDTree(taken.points).query(first.map_points, distance_upper_bound=0.003)
    return list(first.poses), first.map_points[~np.isfinite(d)]


def test_surface_a_picked_item_hid_on_a_known_neighbour_leaves_the_other_poses_kept(perceiver, inventory, cell,
                                                                                    screens, fine_checked):
    """The mug is picked off the dinner plate's rim: the re-scan sees the plate's surface that the mug hid. Those
    new points lie on the surface of a prior still seen where it was, so the glass, whose surroundings hold them
    (~5 % of them new), is kept as it was, with no refinement and no fine check (before, it was refined and
    checked again). The plate itself is seen more than when it was perceived: it is refined and checked again,
    and its visible fraction (what grasp selection reads of how buried it is) is made anew. The mug's own prior,
    not seen any more, explains nothing."""
    placed = _sink_of_five(inventory, cell)
    first = perceiver.perceive(render(inventory, placed, scan_poses(cell), cell, noise=0.002)[0])
    assert sorted(p.obj_id for p in first.poses) == [1, 3, 4, 5, 6]
    priors, prior_map = _after_taking(first, 5)
    after = [it for it in placed if it[0] != 5]
    views, _ = render(inventory, after, scan_poses(cell), cell, noise=0.002, rng=np.random.default_rng(7))
    screens.clear()
    fine_checked.clear()
    r = perceiver.perceive(views, priors=priors, prior_map=prior_map)
    assert screens == [] and fine_checked == [1]
    assert r.kept == 3 and sorted(p.obj_id for p in r.poses) == [1, 3, 4, 6]
    for p in r.poses:
        q = next(q for q in first.poses if q.obj_id == p.obj_id)
        if p.obj_id == 1:
            assert p.visible_fraction > q.visible_fraction
            assert np.linalg.norm(p.T_base_obj[:3, 3] - q.T_base_obj[:3, 3]) < 0.005
        else:
            assert np.array_equal(p.T_base_obj, q.T_base_obj) and p.checks == q.checks


def test_an_item_put_where_the_picked_one_was_is_a_change_for_the_priors_around_it(perceiver, inventory, cell,
                                                                                  screens, fine_checked):
    """The mug is picked and a side plate lies where it stood: no prior puts the side plate's points on its
    surface (the mug's prior is not seen any more), so the priors whose surroundings hold them are refined and
    checked again, and the side plate is estimated."""
    placed = _sink_of_five(inventory, cell)
    first = perceiver.perceive(render(inventory, placed, scan_poses(cell), cell, noise=0.002)[0])
    priors, prior_map = _after_taking(first, 5)
    mug_xy = next(T for oid, T in placed if oid == 5)[:2, 3]
    after = [it for it in placed if it[0] != 5] + [(2, resting_pose(inventory, 2, *mug_xy, 0.0, cell))]
    views, _ = render(inventory, after, scan_poses(cell), cell, noise=0.002, rng=np.random.default_rng(7))
    screens.clear()
    fine_checked.clear()
    r = perceiver.perceive(views, priors=priors, prior_map=prior_map)
    assert 2 in screens and 2 in [p.obj_id for p in r.poses]
    assert r.kept < 4 and 1 in fine_checked  # the dinner plate, under the side plate's edge, checked again
