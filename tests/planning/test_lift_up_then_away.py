"""An item resting against a basin wall whose every lift failed: straight up it slides along the wall past the start
contacts' travel (LIFT_CONTACT_TRAVEL), and every line tilted away from the wall from the grasp drags its lower end
through the item it rests on or in. Up along the wall within that travel first, then tilted towards the sink's
middle (Planner._up_then_away), it comes out: the simulator sees no contact on that lift (it tolerates a start
contact that lasts unbroken while the item is lifted off).

Scenes: an upturned cup tilted by 13 degrees on an upturned cup, its side against the left basin wall (a cup left in
the sink after every one of its plans failed so); the glass lying over an upturned cup of test_lift_wall_gap.py, its
base end touching the back wall."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.fakes.world import SimWorld
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.pick_place import LIFT_CONTACT_TRAVEL, UP_THEN_AWAY
from kitchenbot.transforms import from_rotvec
from kitchenbot.world.cell import Cell

Q_SCAN = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])  # the last scan waypoint (config/sim.yaml)


def _upturned(tilt_deg: float, xyz) -> np.ndarray:
    """An upturned cup's pose (its axis down), tilted by `tilt_deg` about the base x axis (its top towards +y)."""
    T = from_rotvec((np.pi, 0.0, 0.0), xyz)
    R = from_rotvec((np.radians(tilt_deg), 0.0, 0.0), (0.0, 0.0, 0.0))
    T[:3, :3] = R[:3, :3] @ T[:3, :3]
    return T


def _gap(model, T: np.ndarray, axis: int, wall: float, sign: float) -> float:
    V = np.asarray(model.mesh.vertices) @ T[:3, :3].T + T[:3, 3]
    return float(sign * (wall - V[:, axis].max()) if sign > 0 else V[:, axis].min() - wall)


def _wedged_cups(cfg, inventory):
    """An upturned cup on the sink floor by the left wall (+y) and an upturned cup tilted on it, its side touching
    that wall; (world, [lower, upper])."""
    cell = Cell()
    world = SimWorld(cell, inventory, T_flange_tcp=cfg.safety_limits().T_flange_tcp, q=np.array(cfg.robot.home))
    cup = inventory.by_name("cup")
    lo, hi = (np.asarray(v, float) for v in cell.sink_interior)
    T_low = from_rotvec((np.pi, 0.0, 0.0), (0.55, 0.151, lo[2] + cup.extents[2] / 2 + 0.001))
    T_up = _upturned(-12.5, (0.55, 0.162, T_low[2, 3] + 0.059))
    T_up[1, 3] += _gap(cup, T_up, 1, hi[1], 1.0)  # its side on the wall (no gap)
    poses = [ObjectPose(cup.obj_id, "cup", T, 1.0, instance_id=world.add_object(cup, T)) for T in (T_low, T_up)]
    return world, poses


def test_the_scene_is_a_wedge(cfg, inventory):
    """The upper cup's side touches the left wall (no gap): the case the fallback is for."""
    world, (low, up) = _wedged_cups(cfg, inventory)
    cup = inventory.by_name("cup")
    hi = np.asarray(Cell().sink_interior[1], float)
    assert abs(_gap(cup, up.T_base_obj, 1, hi[1], 1.0)) < 1e-6


def test_an_upturned_cup_wedged_against_the_wall_is_lifted_up_then_away(cfg, inventory, planner, lift_contact):
    world, (low, up) = _wedged_cups(cfg, inventory)
    pick = planner.plan_pick(Q_SCAN, [low, up], target=up)
    assert pick.ok, str(pick) + str(pick.details.get("candidates", ""))[:600]
    assert pick.timings_ms.get("lift_up_then_away") == 1.0
    contact = lift_contact(world, pick, up)
    assert contact is None, f"{pick.grasp.spec.name}: {contact}"
    # straight up for the start contacts' travel, then away from the wall (-y), never towards it
    P = np.array([planner.robot.fk_tcp(q)[:3, 3] for q in pick.lift.q])
    up_leg = P[np.linalg.norm(P - P[0], axis=1) <= UP_THEN_AWAY[0] - 1e-3]
    assert np.abs(up_leg[:, :2] - P[0, :2]).max() < 1e-3
    assert P[-1, 1] < P[0, 1] - 0.02 and np.all(np.diff(P[:, 1]) < 1e-4)
    assert UP_THEN_AWAY[0] <= LIFT_CONTACT_TRAVEL


def test_a_lift_that_planned_before_is_unchanged(cfg, inventory, planner):
    """The same cup a centimetre off the wall: a lift tilted from the grasp plans, as before (no up-then-away)."""
    world, (low, up) = _wedged_cups(cfg, inventory)
    up.T_base_obj[1, 3] -= 0.01
    pick = planner.plan_pick(Q_SCAN, [low, up], target=up)
    assert pick.ok, str(pick)
    assert "lift_up_then_away" not in pick.timings_ms
