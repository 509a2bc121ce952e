"""A bowl lying tilted on a pile (sink seed 31: at 129 degrees on two leaning side plates and a dinner plate, its
foot ring facing the right basin wall): every rim pinch comes from below or runs into the plates, and the
foot-ring pinch along the bowl's axis comes in 52 degrees from vertical, over the wall (the palm hits it). The
foot-ring pinch pitched in from outside the ring (planning.grasp_synthesis.generate_grasps, `footpitch`) comes in
from above the pile."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning import grasps as grasps_mod
from kitchenbot.planning.fcl_check import FclChecker, verify_pick
from kitchenbot.transforms import from_rotvec

# The simulator's poses of the pile in sink seed 31 once the items on top of it are gone (rotation vector, then
# position, base frame).
PILE = (
    ("dinner_plate", (-0.0174, 0.011, -0.1016), (0.4126, -0.0257, -0.183)),
    ("side_plate", (-0.129, 0.4788, 0.115), (0.5457, 0.0201, -0.1592)),
    ("side_plate", (0.077, 0.6517, 0.9636), (0.5279, 0.0036, -0.133)),
    ("bowl", (-1.3877, 1.795, 0.3593), (0.4414, -0.0894, -0.0939)),
)


@pytest.fixture
def pile(planner):
    out = []
    for k, (name, rv, t) in enumerate(PILE):
        m = planner.inventory.by_name(name)
        out.append(ObjectPose(m.obj_id, m.cls, from_rotvec(rv, t), 1.0, instance_id=k + 1))
    return out


def test_simulated_gripper_holds_the_bowl_with_a_pitched_foot_pinch(grasps_hold):
    grasps_hold("bowl", "footpitch", 5)


def test_a_tilted_bowl_on_a_pile_is_picked_by_its_foot_ring_pitched_in(planner, pile):
    bowl = pile[-1]
    q0 = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])  # the last scan waypoint (config/sim.yaml)
    pick = planner.plan_pick(q0, pile, target=bowl)
    assert pick.ok, str(pick)
    assert pick.grasp.spec.name.startswith("footpitch"), pick.grasp.spec.name
    assert pick.grasp.T_base_tcp[2, 2] < -0.8  # from above the pile
    checker = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
    assert all(r.ok for _, r in verify_pick(checker, planner, pick, pile, step=0.003))
    # without the pitched pinches no grasp of it is collision-free (the cause)
    m = planner.inventory.by_name("bowl")
    saved = m.grasps
    try:
        m.grasps = [g for g in saved if not g.name.startswith("footpitch")]
        grasps_mod._expanded.clear()
        res = planner.plan_pick(q0, pile, target=bowl)
        assert not res.ok and res.kind == "no_collision_free_grasp", res
    finally:
        m.grasps = saved
        grasps_mod._expanded.clear()


@pytest.mark.parametrize("tilt_deg", [0.0, 20.0])
def test_pitched_pinches_do_not_take_the_places_of_vertical_ones(planner, home, resting, tilt_deg):
    """Under a candidate limit the fallback grasps are checked after every standard one: a bowl upside down
    (or tilted, its pitched pinches' TCPs then higher than some vertical ones) keeps its vertical foot pinches."""
    from kitchenbot.transforms import rot_x

    bowl = resting("bowl", (0.5, 0.0), 1, upside_down=True)
    bowl = ObjectPose(bowl.obj_id, bowl.cls, bowl.T_base_obj @ rot_x(np.radians(tilt_deg)), 1.0, instance_id=1)
    res = planner.select_grasps(home, [bowl], limit=4)
    assert isinstance(res, list) and len(res) == 4
    assert all(g.spec.name.startswith("foot_") for g in res), [g.spec.name for g in res]
