"""A lift that is neither straight up nor along the item's axis (tilted away from what it ran into, a sidestep) may
slide the held item along a tilted support instead of leaving it: the support too may keep its overlap there but
not get deeper. Before, supports were unchecked for the first LIFT_CONTACT_TRAVEL of any lift."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.config import CellConfig
from kitchenbot.fakes.world import SimWorld
from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import from_rotvec, inv
from kitchenbot.world.cell import Cell


def _T(p, rotvec) -> np.ndarray:
    return from_rotvec(rotvec, p)


# A mug lying on its side (65 degrees from upright) on a side plate tilted 20 degrees, a second mug lying across it.
# As perceived (the lower mug to 0.2 mm, the plate to 2 mm: the two overlap by 1.5 mm) and as they are (0.1 mm
# apart). Straight up and along the mug's axis run into the mug on it; tilted 45 degrees away from that mug, the
# lift slides the held mug along the plate: in the model the overlap deepens to 3.1 mm, in the world the mug
# touches the plate from 2.4 mm of travel (`held hits` the plate, a protective stop).
BELIEF = {
    "plate": ("side_plate", _T((0.54381, 0.05441, -0.16990), (0.25191, 0.30314, -1.54016))),
    "mug": ("mug", _T((0.39330, 0.03317, -0.15633), (-0.37715, 1.28983, 1.84052))),
    "upper": ("mug", _T((0.33166, 0.01524, -0.08277), (-0.09577, -1.01014, 0.55785))),
}
TRUTH = {
    "plate": _T((0.54502, 0.05570, -0.16954), (0.32634, 0.18124, -0.84601)),
    "mug": _T((0.39329, 0.03313, -0.15618), (-0.37737, 1.29123, 1.85122)),
    "upper": _T((0.33078, 0.01482, -0.08447), (-0.13297, -1.14181, 0.49378)),
}


def test_a_tilted_lift_does_not_slide_the_held_item_into_its_support(planner, home, sim_contact_along):
    objs = [ObjectPose(planner.inventory.by_name(n).obj_id, planner.inventory.by_name(n).cls, T, 1.0, instance_id=i)
            for i, (n, T) in enumerate(BELIEF.values())]
    plate, mug, upper = objs
    assert planner._lies_on(mug, plate) and planner._lies_on(upper, mug)
    pick = planner.plan_pick(home, objs, target=mug)
    if not pick.ok:  # no lift leaves the plate without sliding into it: the mug on it is named as in the way
        assert pick.kind == "cartesian_path_failed", pick
        return
    Q = np.asarray(pick.lift.q, float)
    lim = CellConfig().safety_limits()
    world = SimWorld(Cell(), planner.inventory, T_flange_tcp=lim.T_flange_tcp, q=Q[0].copy())
    uids = {k: world.add_object(planner.inventory.by_name(BELIEF[k][0]), T) for k, T in TRUTH.items()}
    world.held_uid = uids["mug"]
    world.T_tcp_held = inv(world.T_base_tcp()) @ TRUTH["mug"]
    world.gripper_opening = pick.grasp.spec.opening
    # before: the lift tilted 45 degrees, `held hits plate` 2.4 mm along it
    assert sim_contact_along(world, Q, uids) is None
