"""A mug lying on its side against the basin's far wall, its handle pointing down the wall: every grasp collides
(the grasps across its body that come from above are those whose pads miss the handle; beside the wall they put
the wrist over the counter or a pad into the wall). No strategy applied to it (slide_off_stack slides plates,
slide_off_blocked items lying on another they block), so it stayed in the sink. `slide_from_wall` pushes it away
from the wall with the closed fingers pressing on its top, only to where a grasp of it is free, and the simulated
arm drags it there."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from kitchenbot.executive.belief import Belief
from kitchenbot.executive.oracle import OraclePerceiver
from kitchenbot.executive.strategies import WALL_NEAR, PlanFailure, PlanRequest, SlideFromWall, _wall_room
from kitchenbot.fakes.placement import drop_onto
from kitchenbot.tasks import TASKS
from kitchenbot.transforms import rot_x, rot_z

pytestmark = pytest.mark.timeout(300)

WALL_GAP = 0.003  # m between the mug and the basin's +x wall


@pytest.fixture(scope="module")
def scene(empty_sim_cell):
    """The sink emptied; a mug on its side (its axis along y) WALL_GAP from the +x wall, turned 90 degrees about
    its axis (the handle points down along the wall), dropped onto the floor."""
    cfg, world, planner = empty_sim_cell()
    lo, hi = planner.cell.sink_interior
    mug = next(m for m in world.inventory if m.name == "mug")
    T = rot_x(np.pi / 2) @ rot_z(np.pi / 2)
    V = np.asarray(mug.mesh.vertices) @ T[:3, :3].T
    T[:3, 3] = (hi[0] - WALL_GAP - V[:, 0].max(), 0.0, 0.05)
    u = world.add_object(mug, T)
    world.set_pose(u, drop_onto(world, u, T))
    return cfg, world, planner, u


def _req(world, planner, poses, obj, belief):
    return PlanRequest(obj=obj, targets=[], staged=None, task=None, belief=belief, planner=planner,
                       joints=lambda: world.q.copy(), escape=lambda: True, note=lambda *a, **k: None,
                       check_deadline=lambda: None, scene_objs=poses)


def test_the_sink_tasks_use_it():
    for name in ("sink-pick", "sink-to-dishwasher"):
        assert "slide_from_wall" in TASKS[name].strategies


def test_a_lying_mug_at_the_wall_is_slid_to_where_it_can_be_picked(scene, run_slide):
    cfg, world, planner, u = scene
    poses = OraclePerceiver(world).perceive([]).poses
    mug = next(o for o in poses if o.instance_id == u)
    r = planner.plan_pick(world.q.copy(), poses, target=mug)
    assert not r.ok and r.kind == "no_collision_free_grasp", r

    belief = Belief()
    belief.poses = poses
    req = _req(world, planner, poses, mug, belief)
    s = SlideFromWall()
    crowded = PlanFailure("no_collision_free_grasp", "every grasp collides", "pick", "direct_pick")
    assert _wall_room(planner, mug) < WALL_NEAR
    assert s.applies(crowded, mug, belief, req)
    assert not s.applies(PlanFailure("cartesian_path_failed", "", "pick", "direct_pick"), mug, belief, req)
    assert not s.applies(None, mug, belief, req)
    # a neighbour named as crowding its grasps goes first (blocker_first), no slide
    assert not s.applies(PlanFailure("no_collision_free_grasp", "", "pick", "direct_pick", 3), mug, belief, req)
    # standing on its base (pushed at its top it would tip over): not this strategy's
    T = np.asarray(mug.T_base_obj, float).copy()
    T[:3, :3] = np.eye(3)
    standing = replace(mug, T_base_obj=T)
    assert not s.applies(crowded, standing, belief, _req(world, planner, poses, standing, belief))

    plan = s.plan(req)
    assert plan is not None and plan.slide is not None and plan.strategy == "slide_from_wall"
    assert plan.slide.direction[0] < -0.5  # away from the +x wall
    run_slide(world, cfg, plan.slide, u)
    poses = OraclePerceiver(world).perceive([]).poses
    mug = next(o for o in poses if o.instance_id == u)
    r = planner.plan_pick(world.q.copy(), poses, target=mug)
    assert r.ok, r  # picked from there


def test_not_away_from_the_walls(scene):
    cfg, world, planner, u = scene
    poses = OraclePerceiver(world).perceive([]).poses
    mug = next(o for o in poses if o.instance_id == u)
    T = np.asarray(mug.T_base_obj, float).copy()
    lo, hi = planner.cell.sink_interior
    T[:2, 3] = (np.asarray(lo)[:2] + np.asarray(hi)[:2]) / 2  # the basin's middle
    middle = replace(mug, T_base_obj=T)
    belief = Belief()
    crowded = PlanFailure("no_collision_free_grasp", "", "pick", "direct_pick")
    assert not SlideFromWall().applies(crowded, middle, belief, _req(world, planner, [middle], middle, belief))
