"""Cups, mugs and glasses also get a side grasp across their base end (`side10_*`): a glass lying on its side with a
mug along its body (sink-pick seed 47) leaves no room for a pad beside the body, but one tilted towards the base
comes in past the base end with its pads above and below the body."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.grasps import FALLBACK_GRASPS, select_grasps
from kitchenbot.transforms import make_T

# The simulator's truth of sink-pick seed 47 after the cup and the side plate were taken out: (model, xyz, rotvec).
# A glass (tilted 117 degrees: mouth down) lies with its rim on the top plate of a stack and its base end on the
# handle of a mug, the mug's body 5 mm beside the glass's along its length, 3 cm from the near basin wall.
SEED47 = [
    ("dinner_plate", [0.4594, 0.0259, -0.1837], [-0.0145, -0.0068, -2.8024]),
    ("dinner_plate", [0.4745, 0.0271, -0.1737], [0.0906, -0.012, -3.0887]),
    ("dinner_plate", [0.4829, 0.0481, -0.1618], [0.1296, -0.0187, -1.6881]),
    ("bowl", [0.3378, -0.1091, -0.155], [0.2257, -0.1705, -0.2093]),
    ("mug", [0.3906, 0.0618, -0.1165], [-0.3527, 0.3461, -2.8217]),
    ("glass", [0.3272, 0.0969, -0.107], [-2.0658, -0.6755, -0.8809]),
]


def test_cups_mugs_glasses_get_base_end_side_grasps(inventory, grasps_hold):
    assert "side10" in FALLBACK_GRASPS  # they hold less of the body: ranked after every standard grasp
    for name in ("cup", "mug", "glass"):
        m = inventory.by_name(name)
        V = np.asarray(m.mesh.vertices)
        lo, hi = V[:, 2].min(), V[:, 2].max()
        g10 = [g for g in m.grasps if g.name.startswith("side10_")]
        assert len(g10) >= 8, name  # (a mug's handle takes some)
        for g in g10:
            assert abs(g.T_obj_tcp[2, 2]) < 1e-6  # across the body, perpendicular to its axis
            assert abs(g.T_obj_tcp[2, 3] - (lo + 0.1 * (hi - lo))) < 1e-6
        grasps_hold(name, "side10_", 3)
    assert not [g for g in inventory.by_name("bowl").grasps if g.name.startswith("side10_")]


def test_glass_lying_on_a_mugs_handle_is_taken_at_its_base_end(planner, home):
    objects = []
    for k, (name, t, rv) in enumerate(SEED47):
        m = planner.inventory.by_name(name)
        T = make_T(Rotation.from_rotvec(rv).as_matrix(), t)
        objects.append(ObjectPose(m.obj_id, m.cls, T, 1.0, instance_id=k + 1))
    glass = objects[-1]
    grasps = select_grasps(planner.robot, planner.scene(objects), planner.inventory, objects, home,
                           settings=planner.settings, target=glass)
    assert isinstance(grasps, list), grasps
    # no standard grasp fits (a pad beside the body would sweep into the mug, or the wrist hits the wall) ...
    assert all(g.spec.name.startswith("side10_") for g in grasps), [g.spec.name for g in grasps]
    # ... the base-end grasp comes in from beyond the base (tilted towards it), from above
    assert min(g.T_base_tcp[2, 2] for g in grasps) < -0.5
    pick = planner.plan_pick(home, objects, target=glass)
    assert pick.ok, pick
    assert pick.grasp.spec.name.startswith("side10_")
