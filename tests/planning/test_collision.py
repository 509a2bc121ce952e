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


def test_points_of_a_picked_object_leave_the_map(planner, resting):
    """Once an item is taken away, the map points where it stood are no obstacle (they explained it); points
    of something else beside it stay."""
    cup = resting("cup", (0.5, 0.0), 1)
    model = planner.inventory.by_name("cup")
    on_cup = model.points[:300] @ cup.T_base_obj[:3, :3].T + cup.T_base_obj[:3, 3]
    blob = np.random.default_rng(4).normal((0.5, 0.1, -0.1), 0.01, (300, 3))
    P = np.vstack([on_cup, blob])
    left = planner.without_points_of(P, cup)
    assert len(left) == len(blob) and np.allclose(np.sort(left, axis=0), np.sort(blob, axis=0))
    # with the cup gone from the objects, its points would have been an obstacle where it stood
    assert len(planner.world.unexplained_voxels(P, [])) > len(planner.world.unexplained_voxels(left, []))
    assert planner.without_points_of(None, cup) is None


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


def test_pads_touching_the_target_far_from_the_grasp_point_collide(planner, cfg, home):
    """A mug lying on its side (sim seed 9): its side grasp at 30 degrees to the handle puts the handle through
    one finger while the TCP sits in the mug's body, 3.5 cm from any wall. The simulator (fakes/collision.py)
    allows finger contacts only within 3 cm of the TCP; the planner allowed pad contacts with the target
    anywhere, planned the grasp-in and the FakeArm stopped on it. The planner must refuse it too."""
    from kitchenbot.fakes.collision import SimCollision
    from kitchenbot.fakes.world import SimWorld
    from kitchenbot.perception.types import ObjectPose

    mug = planner.inventory.by_name("mug")
    T_obj = np.array([[-0.0961, 0.22261, -0.97016, 0.47689],
                      [-0.96138, 0.23176, 0.14841, 0.02726],
                      [0.25788, 0.94696, 0.19174, -0.00073],
                      [0.0, 0.0, 0.0, 1.0]])
    T_obj[:3, :3] = np.linalg.svd(T_obj[:3, :3])[0] @ np.linalg.svd(T_obj[:3, :3])[2]  # re-orthonormalised
    # the side grasp the planner chose then (closing axis 30 degrees off the handle, tilted 5 degrees), fully open
    T_obj_tcp = np.array([[-0.04358, -0.86603, -0.49810, -0.017],
                          [-0.07548, 0.5, -0.86275, 0.0],
                          [0.99619, 0.0, -0.08716, 0.005],
                          [0.0, 0.0, 0.0, 1.0]])
    T_obj_tcp[:3, :3] = np.linalg.svd(T_obj_tcp[:3, :3])[0] @ np.linalg.svd(T_obj_tcp[:3, :3])[2]
    opening = 0.10
    q = planner.robot.ik_q(T_obj @ T_obj_tcp, home)
    assert q is not None
    # the simulated physics: a finger hits the mug
    world = SimWorld(planner.cell, planner.inventory, T_flange_tcp=planner.robot.T_flange_tcp,
                     T_flange_cam=cfg.T_flange_cam(), q=home.copy())
    world.add_object(mug, T_obj)
    contact = SimCollision(world).check_config(q, opening)
    assert contact is not None and contact.part.startswith("finger") and contact.other == "obj:1", contact
    # the planner: the grasp scene refuses it, naming the pad and the mug
    scene = planner.scene([ObjectPose(mug.obj_id, "mug", T_obj, 1.0, instance_id=1)])
    grasp = scene.for_grasp("1")
    grasp.set_opening(opening)
    assert not grasp.valid(q)
    assert not grasp.valid_batch(q[None])[0]
    assert any("obj:1" in p and ("pad_a" in p or "pad_b" in p) for p in grasp.colliding_pairs(q))


