"""A bowl lying tilted 5.5 degrees with its underside on the outer rim of a stack of plates, its foot ring about a
millimetre under the top plate's flange, seen through fitted poses a fraction of a millimetre (and 0.6 degrees of
tilt) off, both items about half seen (not doubtful). Lifted straight up, in the world the bowl parts from the plate
by 0.27 mm and 3.5 mm higher its foot meets the flange from below (a contact made again: the simulator's protective
stop); in the fitted poses the gap opens to 1.40 mm and narrows back to 1.02 mm, never touching, and the planner
planned that lift. Now a gap to a start contact that narrows again after parting, within Planner.FIT_POSE_REACH of
the start's, counts as a contact that may be made again (Planner._remade_in_fit): the lift that first parts the
two (planning.lift.separating_legs) is tried before the straight one."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.planning.pick_place import Planner
from kitchenbot.transforms import from_rotvec

# (rotation vector, position; base frame): the true poses, and the fitted ones perception gave
BOWL = ((-0.011113, -0.10091, -0.975451), (0.361319, 0.118029, -0.129694))
BOWL_FIT = ((0.017369, -0.094235, -1.554418), (0.360853, 0.118485, -0.129639))
TOP_PLATE = ((-0.049787, -0.011983, 2.216857), (0.51053, 0.028712, -0.162395))
TOP_PLATE_FIT = ((0.025559, -0.039957, -1.572647), (0.510838, 0.028877, -0.162349))
MID_PLATE = ((-0.010153, -0.038245, -0.107534), (0.522733, 0.022154, -0.175252))
MID_PLATE_FIT = ((0.023247, -0.041543, -1.572881), (0.522249, 0.022471, -0.175992))
Q_SCAN = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])  # the last scan waypoint (config/sim.yaml)


@pytest.fixture
def bowl_on_plates(sim_items):
    return sim_items([(name, from_rotvec(*true), from_rotvec(*fit)) for name, true, fit in (
        ("bowl", BOWL, BOWL_FIT), ("dinner_plate", TOP_PLATE, TOP_PLATE_FIT), ("dinner_plate", MID_PLATE, MID_PLATE_FIT))])


def test_the_bowl_with_its_foot_under_a_plates_flange_is_lifted_without_a_contact_made_again(
        planner, bowl_on_plates, lift_contact):
    world, (bowl, top, mid) = bowl_on_plates
    pick = planner.plan_pick(Q_SCAN, [bowl, top, mid], target=bowl)
    assert pick.ok, str(pick)
    contact = lift_contact(world, pick, bowl)
    assert contact is None, f"{pick.grasp.spec.name}: {contact}"


def test_a_gap_that_narrows_again_within_the_fits_error_may_close():
    """The rule on signed-gap profiles (m, negative: overlap) as the fitted poses give them along a lift."""
    mm = 0.001
    reach, tol = Planner.FIT_POSE_REACH, 0.0001
    # this bowl: parts to 1.40 mm, narrows to 1.02 mm (1.8 mm above the start's -0.78 mm): may close in the world
    assert Planner._remade_within(np.array([-0.78, 0.21, 1.40, 1.27, 1.02, 1.13, 2.16]) * mm, reach, tol)
    # parting steadily: no
    assert not Planner._remade_within(np.array([-0.78, 0.21, 1.40, 1.9, 2.5, 3.0]) * mm, reach, tol)
    # narrowing again only far from the start (more than the reach above it): no
    assert not Planner._remade_within(np.array([-0.78, 1.5, 2.8, 2.4, 2.9]) * mm, reach, tol)
