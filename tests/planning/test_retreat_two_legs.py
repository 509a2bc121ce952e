"""A retreat in two legs (Planner._two_leg_retreat): a mug held by a level side grasp (tilted 5 degrees) is set
down upright on the counter near its back corner to be grasped again (a staging spot). Backing the open pads
out the full approach distance puts the wrist into the counter's walls, and straight up the palm drags along the
mug it hugs: with those two retreats only, the place failed (`cartesian_path_failed: retreat`) for this grasp on
every attempt and the mug stayed in the sink. Backed out 3-5 cm, then straight up, the gripper leaves freely
(checked by the independent python-fcl checker too). The geometry is hand-made after a development scene (a mug
lying on its side in the sink, the arm above it with the mug lifted)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.fcl_check import FclChecker, verify_place
from kitchenbot.planning.pick_place import Planner
from kitchenbot.planning.types import Grasp, PlacePlan, PlaceTarget
from kitchenbot.transforms import make_T
from kitchenbot.world.inventory import GraspSpec

# a level side grasp of the mug, tilted by 5 degrees (the tcp's approach axis nearly horizontal in the mug frame)
T_OBJ_TCP = np.array([[0.07547909, -0.5, -0.86272992, -0.01695333],
                      [0.04357787, 0.8660254, -0.49809735, 0.0],
                      [0.9961947, 0.0, 0.08715574, -0.03902083],
                      [0.0, 0.0, 0.0, 1.0]])
# the mug lying on its side in the sink where it was grasped
T_MUG = np.array([[0.49054, -0.518, -0.70075, 0.3988],
                  [-0.48552, 0.5053, -0.7134, -0.10884],
                  [0.72363, 0.69018, -0.00363, -0.14695],
                  [0.0, 0.0, 0.0, 1.0]])
Q_LIFTED = np.array([2.6584, -1.3389, 2.0991, -2.0791, -1.5829, 0.284])  # the arm above the sink, mug lifted


def _orthonormal(T: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(T[:3, :3])
    out = T.copy()
    out[:3, :3] = U @ Vt
    return out


@pytest.fixture(scope="module")
def situation(planner):
    mug = planner.inventory.by_name("mug")
    obj = ObjectPose(mug.obj_id, mug.cls, _orthonormal(T_MUG), 1.0, instance_id=2)
    spec = GraspSpec("side10_01_tilt+5", _orthonormal(T_OBJ_TCP), opening=0.1, width=0.0783)
    T_tcp = obj.T_base_obj @ spec.T_obj_tcp
    g = Grasp(spec, obj, T_tcp, Q_LIFTED, Q_LIFTED, T_tcp)
    # upright on the counter, 5 cm from its back wall's corner: where the task stages a mug for a regrasp
    target = PlaceTarget(make_T(t=(0.0, 0.45, 0.0588)), "stage", free_yaw=False, support="counter (regrasp)")
    return g, target


def test_a_mug_staged_by_a_side_grasp_is_let_go_with_a_back_out_then_up_retreat(planner, monkeypatch, situation):
    g, target = situation
    with monkeypatch.context() as m:
        m.setattr(Planner, "RETREAT_BACK_LEGS", ())  # the one-leg retreats only, as before
        before = planner.plan_place(Q_LIFTED, g, target)
    assert before.kind == "cartesian_path_failed" and "retreat" in str(before), before
    after = planner.plan_place(Q_LIFTED, g, target)
    assert isinstance(after, PlacePlan), after
    T0, T1 = planner.robot.fk_tcp(after.retreat.q[0]), planner.robot.fk_tcp(after.retreat.q[-1])
    assert T1[2, 3] - T0[2, 3] > 0.08  # up in the end, after backing out a few centimetres (level, nearly)
    assert 0.02 < np.linalg.norm((T1 - T0)[:2, 3]) < 0.07
    checker = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
    for name, r in verify_place(checker, planner, after, g, [], step=0.004):
        assert r.ok, (name, str(r))
