"""A round item's grasp does not hang on its unobservable turn about its axis (planning.grasps.select_grasps, last
pass: spun_grasps).

Hand-made from a pile where it happened (a task run): three side plates in the basin, A leaning steeply on the
wall, B leaning 41 degrees in front of it, F flat under both. B's predefined grasps are copies of each pinch at 12
rim positions 30 degrees apart; the free window between A's contact and F is narrower than that, so whether a copy
lands in it depends on B's turn about its axis, which perception cannot observe (a round plate looks the same at
any turn: the run before had it 95 degrees off). As fitted, no copy lands there; turned by 15 degrees about its
axis, the same plate has one. The last pass tries the grasps turned between their copies."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning import grasps as grasps_mod
from kitchenbot.planning.grasps import GraspStats
from kitchenbot.transforms import from_rotvec, rot_z

# (model name, instance id, pose as fitted: rotation vector, position), base frame; B last
ITEMS = (
    ("side_plate", 2, (0.8458118, 0.8576197, -1.4108957), (0.4200247, 0.1599723, -0.0940616)),  # A, on the wall
    ("side_plate", 1, (0.0164306, -0.0076283, -1.5938129), (0.4408726, 0.0242963, -0.1868881)),  # F, flat
    ("side_plate", 0, (0.4686933, 0.6465572, -1.452118), (0.4007185, 0.1124197, -0.132836)),  # B, leaning on A
)
Q = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])  # where the arm was


def _pile(inventory, spin_deg: float = 0.0) -> tuple[list[ObjectPose], ObjectPose]:
    out = []
    for name, uid, rv, t in ITEMS:
        m = inventory.by_name(name)
        out.append(ObjectPose(m.obj_id, m.cls, from_rotvec(rv, t), 1.0, instance_id=uid))
    out[2].T_base_obj = out[2].T_base_obj @ rot_z(np.radians(spin_deg))  # about the plate's symmetry axis
    return out, out[2]


def test_the_plates_copies_sit_30_degrees_apart(inventory):
    assert np.degrees(grasps_mod.copy_spacing(inventory.by_name("side_plate"))) == pytest.approx(30.0, abs=0.5)


@pytest.mark.parametrize("spin_deg", [0.0, 15.0, 30.0])
def test_before_the_plates_grasp_depends_on_its_turn(planner, inventory, spin_deg, monkeypatch):
    monkeypatch.setattr(grasps_mod, "SPIN_STEPS", ())  # the selection as it was: no last pass
    objects, b = _pile(inventory, spin_deg)
    out = planner.select_grasps(Q, objects, target=b)
    if spin_deg == 15.0:
        assert isinstance(out, list) and out
    else:
        assert not isinstance(out, list) and out.kind == "no_collision_free_grasp"


@pytest.mark.parametrize("spin_deg", [0.0, 30.0, -60.0])
def test_the_plate_has_a_free_grasp_at_any_turn(planner, inventory, spin_deg, grasp_check):
    objects, b = _pile(inventory, spin_deg)
    st = GraspStats()
    out = planner.select_grasps(Q, objects, target=b, stats=st)
    assert isinstance(out, list) and out, str(out)
    g = out[0]
    assert st.spun == 1 and "_spin" in g.spec.name
    # the spun grasp is a predefined one on the plate turned about its axis: the same pinch, elsewhere on the rim
    m = inventory[b.obj_id]
    base = grasps_mod.grasp_base_name(g.spec.name)
    assert base in {s.name for s in m.grasps}
    # the independent python-fcl checker (zero margin): pre-grasp and grasp free, the pads touching only the plate
    res = grasp_check(g, objects, 2)
    assert res.ok, str(res)


def test_a_plate_with_a_grasp_as_given_is_not_spun(planner, inventory):
    objects, b = _pile(inventory, 15.0)
    st = GraspStats()
    out = planner.select_grasps(Q, objects, target=b, stats=st)
    assert isinstance(out, list) and out and st.spun == 0
    assert not any("_spin" in g.spec.name for g in out)


def test_spun_grasps_are_the_given_ones_turned_about_the_axis(inventory):
    plate = inventory.by_name("side_plate")
    spun = grasps_mod.spun_grasps(plate, 0.5)
    given = grasps_mod.expand_grasps(plate)
    assert len(spun) == len(given)
    # every spun grasp is its given one turned half their spacing (15 degrees, to 0.1) about the plate's axis (z)
    for s, g in zip(spun, given):
        assert np.allclose(s.T_obj_tcp, rot_z(np.radians(15.0)) @ g.T_obj_tcp, atol=2e-3)
        assert grasps_mod.grasp_base_name(s.name) == grasps_mod.grasp_base_name(g.name)
