"""A glass lying tilted over an upside-down cup, its mouth end against the cup's side and its base end up by a basin
wall, a millimetre and a half off it. The only way out is straight up: a lift tilted towards the sink's middle
drives the glass into the cup it leans on; one away from the cup runs into the wall. Straight up keeps the gap to
the (vertical) wall. The planner checked the wall with the grasp margin (2 mm) once the first 3 cm of lift
(LIFT_CONTACT_TRAVEL, for contacts the item rests in) were used up, as if the glass slid up along the wall: every
grasp's every lift failed, and the cup under the glass waited for it (a whole pile left in the sink). Now a wall the
held item is clear of at the grasp keeps, for the whole lift, the gap it has there (Planner._wall_gaps); an item
touching the wall is still lifted along it only within LIFT_CONTACT_TRAVEL."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.fakes.world import SimWorld
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.pick_place import LIFT_CLEARANCE_TOL
from kitchenbot.transforms import from_rotvec
from kitchenbot.world.cell import Cell

# (rotation vector, position; base frame): the cup upside down by the back wall; the glass across it, its axis
# 37 degrees below the horizontal, mouth end down against the cup's side, base end up towards the back wall
CUP = ((2.1145, -2.2989, 0.0027), (0.3776, 0.1272, -0.1508))
GLASS = ((0.1915, 2.2053, -0.0169), (0.3151, 0.1344, -0.0841))
Q_SCAN = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])  # the last scan waypoint (config/sim.yaml)


def _wall_gap(model, T: np.ndarray, cell: Cell) -> float:
    """Gap (m) between the item's mesh at T and the back basin wall (the sink's low-x side)."""
    V = np.asarray(model.mesh.vertices) @ T[:3, :3].T + T[:3, 3]
    return float(V[:, 0].min() - cell.sink_interior[0][0])


def _scene(cfg, inventory, gap: float):
    """SimWorld with the cup and the glass (its base end `gap` off the back wall), and their exact poses."""
    cell = Cell()
    world = SimWorld(cell, inventory, T_flange_tcp=cfg.safety_limits().T_flange_tcp, q=np.array(cfg.robot.home))
    cup, glass = inventory.by_name("cup"), inventory.by_name("glass")
    T_cup, T_glass = from_rotvec(*CUP), from_rotvec(*GLASS)
    T_glass[0, 3] += gap - _wall_gap(glass, T_glass, cell)
    poses = [ObjectPose(m.obj_id, m.cls, T, 1.0, instance_id=world.add_object(m, T))
             for m, T in ((cup, T_cup), (glass, T_glass))]
    return world, poses


def test_a_glass_clear_of_the_wall_by_less_than_the_grasp_margin_is_lifted_straight_up(cfg, inventory, planner, lift_contact):
    world, (cup, glass) = _scene(cfg, inventory, 0.0015)
    assert 0.0 < _wall_gap(inventory[glass.obj_id], glass.T_base_obj, planner.cell) < planner.settings.grasp_margin
    pick = planner.plan_pick(Q_SCAN, [cup, glass], target=glass)
    assert pick.ok, str(pick)
    contact = lift_contact(world, pick, glass)
    assert contact is None, f"{pick.grasp.spec.name}: {contact}"


@pytest.mark.parametrize("gap", [0.0015, 0.001])
def test_the_lift_keeps_the_gap_it_has_at_the_grasp(cfg, inventory, planner, gap):
    """Not closer than at the grasp: the held glass never comes nearer the wall than its gap less the tolerance."""
    world, (cup, glass) = _scene(cfg, inventory, gap)
    pick = planner.plan_pick(Q_SCAN, [cup, glass], target=glass)
    assert pick.ok, str(pick)
    held = planner.scene([cup, glass], None, exclude=glass, held=pick.grasp, own=[glass])
    pair = ("held", "cell:sink_wall_back")
    keep = max(gap - LIFT_CLEARANCE_TOL, planner.WALL_GAP_MIN / 2) - 1e-4  # the pair's margin, less the check's step
    assert not held.touching(pick.lift.q, pair, keep).any()


def test_a_glass_touching_the_wall_is_not_slid_up_along_it(cfg, inventory, planner, lift_contact):
    """The rule is for a gap: an item resting against the wall still leaves it within the first 3 cm (every line
    from the grasp fails: straight up slides along the wall, the tilted ones run into the cup); since the
    up-then-away lift (test_lift_up_then_away.py) it goes up 3 cm along the wall, then away from it, and the
    simulator sees no contact on that lift."""
    from kitchenbot.planning.pick_place import UP_THEN_AWAY

    world, (cup, glass) = _scene(cfg, inventory, 0.0001)
    pick = planner.plan_pick(Q_SCAN, [cup, glass], target=glass)
    assert pick.ok, str(pick)
    assert pick.timings_ms.get("lift_up_then_away") == 1.0
    assert lift_contact(world, pick, glass) is None
    held = planner.scene([cup, glass], None, exclude=glass, held=pick.grasp, own=[glass])
    P = np.array([planner.robot.fk_tcp(q)[:3, 3] for q in pick.lift.q])
    near = held.touching(pick.lift.q, ("held", "cell:sink_wall_back"), planner.settings.grasp_margin)
    assert np.linalg.norm(P[near] - P[0], axis=1).max() <= sum(UP_THEN_AWAY) + 1e-3
