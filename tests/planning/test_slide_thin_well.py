"""A large plate lying alone in the middle of the sink (set B of the own dishware: the 29 cm pasta plate, grasps
from the mesh) has no collision-free grasp: every pinch of its wide flat rim puts the wrist, the palm or the camera
into a basin wall (5.5 cm away) or comes in level into the floor. Slid 6 cm towards a wall it is pickable. Its well
is one 5 mm wall resting on the sink floor, so the closed fingers pressing 3 mm into it seemed to reach the floor
(the planner's fingers are 2 mm longer than the simulator's): the press was refused as a collision with the sink
floor. What the item rests on, the cell included, is allowed to the pads during the press (planning/slide.py)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import make_T

pytestmark = pytest.mark.timeout(900)


@pytest.fixture(scope="module")
def pasta(own_b):
    inv, by_name = own_b
    return inv, by_name["pasta_plate"]


def test_a_large_plate_alone_in_the_sink_is_slid_then_picked(pasta, cfg, home, run_pick_on_fake_arm):
    from kitchenbot.fakes.arm import FakeArm
    from kitchenbot.fakes.gripper import FakeGripper
    from kitchenbot.fakes.world import SimWorld
    from kitchenbot.planning.pick_place import Planner
    from kitchenbot.world.cell import Cell

    inv, plate = pasta
    assert plate.cls == "plate"
    planner = Planner.from_config(cfg, inv)
    lo, hi = planner.cell.sink_interior
    c = (lo + hi) / 2
    T = make_T(t=(c[0], c[1], lo[2] - np.asarray(plate.mesh.vertices)[:, 2].min() + 0.0005))
    o = ObjectPose(plate.obj_id, plate.cls, T, 1.0, instance_id=1)
    assert not planner.plan_pick(home, [o], target=o).ok  # no grasp where it lies
    slide = planner.plan_slide(home, [o], o)
    assert slide.ok, slide
    world = SimWorld(Cell(), inv, T_flange_tcp=cfg.safety_limits().T_flange_tcp, q=home.copy())
    world.add_object(plate, T)
    arm, grip = FakeArm(world, cfg.safety_limits()), FakeGripper(world)
    arm.connect()
    grip.connect()
    grip.open(0.0)
    for traj in slide.trajectories:
        arm.execute_trajectory(traj.times, traj.q)
    assert arm.log.collisions == 0 and arm.log.protective_stops == 0
    (uid,) = world.objects
    moved = world.objects[uid].T_base_obj
    assert np.linalg.norm(moved[:2, 3] - T[:2, 3]) > 0.04  # it went along
    assert np.linalg.norm(moved[:3, 3] - slide.T_base_obj_after[:3, 3]) < 0.01  # where the planner said
    o2 = ObjectPose(plate.obj_id, plate.cls, moved.copy(), 1.0, instance_id=1)
    pick = planner.plan_pick(world.q.copy(), [o2], target=o2)
    assert pick.ok, pick
    run_pick_on_fake_arm(cfg, world, pick)
