"""Letting go with a narrower opening (Planner._retreat, planning.pick_place.release_openings): a bowl held by its
rim (a rim pinch opens 3.5 cm for a 5 mm rim) is set on its rim into the lower rack 6 cm from a side plate standing
there. Opened to the grasp's full opening, a pad reaches into the plate and every retreat from the release pose
collides, whichever grasp and IK branch: the item stayed in the sink (`cartesian_path_failed: retreat`, three
grasps per attempt, every attempt). Opened only a few millimetres past the rim, the pads keep clear of the plate at
the release pose and back out past it (checked by the independent python-fcl checker too).
The geometry is hand-made after a development scene (a bowl lifted from a nested pair, the arm above the sink)."""

from __future__ import annotations

import numpy as np
import pytest

import kitchenbot.planning.pick_place as pick_place
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.pick_place import RELEASE_GAPS, release_openings
from kitchenbot.planning.types import PlacePlan, PlaceTarget
from kitchenbot.transforms import make_T, rot_z

from kitchenbot.planning.fcl_check import FclChecker, verify_place

@pytest.fixture(scope="module")
def checker(planner):
    return FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)


ON_ITS_RIM = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # axis level along base x
Q_LIFTED = np.array([3.0393, -1.2597, 1.9598, -2.235, -1.5653, -0.117])  # the arm above the sink, bowl lifted


def test_release_openings_narrow_down_to_a_few_millimetres_past_the_item():
    assert release_openings(0.0347, 0.0047) == pytest.approx([0.0347, *(0.0047 + 2 * g for g in RELEASE_GAPS)])
    assert release_openings(0.0347, 0.0047)[1:] == sorted(release_openings(0.0347, 0.0047)[1:], reverse=True)
    narrow = 0.0047 + 2 * RELEASE_GAPS[-1] + 0.0005  # only the last gap is narrower than that
    assert release_openings(narrow, 0.0047) == pytest.approx([narrow])
    assert release_openings(0.0047 + 2 * RELEASE_GAPS[-1], 0.0047) == pytest.approx([0.0047 + 2 * RELEASE_GAPS[-1]])


def _situation(planner):
    inv = planner.inventory
    bowl, side_plate = inv.by_name("bowl"), inv.by_name("side_plate")
    b = ObjectPose(bowl.obj_id, bowl.cls, make_T(rot_z(np.radians(-29.15))[:3, :3], (0.6052, 0.0826, -0.1624)), 1.0,
                   instance_id=3)
    plate = ObjectPose(side_plate.obj_id, side_plate.cls, make_T(ON_ITS_RIM @ rot_z(np.radians(-60.0))[:3, :3],
                                                                 (-0.0125, -0.57, -0.1686)), 1.0, instance_id=7)
    # the bowl's slot in the lower rack, 6.25 cm from the plate: the rack's pitch
    target = PlaceTarget(make_T(ON_ITS_RIM, (0.05, -0.57, -0.19)), "slot", "lower@0.050,-0.570",
                         support="rack_lower (on its rim)")
    return b, plate, target


def test_a_bowl_set_on_its_rim_beside_a_plate_is_let_go_with_a_narrower_opening(planner, home, monkeypatch, checker):
    b, plate, target = _situation(planner)
    np.testing.assert_allclose(plate.T_base_obj[:3, :3] @ plate.T_base_obj[:3, :3].T, np.eye(3), atol=1e-9)
    grasps = planner.select_grasps(home, [b], target=b)
    rim = [g for g in grasps if g.spec.name.startswith("rim_")]
    assert rim, "the bowl offers its plain rim pinches"
    placed = 0
    for g in rim[:3]:
        with monkeypatch.context() as m:
            m.setattr(pick_place, "RELEASE_GAPS", ())  # only the grasp's own opening, as before
            before = planner.plan_place(Q_LIFTED, g, target, objects=[plate])
        after = planner.plan_place(Q_LIFTED, g, target, objects=[plate])
        if isinstance(before, PlacePlan):
            continue  # this grasp's pads clear the plate fully open (not the situation under test)
        assert before.kind == "cartesian_path_failed" and "retreat" in str(before), before
        assert any("pad" in a or "pad" in c for a, c in before.details.get("pairs", ())), before.details
        assert isinstance(after, PlacePlan), after
        assert g.spec.width < after.release_opening < g.spec.opening  # it lets go, with less room
        for name, r in verify_place(checker, planner, after, g, [plate], step=0.004):
            assert r.ok, (name, str(r))
        placed += 1
    assert placed > 0, "at least one rim grasp is stopped by the plate when fully open and placed when not"
