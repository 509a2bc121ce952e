"""The multi-object test (a neighbour where a pad sweeps while closing) is made at each bite the grasp may back off
to (planning.grasps.select_grasps): a neighbour whose top just reaches the pad tips' sweep at the full bite (a mug
lying on a plate stack: the tips sweep into the plate below) is clear of a grasp 4-8 mm shallower, which still
holds. Hand-made: two cups side by side, the neighbour sunk so its rim lies at the tips' depth."""

import numpy as np

from kitchenbot.transforms import trans


def _pair(planner, resting, sink: float):
    cup = resting("cup", (0.50, 0.0), 1)
    m = planner.inventory[cup.obj_id]
    spec = next(s for s in m.grasps if s.name == "rim_00")  # the rim pinch on the +x side (object frame)
    V = np.asarray(m.mesh.vertices)
    r_rim = float(np.max(np.linalg.norm(V[V[:, 2] > V[:, 2].max() - 0.004][:, :2], axis=1)))
    gr = planner.world.gripper
    # the pad tips at the full bite lie this far below the rim (TCP depth plus the tips' reach past the TCP)
    tips = (V[:, 2].max() - spec.T_obj_tcp[2, 3]) + gr.pad_tip
    nb = resting("cup", (0.50 + 2 * r_rim + 0.005, 0.0), 2)  # its wall 5 mm beyond the target's, in the outer sweep
    nb.T_base_obj = trans(0.0, 0.0, -(tips - sink)) @ nb.T_base_obj  # its rim `sink` m above the tips' depth
    return cup, nb, spec


def test_grasp_whose_shallower_bite_clears_the_neighbour_is_kept(planner, resting, home):
    cup, nb, spec = _pair(planner, resting, 0.001)
    out = planner.select_grasps(home, [cup, nb], target=cup)
    assert isinstance(out, list)
    g = next((g for g in out if g.spec.name == spec.name), None)
    assert g is not None, "rejected as a multi-object grasp although a 4 mm shallower bite clears the neighbour"
    full = np.asarray(cup.T_base_obj) @ spec.T_obj_tcp
    back = float((g.T_base_tcp[:3, 3] - full[:3, 3]) @ -full[:3, 2])
    assert 0.003 < back < 0.009  # backed off along the approach


def test_grasp_still_taking_in_the_neighbour_when_backed_off_is_rejected(planner, resting, home):
    cup, nb, spec = _pair(planner, resting, 0.012)  # 12 mm into the sweep: 8 mm shallower still takes it in
    out = planner.select_grasps(home, [cup, nb], target=cup)
    names = [g.spec.name for g in out] if isinstance(out, list) else []
    assert spec.name not in names
