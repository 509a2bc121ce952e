"""Grasps checked against the observed points (the real surfaces), not only the CAD model at the estimated pose."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kitchenbot.planning.grasps import OBSERVED_HITS, GraspStats, observed_in_grip, observed_in_tool
from kitchenbot.transforms import trans
from kitchenbot.world.gripper import PAD_DEPTH


def test_points_in_a_pad_or_the_palm_count_points_between_the_pads_do_not(planner):
    g = planner.world.gripper
    opening = 0.04
    y_pad = opening / 2 + g.pad_thickness / 2
    inside_pad = np.array([[0.0, y_pad, 0.0], [0.0, -y_pad, -0.03]])
    palm = np.array([[0.0, 0.0, g.pad_root - 0.02]])
    gap = np.array([[0.0, 0.0, 0.0], [0.005, 0.01, 0.005]])
    far = np.array([[0.2, 0.0, 0.0]])
    P = np.vstack([inside_pad, palm, gap, far])
    assert observed_in_tool(P, opening, g) == 3
    assert observed_in_grip(P, opening, g, PAD_DEPTH) == 2


def _surface_points(model, T, n=4000):
    pc = model.mesh.sample_points_uniformly(n)
    P = np.asarray(pc.points)
    return P @ T[:3, :3].T + T[:3, 3]


def test_grasps_whose_pads_land_on_the_observed_item_are_ranked_last(planner, home, resting):
    """A cup perceived 15 mm off where it stands: grasps whose pads (by the model) fit around it but would land
    on the surface its points show come after every grasp the points leave free."""
    cup = resting("cup", (0.50, -0.03), 1)
    model = planner.inventory[cup.obj_id]
    T_true = np.asarray(cup.T_base_obj, float)
    seen = replace(cup, T_base_obj=trans(0.015, 0.0, 0.0) @ T_true, points=_surface_points(model, T_true))
    st = GraspStats()
    grasps = planner.select_grasps(home, [seen], target=seen, stats=st)
    assert isinstance(grasps, list) and grasps
    g = planner.world.gripper

    def hits(gr):
        T = gr.T_base_tcp
        return observed_in_tool((seen.points - T[:3, 3]) @ T[:3, :3], gr.spec.opening, g)

    bad = [hits(gr) >= OBSERVED_HITS for gr in grasps]
    assert any(bad) and not all(bad), bad  # the shift puts some pads on the real wall, not all
    first_bad = bad.index(True)
    assert all(bad[first_bad:])  # every grasp the points leave free ranks before them
    assert st.observed_in_tool == sum(bad)
