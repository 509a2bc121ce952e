"""Lift directions: straight up first, then up and away from the basin walls (a plate leaning on a wall)."""

from __future__ import annotations

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.fcl_check import FclChecker, verify_pick
from kitchenbot.planning.placement import SlotBook


def test_lift_directions_are_up_then_towards_the_sink_middle(planner):
    lo, hi = planner.cell.sink_interior
    mid = (np.asarray(lo) + np.asarray(hi)) / 2
    p = mid + np.array([0.0, 0.12, 0.0])  # near the back wall
    ds = planner._lift_directions(p)
    assert np.allclose(ds[0], (0, 0, 1))
    for d in ds[1:]:
        assert abs(np.linalg.norm(d) - 1) < 1e-9 and d[2] >= np.cos(np.radians(50)) - 1e-9
        assert d[:2] @ (mid - p)[:2] > 0  # away from the back wall
    assert np.degrees(np.arccos(ds[1] @ np.array([0, -1.0, 0]) / np.linalg.norm(ds[1]))) < 90 - 29


def test_a_tilted_object_is_also_lifted_along_its_axis(planner):
    from kitchenbot.transforms import make_T, rot_x

    lo, hi = planner.cell.sink_interior
    p = (np.asarray(lo) + np.asarray(hi)) / 2
    tilted = make_T(t=p) @ rot_x(np.radians(25))
    ds = planner._lift_directions(p, tilted)
    assert np.allclose(ds[0], (0, 0, 1)) and np.allclose(ds[1], tilted[:3, 2])
    upside_down = make_T(t=p) @ rot_x(np.radians(180 - 25))  # its upward axis is -z
    assert np.allclose(planner._lift_directions(p, upside_down)[1], -upside_down[:3, 2])
    flat = planner._lift_directions(p, make_T(t=p) @ rot_x(np.radians(2)))
    lying = planner._lift_directions(p, make_T(t=p) @ rot_x(np.radians(85)))
    assert len(flat) == len(lying) == len(ds) - 1  # no extra direction for a flat or lying item


def test_plate_leaning_on_the_back_wall_is_lifted_away_from_it(planner, home, inventory, cfg):
    """Seed 12 of the simulator's scenes: a side plate leans on the back wall (the glasses on it taken out);
    straight up it would slide along the wall, so the lift leaves it at an angle, re-checked by FCL."""
    from kitchenbot.fakes.scenes import generate_scene

    world = generate_scene(12, inventory, cfg.cell)
    objs = [ObjectPose(o.model.obj_id, o.model.cls, o.T_base_obj, 1.0, instance_id=u)
            for u, o in world.objects.items() if o.model.cls == "side_plate" or o.model.name == "side_plate"]
    leaning = max(objs, key=lambda o: o.T_base_obj[2, 3])
    assert abs(leaning.T_base_obj[2, 2]) < 0.7  # it leans
    targets = SlotBook(planner.cell).targets_for(inventory[leaning.obj_id])[:4]
    pick = planner.plan_pick(home, objs, target=leaning, place_target=targets)
    assert pick.ok, str(pick)
    T0 = planner.robot.fk(pick.lift.q[0])
    T1 = planner.robot.fk(pick.lift.q[-1])
    move = T1[:3, 3] - T0[:3, 3]
    assert move[2] > 0.07 and np.linalg.norm(move[:2]) > 0.05  # up and away from the wall, not straight up
    checker = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
    bad = [(n, str(r)) for n, r in verify_pick(checker, planner, pick, objs, step=0.003) if not r.ok]
    assert not bad


def test_only_items_near_a_wall_get_the_away_from_wall_lifts(planner, inventory):
    from kitchenbot.transforms import make_T

    lo, hi = planner.cell.sink_interior
    mid = (np.asarray(lo) + np.asarray(hi)) / 2
    cup = inventory.by_name("cup")
    centre = ObjectPose(cup.obj_id, "cup", make_T(t=mid), 1.0, instance_id=1)
    by_wall = ObjectPose(cup.obj_id, "cup", make_T(t=(mid[0], hi[1] - 0.05, mid[2])), 1.0, instance_id=2)
    assert not planner._near_sink_wall(centre) and planner._near_sink_wall(by_wall)
    p = mid + np.array([0.0, 0.1, 0.0])
    assert len(planner._lift_directions(p, away_from_walls=False)) == 1
    assert len(planner._lift_directions(p, away_from_walls=True)) == 5
