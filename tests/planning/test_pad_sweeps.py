"""Multi-object grasps are judged by where the pads sweep, not by the whole gap between them."""

import coal
import numpy as np

from kitchenbot.planning.collision import GripperGeometry, coal_transform, mesh_bvh
from kitchenbot.planning.grasp_synthesis import ensure_grasps
from kitchenbot.planning.grasps import pad_sweeps
from kitchenbot.transforms import trans
from kitchenbot.world.inventory import Inventory


def _hits(vol_T, bvh, T_obj):
    return coal.collide(vol_T[0], vol_T[1], bvh, coal_transform(T_obj), coal.CollisionRequest(), coal.CollisionResult())


def test_overhanging_top_plate_is_pinched_alone_on_its_overhang_side():
    inv = ensure_grasps(Inventory.builtin())
    plate = next(m for m in inv if m.cls == "plate" and m.name == "dinner_plate")
    bvh = mesh_bvh(np.asarray(plate.mesh.vertices), np.asarray(plate.mesh.triangles))
    g = GripperGeometry()
    T_lower = np.eye(4)
    T_top = trans(0.02, 0.0, 0.008)  # 20 mm off-centre towards +x, nested 8 mm higher
    # the tilted lip pinch (one pad under the lip): the vertical rim pinch reaches through a plate's well
    rim = [s for s in plate.grasps if s.name.startswith("rimtilt60_")]

    def side(spec):  # +1: the grasp is on the +x side of the top plate
        return np.sign(spec.T_obj_tcp[0, 3]) if abs(spec.T_obj_tcp[0, 3]) > 0.1 else 0

    over = [s for s in rim if side(s) > 0]
    under = [s for s in rim if side(s) < 0]
    assert over and under
    for spec in over:
        T = T_top @ spec.T_obj_tcp
        sweeps = [(v, coal_transform(T @ Tv))
                  for v, Tv in pad_sweeps(spec.opening, spec.width, g.pad_width, g.pad_root, g.pad_tip)]
        assert not any(_hits(s, bvh, T_lower) for s in sweeps), spec.name
    for spec in under:  # where the lower plate sticks out, the outer pad sweeps into its rim
        T = T_top @ spec.T_obj_tcp
        sweeps = [(v, coal_transform(T @ Tv))
                  for v, Tv in pad_sweeps(spec.opening, spec.width, g.pad_width, g.pad_root, g.pad_tip)]
        assert any(_hits(s, bvh, T_lower) for s in sweeps), spec.name


def test_sweeps_span_from_open_to_closed_pads():
    (a, Ta), (b, Tb) = pad_sweeps(0.05, 0.02, 0.026, -0.07, 0.012)
    half = a.halfSide
    assert np.isclose(Ta[1, 3] + half[1], 0.025) and np.isclose(Ta[1, 3] - half[1], 0.01 - 0.003)
    assert np.isclose(Tb[1, 3], -Ta[1, 3])
