"""The release-pose cache (planning/place_reach.py) gives the answers of the full enumeration it replaced: every
raise, turn and IK branch checked against the query's scene. The reference below is that enumeration; the cache
must agree with it on scenes with items next to the target (the cell-only pre-check must not drop a pose the
full scene keeps), from different reference configurations, asked again after other queries (kept geometry)."""

from __future__ import annotations

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.collision import Held
from kitchenbot.planning.grasps import expand_grasps
from kitchenbot.planning.types import PlaceTarget
from kitchenbot.tasks.base import inverted, upright
from kitchenbot.transforms import inv, trans


def _reference(planner, target, T_obj_tcp, q_ref, release_scene, pre_scene, obj_id, first_only=False):
    """The full enumeration (as Planner._place_tcp_options did before the cache)."""
    T_obj = np.asarray(target.T_base_obj, float)
    turns = planner._place_turns(target, obj_id)
    c = float(max(target.clearance, 0.0))
    raises = np.arange(c, c + planner.settings.max_release_drop + 1e-9, 0.01)
    up = target.approach_distance if target.approach_distance is not None else planner.settings.approach_distance
    live = [T_obj @ Rt for Rt in turns if (T_obj @ Rt @ T_obj_tcp)[2, 2] <= planner.settings.max_approach_up]
    out = []
    for dz in raises:
        for To0 in live:
            To = trans(0.0, 0.0, float(dz)) @ To0
            T = To @ T_obj_tcp
            branches = planner.robot.ik_all(T, q_ref)
            if not branches and planner._within_reach(T):
                q = planner.robot.ik_q(T, q_ref, max_seeds=2, max_iter=40)
                branches = [] if q is None else [q]
            for q in branches:
                if not release_scene.valid(q):
                    continue
                q_pre = planner.robot.ik_q(trans(0.0, 0.0, up) @ T, q, max_seeds=0)
                if q_pre is None or not pre_scene.valid(q_pre):
                    continue
                out.append((To, T, q))
                if first_only:
                    return out
        if out:
            break
    out.sort(key=lambda x: float(np.max(np.abs(x[2] - q_ref))))
    return out


def _scenes(planner, model, spec, others):
    objs = planner._scene_objects(others)
    held = Held(model, inv(spec.T_obj_tcp), spec.width)
    pre = planner.world.scene(objs, np.zeros((0, 3)), held)
    return pre.for_release(None), pre


def _same(a, b):
    assert len(a) == len(b)
    for (To, T, q), (To2, T2, q2) in zip(a, b):
        np.testing.assert_allclose(To, To2, atol=1e-9)
        np.testing.assert_allclose(T, T2, atol=1e-9)
        np.testing.assert_allclose(q, q2, atol=1e-6)


def test_cache_agrees_with_the_full_enumeration(planner, home):
    cup = planner.inventory.by_name("cup")
    upper = planner.cell.spec.dishwasher.upper
    xy = (0.51, -0.40)
    target = PlaceTarget(inverted(cup, xy, upper.floor_z), "slot", "t", free_yaw=True)
    # a cup already standing next to the target (what the rack holds): some release poses collide with it only
    near = ObjectPose(cup.obj_id, cup.cls, upright(cup, (xy[0] + 0.085, xy[1]), upper.floor_z), 1.0, instance_id=7)
    far = ObjectPose(cup.obj_id, cup.cls, upright(cup, (xy[0] + 0.3, xy[1] + 0.3), upper.floor_z), 1.0, instance_id=8)
    other_q = home + np.array([-1.2, 0.3, -0.4, 0.5, 0.8, 1.0])
    specs = [g for g in expand_grasps(cup)][::6]
    checked = nonempty = 0
    differs = False
    for others in ([], [near, far], []):  # the empty scene again: the kept geometry answers it
        for spec in specs:
            release, pre = _scenes(planner, cup, spec, others)
            for q_ref in (home, other_q):
                got = planner._place_tcp_options(target, spec.T_obj_tcp, q_ref, release, obj_id=cup.obj_id,
                                                 pre_scene=pre)
                ref = _reference(planner, target, spec.T_obj_tcp, q_ref, release, pre, cup.obj_id)
                _same(got, ref)
                first = planner._place_tcp_options(target, spec.T_obj_tcp, q_ref, release, first_only=True,
                                                   obj_id=cup.obj_id, pre_scene=pre)
                assert bool(first) == bool(ref)
                if first:
                    assert any(np.allclose(first[0][2], q, atol=1e-6) for _, _, q in ref)
                checked += 1
                nonempty += bool(ref)
            if others == [near, far]:
                alone = _reference(planner, target, spec.T_obj_tcp, home, *_scenes(planner, cup, spec, []), cup.obj_id)
                differs |= len(alone) != len(_reference(planner, target, spec.T_obj_tcp, home, release, pre, cup.obj_id))
    assert checked == 3 * len(specs) * 2
    assert 0 < nonempty < checked  # some grasps reach the target, some do not
    assert differs  # the neighbour changes the answer for some grasp: the scene's own check matters


def test_scenes_on_demand_give_the_same_answers_and_are_built_only_when_needed(planner, home):
    """The grasp filter's query scenes built on demand (place_reach.OnDemand): the same answers as scenes built
    beforehand, for grasps that reach the target and grasps that do not; those the cell alone answers (no
    candidate survives it) never build them."""
    from kitchenbot.planning.place_reach import OnDemand

    cup = planner.inventory.by_name("cup")
    upper = planner.cell.spec.dishwasher.upper
    xy = (0.51, -0.40)
    near = ObjectPose(cup.obj_id, cup.cls, upright(cup, (xy[0] + 0.085, xy[1]), upper.floor_z), 1.0, instance_id=7)
    reachable = PlaceTarget(inverted(cup, xy, upper.floor_z), "slot", "t", free_yaw=True)
    # beyond the arm's reach: no release pose has an IK branch, so nothing survives the cell-only check
    beyond = PlaceTarget(inverted(cup, (2.5, 0.0), upper.floor_z), "slot", "t2", free_yaw=True)
    built = {True: 0, False: 0}
    for target in (reachable, beyond):
        for spec in [g for g in expand_grasps(cup)][::6]:
            release, pre = _scenes(planner, cup, spec, [near])
            held = Held(cup, inv(spec.T_obj_tcp), spec.width)
            calls = []

            def build(release=release, pre=pre):
                calls.append(1)
                return release, pre

            for first_only in (True, False):
                want = planner._place_tcp_options(target, spec.T_obj_tcp, home, release, first_only=first_only,
                                                  obj_id=cup.obj_id, pre_scene=pre)
                got = planner._place_tcp_options(target, spec.T_obj_tcp, home, OnDemand(held, spec.width, build),
                                                 first_only=first_only, obj_id=cup.obj_id)
                _same(got, want)
            built[target is reachable] += len(calls)
            if target is beyond:
                assert not calls
    assert built[True] > 0  # where candidates survive the cell, the scenes are built and decide
