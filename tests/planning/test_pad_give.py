"""The Fin-Ray pads' give (planning/pad_give.py): a grasp whose pad envelope brushes a neighbour by a few
millimetres is admitted, bounded, and the simulator (its own finger geometry and contact rules) runs it without a
collision; deeper, it is rejected as before."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.planning import grasps as grasps_mod
from kitchenbot.planning.grasps import expand_grasps
from kitchenbot.planning.pad_give import PAD_GIVE
from kitchenbot.world.gripper import FINGERS, PAD_ENVELOPE

# rim_00 of the glass: a pinch of the rim wall from straight above, the closing axis along the glass's x; its outer
# pad envelope's outer face lies OUTER m from the glass's axis, and the glass is RADIUS m wide at most.
OUTER = 0.032 + 0.0325 / 2 + PAD_ENVELOPE.thickness
RADIUS = 0.036


def test_give_leaves_the_physical_finger_clear():
    from kitchenbot.planning.settings import PlanningSettings

    assert PAD_GIVE == pytest.approx(PAD_ENVELOPE.thickness - FINGERS.finger_thickness - 0.001)
    assert PlanningSettings().pad_give == 0.0  # off by default (planning/settings.py says why)
    assert PlanningSettings(pad_give=PAD_GIVE).pad_give == pytest.approx(PAD_GIVE)


def _two_glasses(gap_into_envelope: float):
    """A sim world with two glasses upright on the sink floor along x, the second one reaching
    `gap_into_envelope` metres into the first one's rim_00 outer pad envelope."""
    from kitchenbot.executive.assembly import make_sim_world
    from kitchenbot.executive.config import load_config
    from kitchenbot.fakes.placement import drop_onto
    from kitchenbot.transforms import make_T

    cfg = load_config()
    world = make_sim_world(cfg, 0)
    for u in list(world.objects):
        world.remove_object(u)
    m = world.inventory.by_name("glass")
    lo, _ = world.cell.sink_interior
    for x in (0.45, 0.45 + OUTER + RADIUS - gap_into_envelope):
        uid = world.add_object(m, make_T(t=(x, 0.0, lo[2] + m.extents[2] / 2 + 0.005)))
        world.set_pose(uid, drop_onto(world, uid, world.objects[uid].T_base_obj))
    return cfg, world, m


def _setup(gap):
    from kitchenbot.executive.oracle import OraclePerceiver
    from kitchenbot.planning.pick_place import Planner

    cfg, world, m = _two_glasses(gap)
    planner = Planner.from_config(cfg, world.inventory)
    poses = OraclePerceiver(world).perceive([]).poses
    target = min(poses, key=lambda p: p.T_base_obj[0, 3])
    # only this one grasp: the others would go round the neighbour
    avoid = tuple(s.name for s in expand_grasps(planner.inventory[m.obj_id]) if s.name != "rim_00")
    return cfg, world, planner, poses, target, avoid


def test_pads_brushing_a_neighbour_within_their_give_grasp_it_without_a_collision(run_pick_on_fake_arm, monkeypatch):
    # the pads opened as wide as given (no narrowed grasp: planning.grasps' third pass would take the glass with
    # its pads opened narrower, clear of the neighbour, and the give would not be what is tested)
    monkeypatch.setattr(grasps_mod, "NARROW_SLACKS", ())
    cfg, world, planner, poses, target, avoid = _setup(0.002)
    home = np.asarray(cfg.robot.home, float)
    planner.settings = planner.settings.model_copy(update={"pad_give": 0.0})
    assert planner.plan_pick(home, poses, target=target, avoid_grasps=avoid).kind == "no_collision_free_grasp"
    planner.settings = planner.settings.model_copy(update={"pad_give": PAD_GIVE})
    pick = planner.plan_pick(home, poses, target=target, avoid_grasps=avoid)
    assert pick.ok, pick
    assert pick.grasp.spec.name == "rim_00"
    neighbour = f"obj:{next(p.instance_id for p in poses if p is not target)}"
    assert {n for _, n in pick.grasp.pad_contacts} == {neighbour}
    run_pick_on_fake_arm(cfg, world, pick)


def test_a_neighbour_deeper_than_the_give_still_blocks_the_grasp_and_is_named_as_the_blocker(monkeypatch):
    monkeypatch.setattr(grasps_mod, "NARROW_SLACKS", ())  # the pads opened as wide as given (as above)
    cfg, world, planner, poses, target, avoid = _setup(0.005)
    planner.settings = planner.settings.model_copy(update={"pad_give": PAD_GIVE})
    home = np.asarray(cfg.robot.home, float)
    f = planner.plan_pick(home, poses, target=target, avoid_grasps=avoid)
    assert f.kind == "no_collision_free_grasp"
    neighbour = next(p for p in poses if p is not target)
    # nothing lies on the glass: the neighbour its grasps collide with is the one to take out first
    assert f.details["crowded_by"] == {str(neighbour.instance_id): 1}
    assert f.details["blocking"] == neighbour.instance_id
