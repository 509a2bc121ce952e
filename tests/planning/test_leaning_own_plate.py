"""A round plate known only by its mesh, leaning against a basin wall: its lip pinches from the antipodal synthesis
all put the palm, the wrist or a pad into the wall or the counter (the wall-side pad where the upper lip touches the
wall, the gripper over the counter at the lip's sides), or come from below, so it had no grasp at all and stayed in
the sink. The builtin plates have a narrow lip pinch rolled 45 degrees for this (from above at the lip's side,
`rimnarrow`); a plate known by its mesh gets it too now (`grasp_synthesis.narrow_lip_pinches`). Checked as the
simulator sees it: approach and grasp free of contact, the simulated Fin-Ray holds the plate, the lift free of
contact with the plate held. Partial: at this pose one of the narrow pinch's 12 rim copies is free; 4 cm along the
wall, or the plate turned 15 degrees about its axis, none is yet (docs/executive_measurements.md, lean31)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.config import CellConfig
from kitchenbot.fakes.gripper import FakeGripper
from kitchenbot.fakes.world import SimWorld
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.grasp_synthesis import cached_synthesis, generate_grasps
from kitchenbot.planning.pick_place import Planner
from kitchenbot.transforms import rot_x
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory

pytestmark = pytest.mark.timeout(600)

LEAN = np.radians(21.0)  # off vertical, its underside to the wall (as seen with set F's side plate)


def _leaning(model, sink_hi, sink_lo, x: float = 0.45) -> np.ndarray:
    """The pose of `model` leaning LEAN against the basin's +y wall (1 mm off it), its mouth towards the basin's
    middle, its low rim 1 mm above the floor."""
    T = rot_x(np.pi / 2 - LEAN)
    V = np.asarray(model.mesh.vertices) @ T[:3, :3].T
    T[:3, 3] = (x, sink_hi[1] - 0.001 - V[:, 1].max(), sink_lo[2] + 0.001 - V[:, 2].min())
    return T


def _picked_in_the_simulator(inventory, model, T_plate, pick, sim_contact_along, lift_contact) -> None:
    """The simulator's checker passes the pick: approach and grasp free of contact, the Fin-Ray closing holds the
    plate, the lift free of contact with it held."""
    lim = CellConfig().safety_limits()
    Q = np.vstack([pick.approach.q, pick.grasp_in.q])
    world = SimWorld(Cell(), inventory, T_flange_tcp=lim.T_flange_tcp, q=Q[0].copy())
    uid = world.add_object(model, T_plate)
    g = FakeGripper(world)
    g.connect()
    g.open(pick.grasp.spec.opening)
    assert sim_contact_along(world, Q, {"plate": uid}) is None
    world.set_joints(Q[-1])
    r = g.grasp(0.8)
    assert r.holding and world.held_uid == uid, r
    world.release()
    item = ObjectPose(model.obj_id, model.cls, T_plate, 1.0, instance_id=uid)
    assert lift_contact(world, pick, item) is None


@pytest.fixture(scope="module")
def own_f(own_dishware_f, tmp_path_factory):
    """(inventory, the side plate with its grasps synthesised from its mesh) of set F; only the plate synthesised
    (the planner needs the grasps of no other item here)."""
    folder, names = own_dishware_f
    inventory = Inventory.load(folder)
    plate = inventory[next(k for k, (name, _) in names.items() if name == "small_side_plate")]
    plate.grasps = cached_synthesis(plate, tmp_path_factory.mktemp("grasps_f"))
    return inventory, plate


def test_a_round_plate_known_by_its_mesh_gets_the_narrow_rolled_lip_pinches(own_f, sim_holds):
    inventory, plate = own_f
    names = [g.name for g in plate.grasps]
    for roll in ("+0", "+45", "-45"):
        assert sum(n.startswith(f"rimnarrow{roll}_") for n in names) == 12, roll
    # each closes across the lip: about the thickness of its rim, not across the plate
    assert all(0.002 < g.width < 0.015 for g in plate.grasps if g.name.startswith("rimnarrow"))
    # the same pinches, where they are, as a builtin plate of that profile gets them
    built = {g.name: g for g in generate_grasps(plate) if g.name.startswith("rimnarrow")}
    for g in plate.grasps:
        if g.name.startswith("rimnarrow"):
            assert np.allclose(g.T_obj_tcp, built[g.name].T_obj_tcp, atol=1e-6), g.name
    # the simulated Fin-Ray holds the plate with them (each roll, a few places round the rim)
    sim_holds(inventory, plate, [g for g in plate.grasps if g.name.startswith("rimnarrow")][::5], width_tol=0.006)


def test_a_set_f_side_plate_leaning_on_a_basin_wall_is_picked(own_f, sim_contact_along, lift_contact):
    inventory, plate = own_f
    cfg = CellConfig()
    planner = Planner.from_config(cfg, inventory)
    lo, hi = planner.cell.sink_interior
    T = _leaning(plate, hi, lo)
    obj = ObjectPose(plate.obj_id, plate.cls, T, 1.0, instance_id=1)
    pick = planner.plan_pick(np.asarray(cfg.robot.home, float), [obj], target=obj)
    assert pick.ok, pick  # before: no_collision_free_grasp (every synthesised pinch collides or comes from below)
    assert pick.grasp.spec.name.startswith("rimnarrow")
    _picked_in_the_simulator(inventory, plate, T, pick, sim_contact_along, lift_contact)


def test_a_builtin_side_plate_leaning_on_a_basin_wall_is_picked(planner, inventory, home, sim_contact_along,
                                                                 lift_contact):
    """The builtin side plate had the narrow pinches already (passes before and after): the same check."""
    plate = inventory.by_name("side_plate")
    lo, hi = planner.cell.sink_interior
    T = _leaning(plate, hi, lo)
    obj = ObjectPose(plate.obj_id, plate.cls, T, 1.0, instance_id=1)
    pick = planner.plan_pick(home, [obj], target=obj)
    assert pick.ok, pick
    _picked_in_the_simulator(inventory, plate, T, pick, sim_contact_along, lift_contact)

