"""The re-fit beside what is left (perception/refit.py): what it costs on re-scans. A re-fit that failed (a right
pose beside a thing no model explains) is not tried again while the pose and the points are the same; it is tried
again as soon as the points change."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from kitchenbot.perception import refit
from kitchenbot.perception.refit import RefitMemo
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses
from kitchenbot.transforms import make_T


@pytest.fixture
def fits(monkeypatch):
    """The poses whose re-fit was attempted (model ids), one per (pose, cluster) pair fitted."""
    calls = []
    real = refit._fits

    def counted(per, inst, views, hyp, found):
        calls.append(hyp.obj_id)
        return real(per, inst, views, hyp, found)

    monkeypatch.setattr(refit, "_fits", counted)
    return calls


def _cup_and_brick(inventory, cell, brick_x: float, rng: int):
    """Views of a cup with a brick (no model of it) beside it, within the cup's reach; the cup's true pose."""
    cup = resting_pose(inventory, 4, 0.40, -0.10, 0.0, cell)
    brick = o3d.geometry.TriangleMesh.create_box(0.10, 0.06, 0.05)
    brick.translate([brick_x, -0.13, cell.sink_interior[0][2]])
    views, _ = render(inventory, [(4, cup)], scan_poses(cell), cell, noise=0.002, rng=np.random.default_rng(rng),
                      extra=[(brick, (0.9, 0.8, 0.1))])
    return views, cup


def test_a_failed_refit_is_not_tried_again_while_nothing_changed(perceiver, inventory, cell, fits):
    perceiver.refit_memo = RefitMemo()  # the session's perceiver: nothing remembered from other tests
    views, cup = _cup_and_brick(inventory, cell, 0.455, rng=1)
    first = perceiver.perceive(views)
    assert [p.obj_id for p in first.poses] == [4] and first.rejected >= 1
    assert np.linalg.norm(first.poses[0].T_base_obj[:3, 3] - cup[:3, 3]) < 0.01
    assert fits == [4]  # the brick's points, unexplained within the cup's reach: the cup was fitted with them
    # the full estimate of a pose fitted again searches its own model only
    cup_pts = first.map.select(np.nonzero(first.map.ids == first.poses[0].instance_id)[0])
    assert perceiver.estimate(cup_pts, views)[0].obj_id == 4
    mug = perceiver.estimate(cup_pts, views, model=5)[0]
    assert mug is None or mug.obj_id == 5
    # the same scene scanned again (other noise): the cup kept as it was, the brick the same points
    fits.clear()
    again, _ = _cup_and_brick(inventory, cell, 0.455, rng=2)
    r = perceiver.perceive(again, priors=first.poses, prior_map=first.map_points)
    assert fits == []
    assert [p.obj_id for p in r.poses] == [4]
    assert np.array_equal(r.poses[0].T_base_obj, first.poses[0].T_base_obj)
    # the brick pushed 1 cm towards the cup: other points beside the same pose, fitted again
    moved, _ = _cup_and_brick(inventory, cell, 0.445, rng=3)
    r2 = perceiver.perceive(moved, priors=r.poses, prior_map=r.map_points)
    assert fits == [4]
    assert [p.obj_id for p in r2.poses] == [4]


def test_the_memo_tells_the_same_pose_and_points_from_others():
    rng = np.random.default_rng(0)
    P = rng.uniform(-0.05, 0.05, (2000, 3))
    T = make_T(np.eye(3), [0.4, 0.0, 0.1])
    C = P[:200] + [0.08, 0.0, 0.0]  # a cluster beside the pose's own points P
    memo = RefitMemo(size=2)
    memo.remember(4, False, T, P, C)
    again = P + rng.normal(0.0, 0.001, P.shape)  # re-scanned: each point within a few millimetres
    C_again = C + rng.normal(0.0, 0.001, C.shape)
    assert memo.failed_before(4, False, T, again, C_again)
    assert not memo.failed_before(5, False, T, again, C_again)  # another model
    assert not memo.failed_before(4, False, make_T(np.eye(3), [0.402, 0.0, 0.1]), again, C_again)  # moved 2 mm
    turned = make_T(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), [0.4, 0.0, 0.1])
    assert not memo.failed_before(4, False, turned, again, C_again)  # turned 90 deg about its axis ...
    memo.remember(4, True, T, P, C)
    assert memo.failed_before(4, True, turned, again, C_again)  # ... which for a symmetric model is the same pose
    assert not memo.failed_before(4, False, T, again, C + [0.02, 0.0, 0.0])  # the cluster moved 2 cm
    assert not memo.failed_before(4, False, T, P + [0.02, 0.0, 0.0], C_again)  # the own points moved
    assert not memo.failed_before(4, False, T, again, C[:150])  # a quarter of the cluster gone
    memo.remember(7, False, T, P, C)
    memo.remember(8, False, T, P, C)
    assert len(memo.entries) == 2 and not memo.failed_before(4, True, T, P, C)  # the oldest forgotten


def test_only_the_part_of_a_cluster_within_the_items_size_can_be_taken():
    """What a fit of a cup (11.7 cm across) that keeps its own points could take of a cluster: the part of a long
    thing beside it within that size of its points, none of a cluster across the sink, all of a crescent on it."""
    from kitchenbot.perception.refit import _within_one_item

    rng = np.random.default_rng(1)
    a = rng.uniform(0, 2 * np.pi, 3000)
    own = np.c_[0.04 * np.cos(a), 0.04 * np.sin(a), rng.uniform(0.0, 0.08, 3000)]  # a cup's wall, centre at 0
    beside = np.c_[rng.uniform(0.05, 0.45, 4000), rng.uniform(-0.02, 0.02, 4000), rng.uniform(0.0, 0.05, 4000)]
    room = _within_one_item(own, beside, 0.9 * len(own), 0.117)
    assert room[beside[:, 0] < 0.06].all() and not room[beside[:, 0] > 0.2].any()
    across = beside + [0.5, 0.0, 0.0]
    assert not _within_one_item(own, across, 0.9 * len(own), 0.117).any()
    crescent = own[:300] * [1.1, 1.1, 1.0]
    assert _within_one_item(own, crescent, 0.9 * len(own), 0.117).all()


def test_a_cluster_no_ball_of_the_items_size_holds_with_its_points_is_not_fitted():
    """A plate's points (a 27 cm disc) and a cluster 10 cm beyond its rim: most plate points are within the
    plate's diameter of the cluster, but no ball of the plate's size holds both; a crescent at the rim fits."""
    from kitchenbot.perception.refit import _enclosing_radius, _in_one_ball

    rng = np.random.default_rng(2)
    r, a = 0.135 * np.sqrt(rng.uniform(0, 1, 8000)), rng.uniform(0, 2 * np.pi, 8000)
    plate = np.c_[r * np.cos(a), r * np.sin(a), np.zeros(8000)]
    radius = _enclosing_radius(plate) + 0.003
    assert abs(radius - 0.138) < 0.002
    beyond = rng.uniform([0.235, -0.03, 0.0], [0.30, 0.03, 0.05], (2000, 3))
    assert not _in_one_ball(plate[:6000], beyond, 0.9 * 6000, 200, radius)
    crescent = plate[np.hypot(plate[:, 0], plate[:, 1]) > 0.12]
    assert _in_one_ball(plate[:6000], crescent, 0.9 * 6000, 0.5 * len(crescent), radius)
