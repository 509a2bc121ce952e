"""An item whose every grasp is refused only for its open pads is approached with them opened narrower
(planning.grasps.select_grasps, third pass: narrowed_grasp).

Hand-made from a sink where it happened (a task run): a glass standing upside down on the basin's floor in a
corner, its rim 13 mm from the back wall and 15 mm from the left one, nothing else in the sink. Its grasps open the
pads 30 mm wider than the glass; from above, the palm meets the walls; from the side, each grasp coming in along
the corner's diagonal has one open pad in a wall. Opened 16 mm wider than the glass (the slack leaning rim and foot
pinches are given anyway), both pads clear the walls and the grasp is free: the independent checker agrees."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning import grasps as grasps_mod
from kitchenbot.planning.grasps import GraspStats
from kitchenbot.transforms import make_T, rot_x, rot_z
from kitchenbot.world.inventory import NARROW_TAG, grasp_base_name

CORNER = (0.299, 0.149, -0.139)  # the glass's centre, base frame: basin interior x >= 0.25, y <= 0.20, floor -0.20
MIDDLE = (0.50, 0.0, -0.139)
Q = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])  # the last scan waypoint (config/sim.yaml)


def _glass(inventory, at, turn_deg: float = 0.0) -> list[ObjectPose]:
    m = inventory.by_name("glass")
    T = make_T(t=at) @ rot_z(np.radians(turn_deg)) @ rot_x(np.pi)  # upside down, turned about its axis
    return [ObjectPose(m.obj_id, m.cls, T, 1.0, instance_id=0)]


def test_before_the_glass_in_the_corner_has_no_grasp(planner, inventory, monkeypatch):
    monkeypatch.setattr(grasps_mod, "NARROW_SLACKS", ())  # no third pass
    objects = _glass(inventory, CORNER)
    out = planner.select_grasps(Q, objects, target=objects[0])
    assert not isinstance(out, list) and out.kind == "no_collision_free_grasp"


@pytest.mark.parametrize("turn_deg", [0.0, 20.0])
def test_the_glass_in_the_corner_is_taken_with_the_pads_opened_narrower(planner, inventory, grasp_check, turn_deg):
    objects = _glass(inventory, CORNER, turn_deg)
    st = GraspStats()
    out = planner.select_grasps(Q, objects, target=objects[0], stats=st)
    assert isinstance(out, list) and out, str(out)
    g = out[0]
    assert st.narrowed >= 1 and "_narrow16" in g.spec.name
    # the same grasp of the glass (pose, width), its pads opened 16 mm wider than the glass instead of 30 mm
    given = {s.name: s for s in grasps_mod.expand_grasps(inventory[objects[0].obj_id])}
    made_from = given.get(g.spec.name.split(NARROW_TAG)[0])  # None for a spun one (turned between the copies)
    if made_from is not None:
        assert np.allclose(made_from.T_obj_tcp, g.spec.T_obj_tcp) and made_from.width == g.spec.width
        assert made_from.opening > g.spec.opening
    assert g.spec.opening == pytest.approx(g.spec.width + 0.016)
    assert grasp_base_name(g.spec.name) in {s.name for s in inventory[objects[0].obj_id].grasps}
    # the independent python-fcl checker (zero margin): pre-grasp and grasp free, the pads touching only the glass
    res = grasp_check(g, objects, 0)
    assert res.ok, str(res)
    # and the pick as a whole (approach, grasp-in, lift) plans
    pick = planner.plan_pick(Q, objects, target=objects[0])
    assert pick.ok, str(pick)


def test_a_glass_with_room_is_not_narrowed(planner, inventory):
    objects = _glass(inventory, MIDDLE)
    st = GraspStats()
    out = planner.select_grasps(Q, objects, target=objects[0], stats=st)
    assert isinstance(out, list) and out and st.narrowed == 0
    assert not any("_narrow" in g.spec.name for g in out)


def test_a_grasp_that_opens_narrowly_already_is_not_narrowed(inventory):
    for s in grasps_mod.expand_grasps(inventory.by_name("glass")):
        n = grasps_mod.narrowed_grasp(inventory.by_name("glass"), s, grasps_mod.NARROW_SLACK)
        if s.opening <= s.width + grasps_mod.NARROW_SLACK + 1e-4:
            assert n is None
        elif n is not None:
            assert n.opening < s.opening and np.allclose(n.T_obj_tcp, s.T_obj_tcp)