def test_scenes_sharing_a_layout_get_their_own_pairs_and_margins(planner, home):
    """Collision pairs are computed once per layout (planning.collision._collision_pairs): scenes with the same
    layout but other objects name their own objects; the grasp variant's margins and allowed contacts are per
    scene; and a scene checks what a fresh world's scene of the same content checks."""
    from kitchenbot.planning.collision import CollisionWorld, Held

    inv_models = list(planner.inventory.models.values())
    a = [SceneObject("a", inv_models[0], np.eye(4)), SceneObject("b", inv_models[1], np.eye(4))]
    b = [SceneObject("c", inv_models[2], np.eye(4)), SceneObject("d", inv_models[3], np.eye(4))]
    held = Held(inv_models[4], np.eye(4), 0.05)
    sa, sb = planner.world.scene(a, None, held), planner.world.scene(b, None, held)
    assert len(sa.pair_names) == len(sb.pair_names)
    assert {"obj:a", "obj:b"} <= {n for p in sa.pair_names for n in p}
    assert not {"obj:a", "obj:b"} & {n for p in sb.pair_names for n in p}
    ga = sa.for_grasp("a")
    allowed = [k for k, p in enumerate(ga.pair_names) if not ga.gd.activeCollisionPairs[k]]
    assert allowed and all("obj:a" in ga.pair_names[k] for k in allowed)
    assert all(sb.gd.activeCollisionPairs[k] for k in range(len(sb.pair_names)))
    fresh = CollisionWorld(planner.robot, planner.cell, planner.world.T_flange_cam, margin=planner.world.margin,
                           grasp_margin=planner.world.grasp_margin, gripper=planner.world.gripper)
    sf = fresh.scene(b, None, held)
    assert sf.pair_names == sb.pair_names
    rng = np.random.default_rng(0)
    Q = home + rng.normal(0.0, 0.6, size=(300, 6))
    assert np.array_equal(sf.valid_batch(Q), sb.valid_batch(Q))
    assert [sf.valid(q) for q in Q] == [sb.valid(q) for q in Q]


def test_batch_pools_are_kept_per_opening(planner, home, resting, monkeypatch):
    """A grasp search alternates between a few pad openings on one scene: the batch checker's pool (a copy of the
    geometry with the pads where they were) is built once per opening and kept, and a kept pool answers as the
    single checks do at that opening (the pads moved away and back in between)."""
    from kitchenbot.planning import collision

    built = []
    real = collision.pin.BroadPhaseManagerPool_DynamicAABBTreeCollisionManager

    def counted(*a):
        built.append(1)
        return real(*a)

    monkeypatch.setattr(collision.pin, "BroadPhaseManagerPool_DynamicAABBTreeCollisionManager", counted)
    cup = resting("cup", (0.5, 0.0), 1)
    spec = planner.inventory.by_name("cup").grasps[0]
    q_grasp = planner.robot.ik_q(cup.T_base_obj @ spec.T_obj_tcp, home)
    assert q_grasp is not None
    rng = np.random.default_rng(11)
    Q = np.clip(np.vstack([q_grasp + rng.normal(0.0, 0.02, (150, 6)), home + rng.uniform(-1.5, 1.5, (150, 6))]),
                planner.robot.lower, planner.robot.upper)
    for kind, scene in (("base", planner.scene([cup])), ("grasp", planner.scene([cup]).for_grasp("1"))):
        built.clear()
        answers = {}
        for opening in (0.1, 0.03, 0.1, 0.03, 0.06, 0.1):
            scene.set_opening(opening)
            single = np.array([scene.valid(q) for q in Q])
            batch = scene.valid_batch(Q)
            np.testing.assert_array_equal(batch, single)
            answers.setdefault(opening, batch)
            np.testing.assert_array_equal(batch, answers[opening])
        if kind == "base":  # the pads' opening matters here (closed into the cup wall near the grasp)
            assert not np.array_equal(answers[0.1], answers[0.03])
            assert len(built) == 3, len(built)  # one pool per opening
        else:  # its strict scene (pad contacts checked) keeps its own: at most one more per opening
            assert len(built) <= 2 * 3, len(built)
