"""A flared wall's pinches close along its normal, so they are approached along its slope or across it, and their
outer pad lies in the space under the flare: where a second bowl of the kind is when one leans in the other. A
Fin-Ray takes such a rim from straight above, the pads closing level across the top of the wall (one inside the
bowl, one outside its lip). Synthesised as `rimlevel` fallbacks (planning/grasp_synthesis.py); here a straight-
walled conical bowl (set B of the own dishware, grasps from the mesh) leaning in another one on the sink floor
has no other grasp free, and the simulated arm lifts it with one of them."""

from __future__ import annotations

import coal
import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.collision import coal_transform
from kitchenbot.planning.grasp_synthesis import RIM_LEVEL
from kitchenbot.planning.grasps import FALLBACK_GRASPS, GraspStats, select_grasps
from kitchenbot.transforms import make_T, rot_x


@pytest.fixture(scope="module")
def cone(own_b):
    inv, by_name = own_b
    return inv, by_name["conical_bowl"]


def _leaning_pair(planner, bowl, tilt_deg: float, shift: float) -> list[ObjectPose]:
    """One bowl upright on the sink floor's middle; a second tilted `tilt_deg` about x, moved `shift` along y,
    lowered until it rests in the first."""
    lo, hi = planner.cell.sink_interior
    c = (lo + hi) / 2
    T_low = make_T(t=(c[0], c[1], lo[2] - np.asarray(bowl.mesh.vertices)[:, 2].min() + 0.001))
    R = rot_x(np.radians(tilt_deg))[:3, :3]
    z = T_low[2, 3] + 0.1
    while not coal.collide(planner.world.bvh(bowl), coal_transform(make_T(R, (c[0], c[1] + shift, z))),
                           planner.world.bvh(bowl), coal_transform(T_low), coal.CollisionRequest(),
                           coal.CollisionResult()):
        z -= 0.0005
    T_up = make_T(R, (c[0], c[1] + shift, z + 0.001))
    return [ObjectPose(bowl.obj_id, bowl.cls, T_low, 1.0, instance_id=1),
            ObjectPose(bowl.obj_id, bowl.cls, T_up, 1.0, instance_id=2)]


def test_a_conical_bowl_leaning_in_another_is_pinched_at_its_rim_from_above(cone, cfg, home, run_pick_on_fake_arm):
    from kitchenbot.fakes.world import SimWorld
    from kitchenbot.planning.pick_place import Planner
    from kitchenbot.world.cell import Cell

    inv, bowl = cone
    assert bowl.cls == "bowl"
    assert RIM_LEVEL in FALLBACK_GRASPS
    level = [g for g in bowl.grasps if g.name.startswith(RIM_LEVEL)]
    assert level and all(g.T_obj_tcp[2, 2] < -0.99 for g in level)  # straight down along the bowl's axis
    planner = Planner.from_config(cfg, inv)
    objects = _leaning_pair(planner, bowl, 8.0, 0.02)
    assert objects[1].T_base_obj[2, 3] - objects[0].T_base_obj[2, 3] > 0.02  # leaning in it, not nested
    st = GraspStats()
    grasps = select_grasps(planner.robot, planner.scene(objects), inv, objects, home, settings=planner.settings,
                           target=objects[1], stats=st)
    assert isinstance(grasps, list), st.__dict__
    # every grasp along or across the flared wall takes in the lower bowl or meets it; level rim pinches do not
    assert all(g.spec.name.startswith(RIM_LEVEL) for g in grasps), [g.spec.name for g in grasps]
    assert st.multi_object > 0
    pick = planner.plan_pick(home, objects, target=objects[1])
    assert pick.ok, pick
    world = SimWorld(Cell(), inv, T_flange_tcp=cfg.safety_limits().T_flange_tcp, q=home.copy())
    for o in objects:
        world.add_object(bowl, np.asarray(o.T_base_obj, float))
    run_pick_on_fake_arm(cfg, world, pick)
    assert world.held_uid == 2  # the upper bowl (added second)
