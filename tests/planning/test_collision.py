"""Collision world: known free/colliding configurations, broad phase == all pairs, allowed contacts, voxels."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.collision import SceneObject


def test_home_and_scan_waypoints_are_free(planner, cfg, home):
    scene = planner.world.scene()
    assert scene.valid(home), scene.colliding_pairs(home)
    for q in cfg.scan_waypoints:
        assert scene.valid(q), scene.colliding_pairs(q)


def test_arm_into_the_cell_collides(planner, home):
    scene = planner.world.scene()
    q = home.copy()
    q[1] = 0.0  # shoulder lift level: forearm and wrist hang down into the sink
    pairs = scene.colliding_pairs(q)
    assert not scene.valid(q)
    assert any(a.startswith("cell:") or b.startswith("cell:") for a, b in pairs), pairs
    assert planner.robot.fk_tcp(q)[2, 3] < -0.15  # really down there (not a margin artefact)


def test_folded_forearm_self_collides(planner, home):
    scene = planner.world.scene()
    q = home.copy()
    q[2] = 3.1  # elbow folded: forearm onto the upper arm
    assert not scene.valid(q)


def test_broadphase_agrees_with_all_pairs(planner, home, resting):
    obj = resting("cup", (0.5, 0.0), 1)
    scene = planner.scene([obj])
    rng = np.random.default_rng(3)
    Q = home + rng.uniform(-1.5, 1.5, (400, 6))
    for q in Q:
        q = np.clip(q, planner.robot.lower, planner.robot.upper)
        fast = scene.valid(q)
        slow = not scene.in_collision_exhaustive(q)
        if fast != slow:  # the workspace check is the only other difference
            p = planner.robot.fk_tcp(q)[:3, 3]
            ws = planner.limits.workspace
            assert not ws.contains(p), (q, fast, slow)


def test_pads_may_touch_the_grasp_target_only(planner, home, resting):
    cup = resting("cup", (0.5, 0.0), 1)
    spec = planner.inventory.by_name("cup").grasps[0]
    T = cup.T_base_obj @ spec.T_obj_tcp
    q = planner.robot.ik_q(T, home)
    assert q is not None
    scene = planner.scene([cup])
    scene.set_opening(0.03)  # pads closed into the cup wall: contact
    assert not scene.valid(q)
    grasp = scene.for_grasp("1")
    grasp.set_opening(0.03)
    pairs = [p for p in grasp.colliding_pairs(q) if "obj:1" in p]
    assert all(("palm" in p or "camera" in p) for p in pairs), pairs  # pad contacts are allowed, nothing else


def test_unexplained_map_points_become_obstacles(planner, home, resting):
    cup = resting("cup", (0.5, 0.0), 1)
    rng = np.random.default_rng(4)
    model = planner.inventory.by_name("cup")
    on_cup = model.points[:300] @ cup.T_base_obj[:3, :3].T + cup.T_base_obj[:3, 3]
    blob = rng.normal((0.5, 0.1, -0.1), 0.01, (300, 3))  # something in the sink that no object explains
    so = [SceneObject("1", model, cup.T_base_obj)]
    vox = planner.world.unexplained_voxels(np.vstack([on_cup, blob]), so)
    assert len(vox) > 0
    assert np.all(np.linalg.norm(vox - (0.5, 0.1, -0.1), axis=1) < 0.06)  # only the blob
    # points of the cup's own instance explain a pose a little off (shifted 2 cm: none left over) ...
    shifted = on_cup + (0.02, 0.0, 0.0)
    assert len(planner.world.unexplained_voxels(shifted, so, instance_points=[shifted])) == 0
    # ... but an instance that took in the blob (segmentation merged them) does not hide the blob
    vox2 = planner.world.unexplained_voxels(np.vstack([on_cup, blob]), so, instance_points=[np.vstack([on_cup, blob])])
    assert len(vox2) > 0 and np.all(np.linalg.norm(vox2 - (0.5, 0.1, -0.1), axis=1) < 0.06)


def test_check_time_per_configuration(planner, home, resting):
    """Not a speed assertion (see `kitchenbot bench planning`): the check must answer for 1000 configurations."""
    scene = planner.scene([resting("cup", (0.5, 0.0), 1), resting("bowl", (0.4, 0.1), 2)])
    rng = np.random.default_rng(5)
    v = scene.valid_batch(np.clip(home + rng.uniform(-1, 1, (1000, 6)), planner.robot.lower, planner.robot.upper))
    assert 0 < v.sum() < 1000


def test_batch_check_agrees_with_single_checks(planner, home, resting):
    """valid_batch (Pinocchio's C++ batch loop + vectorised FK) == valid, with allowed contacts and pad moves."""
    cup = resting("cup", (0.5, 0.0), 1)
    base = planner.scene([cup])
    grasp = base.for_grasp("1")
    rng = np.random.default_rng(7)
    Q = np.clip(home + rng.uniform(-1.5, 1.5, (600, 6)), planner.robot.lower, planner.robot.upper)
    for scene in (base, grasp):
        for opening in (0.1, 0.03):
            scene.set_opening(opening)
            single = np.array([scene.valid(q) for q in Q])
            np.testing.assert_array_equal(scene.valid_batch(Q), single)
            k = scene.first_invalid(Q)
            assert k == (int(np.argmin(single)) if not single.all() else -1)
