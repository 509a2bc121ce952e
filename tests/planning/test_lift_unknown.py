"""A lift blocked by something perception did not recognise (map voxels no perceived object explains): the
lifts tilt away from those voxels, and sideways-then-up lifts lead away from them, as they do from a perceived
item (planning.lift: `ran_into_unknown`, `unknown`). Before, only perceived items gave a direction to move away
from, so an item with an unrecognised one leaning over it was never lifted (nor was the unrecognised one picked:
it is no candidate), and what lay under it stayed in the sink too."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.lift import directions_away, sidesteps
from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import make_T

OVERHANG, GAP = 0.04, 0.025  # m the unrecognised plate reaches over the cup's rim, and above it (its voxels: 2 cm)


def test_directions_and_sidesteps_lead_away_from_unknown_voxels():
    centre = np.array([0.5, 0.0, -0.15])
    blob = np.array([[0.58, 0.01, -0.1], [0.6, -0.01, -0.1], [0.62, 0.0, -0.08]])  # towards +x
    up = [np.array([0.0, 0.0, 1.0])]
    ds = directions_away(centre, [], set(), up, unknown=blob)
    assert ds and all(d[0] < 0 and d[2] > 0 for d in ds)
    legs = sidesteps(centre, [], set(), unknown=blob)
    assert legs and all(leg[0] < 0 for leg in legs)
    assert directions_away(centre, [], set(), up) == [] and sidesteps(centre, [], set()) == []




def test_a_cup_under_an_unrecognised_plate_is_lifted_out_of_its_way(run_pick_on_fake_arm):
    from kitchenbot.executive.assembly import make_sim_world
    from kitchenbot.executive.config import load_config
    from kitchenbot.planning.pick_place import Planner

    cfg = load_config()
    world = make_sim_world(cfg, 0)
    for u in list(world.objects):
        world.remove_object(u)
    planner = Planner.from_config(cfg, world.inventory)
    inv = world.inventory
    lo, hi = planner.cell.sink_interior
    cup, plate = inv.by_name("cup"), inv.by_name("dinner_plate")
    c = np.array([(lo[0] + hi[0]) / 2 - 0.04, (lo[1] + hi[1]) / 2, lo[2] + cup.extents[2] / 2 + 0.001])
    rim = lo[2] + cup.extents[2]
    p = np.array([c[0] + cup.extents[0] / 2 - OVERHANG + plate.extents[0] / 2, c[1], rim + GAP + plate.extents[2] / 2])
    world.add_object(cup, make_T(t=c))
    world.add_object(plate, make_T(t=p))
    # perception recognised the cup only: the plate is map points (its top surface, as a camera from above sees it)
    P = np.asarray(plate.mesh.sample_points_uniformly(6000).points) + p
    P = P[P[:, 2] > p[2]]
    seen = ObjectPose(cup.obj_id, cup.cls, make_T(t=c), 1.0, instance_id=1)
    home = np.asarray(cfg.robot.home, float)
    pick = planner.plan_pick(home, [seen], target=seen, map_points=P)
    assert pick.ok, pick
    P_lift = np.array([planner.robot.fk_tcp(q)[:3, 3] for q in pick.lift.q])
    assert P_lift[-1, 0] < P_lift[0, 0] - 0.02  # away from the plate (it lies towards +x)
    run_pick_on_fake_arm(cfg, world, pick)


def test_a_failed_pick_says_what_failed_for_each_grasp_it_tried(planner, home, resting):
    """details["candidates"]: one line per grasp tried, naming the grasp, the failure and its segment (what the
    journal keeps of a pick that failed: which straight segment failed, and on what)."""
    from kitchenbot.perception.types import ObjectPose

    plate = resting("side_plate", (0.45, 0.0), 7)
    cup_m = planner.inventory.by_name("cup")
    z = plate.T_base_obj[2, 3] + planner.inventory[plate.obj_id].extents[2] / 2 + cup_m.extents[2] / 2 - 0.015
    cup = ObjectPose(cup_m.obj_id, cup_m.cls, make_T(t=(0.45, 0.0, z)), 1.0, instance_id=9)  # in the plate's well
    res = planner.plan_pick(home, [plate, cup], target=plate)
    assert res.kind == "cartesian_path_failed", res
    lines = res.details["candidates"]
    assert len(lines) == res.details["candidates_tried"] >= 1
    assert all(": cartesian_path_failed: lift: " in s for s in lines) and "held/obj:9" in lines[0], lines
