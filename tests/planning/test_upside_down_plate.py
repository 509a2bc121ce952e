"""A plate lying upside down (tipped over from a lean, or one of a stack of plates face down) offered no grasp: every
builtin plate pinch approaches along -z of the plate, so upside down they all came from below
(`no_collision_free_grasp`, `from_below` = every grasp but a few). Its lip is a thin band pinched the same from
either face: the pinches that lean in from outside are mirrored through the lip's mid-surface
(`grasp_synthesis._underside_pinches`, `rimunder*`, fallbacks)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.oracle import OraclePerceiver
from kitchenbot.fakes.placement import drop_onto
from kitchenbot.planning.grasp_synthesis import UNDERSIDE
from kitchenbot.transforms import rot_x

pytestmark = pytest.mark.timeout(300)


@pytest.mark.parametrize("name", ["dinner_plate", "side_plate"])
def test_plates_get_underside_lip_pinches_the_simulated_gripper_holds(name, grasps_hold):
    grasps_hold(name, UNDERSIDE, 6)


@pytest.fixture(scope="module")
def tipped(empty_sim_cell):
    """The sink emptied; a bowl upside down on its floor and a side plate face down, tilted 36 degrees, dropped
    beside it (a plate face down on a pile)."""
    cfg, world, planner = empty_sim_cell()
    lo, hi = planner.cell.sink_interior
    c = (np.asarray(lo, float) + np.asarray(hi, float)) / 2
    bowl = next(m for m in world.inventory if m.cls == "bowl")
    plate = next(m for m in world.inventory if m.name == "side_plate")
    T = rot_x(np.pi)
    T[:3, 3] = (c[0], c[1] + 0.07, lo[2] + 0.10)
    b = world.add_object(bowl, T)
    world.set_pose(b, drop_onto(world, b, T))
    T = rot_x(np.radians(36)) @ rot_x(np.pi)  # face down, tilted
    T[:3, 3] = (c[0], c[1] - 0.03, lo[2] + 0.15)
    p = world.add_object(plate, T)
    world.set_pose(p, drop_onto(world, p, T))
    return cfg, world, planner, p


def test_a_plate_face_down_on_a_pile_is_picked_by_its_underside(tipped, run_pick_on_fake_arm):
    cfg, world, planner, p = tipped
    assert world.objects[p].T_base_obj[2, 2] < -0.8  # face down, tilted
    poses = OraclePerceiver(world).perceive([]).poses
    target = next(o for o in poses if o.instance_id == p)
    pick = planner.plan_pick(world.q.copy(), poses, target=target)
    assert pick.ok, pick  # before: no_collision_free_grasp, every grasp but a few from below
    assert pick.grasp.spec.name.startswith(UNDERSIDE)
    run_pick_on_fake_arm(cfg, world, pick)
    assert world.held_uid == p
