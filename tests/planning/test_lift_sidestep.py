"""A lift in two legs (planning.lift.sidesteps, Planner._two_leg_lift): a cup with a plate's rim overhanging it
runs into the plate on every line that rises at once (straight up, tilted 30 / 45 degrees away from it); moved
out from under it nearly level first, it then goes straight up. The simulator runs the lift without a collision."""

from __future__ import annotations

import numpy as np

import kitchenbot.planning.pick_place as pick_place
from kitchenbot.planning.lift import SIDESTEPS, sidesteps
from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import make_T

OVERHANG, GAP = 0.06, 0.025  # m the plate reaches over the cup's rim, and above it


def test_sidesteps_lead_away_from_what_the_lifts_ran_into_nearly_level():
    plate = ObjectPose(0, "dinner_plate", make_T(t=(0.6, 0.0, -0.1)), 1.0, instance_id=2)
    legs = sidesteps(np.array([0.5, 0.0, -0.15]), [plate], {"2"})
    assert len(legs) == 3 * len(SIDESTEPS)
    assert all(leg[0] < 0 for leg in legs)  # away from the plate (it lies towards +x)
    assert all(leg[2] < 0.5 * np.linalg.norm(leg[:2]) for leg in legs)  # nearly level
    assert np.linalg.norm(legs[0][:2]) <= np.linalg.norm(legs[-1][:2])  # shortest first
    assert sidesteps(np.array([0.5, 0.0, -0.15]), [plate], set()) == []


def _cup_under_a_plate(world=None, planner=None):
    """(cup, plate) poses: the cup upright on the sink floor, a plate held level GAP above its rim reaching
    OVERHANG over it (added to `world` when given: the cup dropped onto the floor, the plate where it is)."""
    inv = (world or planner).inventory
    lo, hi = (world or planner).cell.sink_interior
    cup, plate = inv.by_name("cup"), inv.by_name("dinner_plate")
    c = np.array([(lo[0] + hi[0]) / 2 - 0.04, (lo[1] + hi[1]) / 2, lo[2] + cup.extents[2] / 2 + 0.001])
    rim = lo[2] + cup.extents[2]
    p = np.array([c[0] + cup.extents[0] / 2 - OVERHANG + plate.extents[0] / 2, c[1], rim + GAP + plate.extents[2] / 2])
    if world is None:
        return (ObjectPose(cup.obj_id, cup.cls, make_T(t=c), 1.0, instance_id=1),
                ObjectPose(plate.obj_id, plate.cls, make_T(t=p), 1.0, instance_id=2))
    world.add_object(cup, make_T(t=c))
    world.add_object(plate, make_T(t=p))
    return None


def test_a_cup_under_an_overhanging_plate_is_lifted_out_sideways_then_up(monkeypatch, run_pick_on_fake_arm):
    from kitchenbot.executive.assembly import make_sim_world
    from kitchenbot.executive.config import load_config
    from kitchenbot.executive.oracle import OraclePerceiver
    from kitchenbot.planning.pick_place import Planner

    cfg = load_config()
    world = make_sim_world(cfg, 0)
    for u in list(world.objects):
        world.remove_object(u)
    _cup_under_a_plate(world=world)
    planner = Planner.from_config(cfg, world.inventory)
    home = np.asarray(cfg.robot.home, float)
    poses = OraclePerceiver(world).perceive([]).poses
    cup = next(p for p in poses if p.cls == "cup")
    plate = next(p for p in poses if p.cls != "cup")
    with monkeypatch.context() as m:
        m.setattr(pick_place, "sidesteps", lambda *a, **k: [])
        blocked = planner.plan_pick(home, poses, target=cup)
    assert blocked.kind == "cartesian_path_failed", blocked
    assert blocked.details.get("blocking") == plate.instance_id  # what blocker_first would take first
    pick = planner.plan_pick(home, poses, target=cup)
    assert pick.ok, pick
    assert pick.timings_ms.get("lift_sidestep_m", 0.0) > 0.0
    P = np.array([planner.robot.fk_tcp(q)[:3, 3] for q in pick.lift.q])
    assert P[-1, 2] - P[0, 2] >= planner.settings.lift_height  # then straight up
    run_pick_on_fake_arm(cfg, world, pick)
