"""Escaping a stop within the collision margin: a short straight TCP line that ends with every margin kept."""

import numpy as np
import pytest

from kitchenbot.planning.escape import plan_escape

pytestmark = pytest.mark.timeout(120)


def _tcp_down_at(planner, home, xyz):
    T = planner.robot.fk_tcp(home)  # home points the tool down
    T[:3, 3] = xyz
    q = planner.robot.ik_q(T, home)
    assert q is not None
    return q


def test_stopped_near_the_sink_floor_escapes_up(planner, home):
    lo, _ = planner.cell.sink_interior
    # finger tips (12 mm past the TCP) 5 mm above the sink floor: inside the 1 cm margin, not touching
    q0 = _tcp_down_at(planner, home, (0.50, 0.0, lo[2] + 0.012 + 0.005))
    scene = planner.scene([])
    assert not scene.valid(q0)
    assert planner.plan_move(q0, home).kind == "start_in_collision"

    plan = planner.plan_escape(q0)
    assert plan.ok, plan
    q_end = plan.trajectory.q[-1]
    assert scene.valid(q_end)
    rise = planner.robot.fk_tcp(q_end)[2, 3] - planner.robot.fk_tcp(q0)[2, 3]
    assert rise > 0.03  # out, upwards
    assert planner.plan_move(q_end, home).ok  # and from there planned motions work again
    # every sample of the escape keeps the close pairs from touching
    close = scene.touching_only(scene.colliding_pairs(q0))
    assert all(close.valid(q) for q in plan.trajectory.q)


def test_touching_start_is_refused(planner, home):
    lo, _ = planner.cell.sink_interior
    q0 = _tcp_down_at(planner, home, (0.50, 0.0, lo[2] + 0.012 - 0.004))  # finger tips 4 mm into the floor
    res = plan_escape(planner, q0)
    assert not res.ok and res.kind == "start_in_collision"


def test_nothing_to_escape_from(planner, home):
    res = planner.plan_escape(home)
    assert not res.ok and "nothing to escape" in res.message


def test_pads_around_a_plate_just_let_go_back_out_of_it():
    """The arm stands where it let a plate go in the lower rack (a retreat stopped and backed off to its start):
    the open pads touch the plate in the planner's model, so no planned motion starts there and no line keeps
    them from touching. They back out along the approach axis, as the planned retreat does; the simulator (its own
    collision model) runs that without a collision, and planned motions start again from its end."""
    from kitchenbot.executive.assembly import make_sim_world
    from kitchenbot.executive.config import load_config
    from kitchenbot.executive.oracle import OraclePerceiver
    from kitchenbot.fakes.arm import FakeArm
    from kitchenbot.fakes.gripper import FakeGripper
    from kitchenbot.fakes.placement import drop_onto
    from kitchenbot.perception.types import ObjectPose
    from kitchenbot.planning.pick_place import Planner
    from kitchenbot.planning.placement import SlotBook
    from kitchenbot.transforms import make_T

    cfg = load_config()
    world = make_sim_world(cfg, 0)
    for u in list(world.objects):
        world.remove_object(u)
    m = world.inventory.by_name("dinner_plate")
    lo, _ = world.cell.sink_interior
    uid = world.add_object(m, make_T(t=(0.50, 0.0, lo[2] + m.extents[2] / 2 + 0.01)))
    world.set_pose(uid, drop_onto(world, uid, world.objects[uid].T_base_obj))
    arm, grip = FakeArm(world, cfg.safety_limits()), FakeGripper(world)
    arm.connect()
    grip.connect()
    planner = Planner.from_config(cfg, world.inventory)
    home = np.asarray(cfg.robot.home, float)
    plate = OraclePerceiver(world).perceive([]).poses[0]
    targets = SlotBook(planner.cell).targets_for(m)[:3]
    pick = planner.plan_pick(arm.joint_positions(), [plate], target=plate, place_target=targets)
    assert pick.ok, pick
    place = planner.plan_place(pick.end, pick.grasp, targets)
    assert place.ok, place
    grip.open(pick.grasp.spec.opening)
    for t in (pick.approach, pick.grasp_in):
        arm.execute_trajectory(t.times, t.q)
    assert grip.grasp(0.5).holding
    for t in (pick.lift, place.transfer, place.lower):
        arm.execute_trajectory(t.times, t.q)
    grip.open(pick.grasp.spec.opening)
    assert arm.log.collisions == 0 and arm.log.protective_stops == 0
    # the executive's record of it: at its target (the release pose, the plate drops the last few mm)
    placed = ObjectPose(m.obj_id, m.cls, place.T_base_obj, 1.0, instance_id=5)
    q_rel = arm.joint_positions()
    assert not planner.scene([placed]).valid(q_rel)  # (plan_move now leaves such a start itself: planning.leave)
    assert plan_escape(planner, q_rel, [placed]).ok  # (fully open pads, as plan_move assumes)
    plan = planner.plan_escape(q_rel, [placed], opening=grip.opening())
    assert plan.ok, plan
    assert plan.timings_ms["backed_out_of"] == "5"
    arm.execute_trajectory(plan.trajectory.times, plan.trajectory.q)
    assert arm.log.collisions == 0 and arm.log.protective_stops == 0
    assert world.held_uid is None
    assert planner.plan_move(arm.joint_positions(), home, objects=[placed]).ok


def test_pads_touching_something_held_or_not_an_item_are_not_backed_out():
    from kitchenbot.planning.escape import pad_touched

    assert pad_touched([("pad_a", "obj:5"), ("pad_b", "obj:5")]) == "5"
    assert pad_touched([("obj:5", "pad_b")]) == "5"
    assert pad_touched([("pad_a", "obj:5"), ("pad_b", "obj:6")]) is None  # two items: which way is not known
    assert pad_touched([("pad_a", "obj:5"), ("palm", "obj:5")]) is None  # the palm on it: not a pad contact
    assert pad_touched([("pad_a", "cell:sink_floor")]) is None  # the cell: not an item let go
