"""The top plate of a messy stack of three dinner plates in the basin: each plate landed off-centre on the one below
and tipped (9 and 11.5 degrees) towards the basin's -x wall, the top one overhanging the plates below only on the
sides where it is close to a wall. Every pinch of the top plate meets the rim of the plate under it (or the wall), so
the planner answers `no_collision_free_grasp` and names the plate under it as what crowds its grasps
(`crowded_by`). That plate cannot go first (the top plate lies on it, and its own failure names the top plate): with
the named blocker, `slide_off_stack` did not apply (it stays out where the failure names a blocker, for a plate with
an item on it), `slide_off_blocked` could not push a dinner plate off another one 6 cm away, and `blocker_first`
went round the stack until the attempts ran out, all three plates left in the sink. Now a named blocker that the
plate itself lies on does not keep the slide from applying: the top plate is slid, then a pinch of it is free and
the simulated arm picks it."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.oracle import OraclePerceiver
from kitchenbot.fakes.placement import drop_onto
from kitchenbot.transforms import from_rotvec, make_T

from .conftest import plan_with_strategies

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def stack(empty_sim_cell):
    """The sink emptied; three dinner plates dropped onto each other near the basin's -x wall: the lowest flat on
    the floor, the middle one 3.7 cm towards the wall and tipped 9 degrees (its far edge down on the floor), the top
    one 2 cm farther and tipped 11.5 degrees. Returns (cfg, world, planner, [lowest, middle, top] uids)."""
    cfg, world, planner = empty_sim_cell()
    plate = world.inventory.by_name("dinner_plate")

    def drop(xy, tilt_deg, towards):
        """A plate dropped at `xy`, its axis tipped `tilt_deg` towards the level direction `towards`."""
        axis = np.array([-towards[1], towards[0], 0.0])
        T = make_T(from_rotvec(axis / np.linalg.norm(axis) * np.radians(tilt_deg))[:3, :3], (xy[0], xy[1], 0.05))
        uid = world.add_object(plate, T)
        world.set_pose(uid, drop_onto(world, uid, T))
        return uid

    uids = [drop((0.445, 0.030), 0.0, (1.0, 0.0)), drop((0.409, 0.034), 9.0, (1.0, 0.0)),
            drop((0.397, 0.049), 11.5, (0.95, -0.32))]
    z = [world.objects[u].T_base_obj[2, 3] for u in uids]
    assert z[0] < z[1] < z[2]  # stacked, in that order
    return cfg, world, planner, uids


def test_the_top_plate_of_a_messy_stack_is_slid_then_picked(stack, run_slide, run_pick_on_fake_arm):
    cfg, world, planner, (lowest, middle, top_uid) = stack
    poses = OraclePerceiver(world).perceive([]).poses
    top = next(p for p in poses if p.instance_id == top_uid)
    plan, counts = plan_with_strategies("sink-pick", top, world, planner, poses)
    # the direct pick found no collision-free pinch (the plates under it crowd them); the slide applied
    assert counts["direct_pick"] == {"tried": 1, "planned": 0}
    assert plan.strategy == "slide_off_stack" and plan.slide is not None, counts
    run_slide(world, cfg, plan.slide, top_uid)
    # the next look sees it overhanging the plate under it: a pinch is free, and the simulated arm (its own
    # contact checks) takes it out of the stack without touching anything
    poses = OraclePerceiver(world).perceive([]).poses
    top = next(p for p in poses if p.instance_id == top_uid)
    pick = planner.plan_pick(world.q.copy(), poses, target=top)
    assert pick.ok, pick
    run_pick_on_fake_arm(cfg, world, pick)
    assert world.held_uid == top_uid
