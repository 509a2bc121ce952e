"""A bowl lying tilted in the mouth of another (41 degrees between their axes; the lower one on a pile), as the
simulator settles one, seen through fitted poses a few tenths of a millimetre off. Lifted straight up (the first
lift the planner tries), the held bowl slides along the lower one's wall: in the world the two part by 0.16 mm and
meet again a few millimetres higher, a contact made again, which the simulator (fakes/collision.py), like a real
arm's contact detection, stops. On the fitted poses the two overlap all along (0.85 mm, shallowing to 0.73 mm,
then deeper): one unbroken contact, so the planner planned that lift. Now a start contact that, within the fits'
resolution, may break and be made again refuses the lift (Planner._remade_within_fit), and the bowl is lifted first
along the direction that parts it from the one it rests in (planning.lift.separating_leg), then straight up."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.planning.pick_place import Planner
from kitchenbot.transforms import from_rotvec

# (rotation vector, position; base frame): the true poses, and the fitted ones perception gave
LOWER = ((-0.808945, 0.212234, 2.235314), (0.564417, -0.044593, -0.096473))
UPPER = ((-1.682054, 0.748794, 2.187913), (0.564166, -0.035112, -0.04648))
LOWER_FIT = ((0.07944, -0.735381, -1.448544), (0.564763, -0.044117, -0.096236))
UPPER_FIT = ((-0.55945, -1.280681, -0.31709), (0.564185, -0.034892, -0.04627))
Q_SCAN = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])  # the last scan waypoint (config/sim.yaml)


@pytest.fixture
def tilted_in(sim_items):
    """The SimWorld with the two bowls (true poses), and the two as perceived (fitted poses)."""
    return sim_items([("bowl", from_rotvec(*true), from_rotvec(*fit)) for true, fit in ((LOWER, LOWER_FIT),
                                                                                         (UPPER, UPPER_FIT))])


def test_the_bowl_tilted_in_another_is_lifted_without_a_contact_made_again(planner, tilted_in, lift_contact):
    world, (lower, upper) = tilted_in
    pick = planner.plan_pick(Q_SCAN, [lower, upper], target=upper)
    assert pick.ok, str(pick)
    contact = lift_contact(world, pick, upper)
    assert contact is None, f"{pick.grasp.spec.name}: {contact}"


def test_straight_up_the_contact_breaks_in_the_world_and_is_made_again(planner, tilted_in, straight_up,
                                                                        sim_contact_along):
    """The cause: the straight-up lift, which the fitted poses see as one contact, is stopped in the world."""
    world, (lower, upper) = tilted_in
    pick = planner.plan_pick(Q_SCAN, [lower, upper], target=upper)
    assert pick.ok, str(pick)
    world.set_joints(pick.grasp.q)
    world.attach(upper.instance_id, slip=False)
    world.gripper_opening = pick.grasp.spec.opening
    try:
        contact = sim_contact_along(world, straight_up(pick.grasp.q, 0.002, 0.05), {"lower": lower.instance_id})
    finally:
        world.release()
    assert contact == "held hits lower"


def test_a_contact_that_shallows_then_deepens_may_be_made_again():
    """The rule on signed-gap profiles (m, negative: overlap) as the fitted poses give them along a lift."""
    remade = Planner._remade_within_fit
    mm = 0.001
    assert remade(np.array([-0.85, -0.84, -0.80, -0.73, -1.0, -1.0, -0.5, 0.2, 1.0]) * mm)  # the bowl's, straight up
    assert remade(np.array([-0.3, -0.2, 0.1, -0.1, 0.5]) * mm)  # parts and touches again
    assert not remade(np.array([-0.85, -0.8, -0.6, -0.3, 0.0, 0.4, 1.2, 3.0]) * mm)  # opens and stays open
    assert not remade(np.array([-3.0, -3.0, -3.0, -2.0, -1.0, 0.5, 3.0]) * mm)  # a deep overlap left for good
    assert not remade(np.array([-0.5, -0.49, -0.5, -0.49, 0.2, 3.0]) * mm)  # a wobble below the tolerance
    assert not remade(np.array([-0.5, 1.5, 3.0, 1.2, 3.0]) * mm)  # comes closer again, not back within the fit
