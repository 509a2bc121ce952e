"""A bowl resting tilted in a nest (on the rim of the upright bowl it leans in): lifted straight up, it leaves the
bowl below within a millimetre and its side then sweeps into that bowl's rim 1-2 cm higher. The planner let the
held item touch what it rests on anywhere in the lift's first centimetres (LIFT_CONTACT_TRAVEL); the simulator
(fakes/collision.py), like a real arm's contact detection, tolerates a resting contact only while it lasts: a
contact made again is a protective stop. Now a lift whose start contact comes back is refused
(Planner._contact_comes_back) and the tilted item is also lifted between straight up and its own axis
(planning.lift.between_up_and_axis), which clears the rim and a glass its axis leads into."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.fakes.collision import SimCollision
from kitchenbot.fakes.world import SimWorld
from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import from_rotvec
from kitchenbot.world.cell import Cell

# A nest as the simulator settles one on a pile (rotation vector, position; base frame): the bowl A, tilted by 14
# degrees, the bowl B resting in it tilted by 49 degrees, a glass lying beside the nest where B's axis points.
A = ((-0.0868, 0.2396, -0.1505), (0.4596, 0.0388, -0.0967))
B = ((-1.0979, -0.2831, -2.4253), (0.4469, 0.0288, -0.0592))
GLASS = ((1.0498, 1.7436, 1.4278), (0.6015, 0.0973, -0.055))


@pytest.fixture
def nest(cfg, inventory):
    """The SimWorld with the nest (the meshes only: what A rests on plays no part in B's lift), and the same items
    as perceived poses (exact)."""
    world = SimWorld(Cell(), inventory, T_flange_tcp=cfg.safety_limits().T_flange_tcp, q=np.array(cfg.robot.home))
    bowl, glass = inventory.by_name("bowl"), inventory.by_name("glass")
    poses = {}
    for name, model, (rv, t) in (("A", bowl, A), ("B", bowl, B), ("glass", glass, GLASS)):
        T = from_rotvec(rv, t)
        uid = world.add_object(model, T)
        poses[name] = ObjectPose(model.obj_id, model.cls, T, 1.0, instance_id=uid)
    return world, poses


def _lift_in_simulator(world, pick, uid):
    world.set_joints(pick.lift.q[0])
    world.attach(uid, slip=False)
    try:
        return SimCollision(world).check_path(pick.lift.q, pick.grasp.spec.opening)
    finally:
        world.release()


def test_the_tilted_bowl_is_lifted_without_a_new_contact_with_the_bowl_below(planner, nest):
    world, p = nest
    q0 = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])  # the last scan waypoint (config/sim.yaml)
    objects = [p["A"], p["B"], p["glass"]]
    pick = planner.plan_pick(q0, objects, target=p["B"])
    assert pick.ok, str(pick)
    contact = _lift_in_simulator(world, pick, p["B"].instance_id)
    assert contact is None, f"{pick.grasp.spec.name}: {contact}"


def test_straight_up_the_bowl_leaves_the_rim_below_and_meets_it_again(planner, nest, straight_up):
    """The cause, on the planner's own geometry: the straight-up lift's exact contacts with A break and return."""
    world, p = nest
    q0 = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])
    pick = planner.plan_pick(q0, [p["A"], p["B"], p["glass"]], target=p["B"])
    assert pick.ok, str(pick)
    from kitchenbot.planning.grasps import object_name

    objects = [p["A"], p["B"], p["glass"]]
    held = planner.scene(objects, None, exclude=p["B"], held=pick.grasp, own=[p["B"]]).for_release(None)
    Q = straight_up(pick.grasp.q, 0.002, 0.05)
    touching = held.touching(Q, ("held", f"obj:{object_name(p['A'], 0)}"))
    assert touching[0] and not touching.all()
    first_apart = int(np.argmin(touching))
    assert touching[first_apart:].any()  # made again: what the planner now refuses
    assert planner._contact_comes_back(held, np.array(Q), [("held", f"obj:{object_name(p['A'], 0)}")]) is not None
