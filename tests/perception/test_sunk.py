"""No item passes through the surface it stands on (verify.sunk, the verification part `sunk`): a glass fitted
upside down on a drink can shorter than it puts its base on the can's lid and its rim through the support, where
no camera sees it (a D435 table scene: the glass's rim 2 cm under the table, every other part passed)."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.perception.pipeline import SUNK_POINTS, Perceiver
from kitchenbot.perception.surfaces import find_surfaces
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses
from kitchenbot.perception.verify import SUNK_FULL, Verification, sunk
from kitchenbot.transforms import make_T, rot_x

GLASS, MUG = 6, 5
# The verification rejects a pose above this (threshold 0.85: 1 - sunk / SUNK_FULL < 0.85).
REJECTED = 0.15 * SUNK_FULL


def _can(r: float, h: float, x: float, y: float, floor: float) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_cylinder(r, h, resolution=32)
    m.translate((x, y, floor + h / 2))
    m.compute_vertex_normals()
    return m


def _scene(inventory, cell):
    """A mug standing on the sink floor beside an upright drink can of the glass's rim radius, 14 mm shorter than
    the glass: the views, the mug's pose, the can's centre (x, y), the floor's height and the can's height."""
    T_mug = resting_pose(inventory, MUG, 0.42, 0.10, 0.3, cell)
    floor = float((inventory[MUG].points @ T_mug[:3, :3].T + T_mug[:3, 3])[:, 2].min())
    glass_h = float(np.ptp(inventory[GLASS].points[:, 2]))
    can_h = glass_h - 0.014
    extra = [(_can(0.0355, can_h, 0.50, -0.06, floor), (0.75, 0.76, 0.78))]
    views, _ = render(inventory, [(MUG, T_mug)], scan_poses(cell), cell, noise=0.002, extra=extra)
    return views, T_mug, (0.50, -0.06), floor, can_h


def _sunk(perceiver, oid: int, T: np.ndarray, inside) -> float:
    dense = perceiver.database[oid].dense_points
    return sunk(dense[::max(1, len(dense) // SUNK_POINTS)], T, inside)


def test_a_glass_through_the_floor_on_a_can_is_sunk_and_items_resting_on_it_are_not(perceiver, inventory, cell):
    """The supports found in the data (no cell): the floor, seen round the can and the mug, is solid under them too.
    A glass upside down with its base on the can's lid (its rim 14 mm under the floor) is rejected; the mug as it
    stands, a glass standing on the floor fitted 4 mm low, one lying on it and one upside down on the floor are
    not."""
    views, T_mug, (x, y), floor, can_h = _scene(inventory, cell)
    surfaces = find_surfaces(views)

    def inside(P):
        return surfaces.inside_solid(P, supports_only=True)
    g = inventory[GLASS].points
    lo, hi = g[:, 2].min(), g[:, 2].max()
    down = rot_x(np.pi)[:3, :3]
    on_can = make_T(down, [x, y, floor + can_h - (-lo)])  # its base (z = lo, turned up) on the lid
    assert _sunk(perceiver, GLASS, on_can, inside) > REJECTED
    assert Verification(1.0, 1.0, 0.0, 1.0, sunk=_sunk(perceiver, GLASS, on_can, inside)).score < 0.85
    standing = make_T(np.eye(3), [0.36, -0.10, floor - lo - 0.004])
    upside_down = make_T(down, [0.36, -0.10, floor + hi])
    r = float(np.linalg.norm(g[:, :2], axis=1).max())
    lying = make_T(rot_x(np.pi / 2)[:3, :3], [0.36, -0.10, floor + r])
    for oid, T in ((MUG, T_mug), (GLASS, standing), (GLASS, upside_down), (GLASS, lying)):
        assert _sunk(perceiver, oid, T, inside) == 0.0, (oid, np.round(T[:3, 3], 3))


def test_a_mug_beside_a_can_keeps_its_pose(perceiver, inventory, cell):
    """Through the whole pipeline, segmented with the surfaces found in the data (where `sunk` is judged): the mug
    beside the can is found, and nothing on the can; the mug's `sunk` part is 0."""
    views, T_mug, _, _, _ = _scene(inventory, cell)
    poses = Perceiver(perceiver.settings, inventory, cell, use_cell="never").perceive(views).poses
    assert [(p.obj_id, bool(np.linalg.norm(p.T_base_obj[:3, 3] - T_mug[:3, 3]) < 0.01)) for p in poses] == \
        [(MUG, True)], [(inventory[p.obj_id].name, np.round(p.T_base_obj[:3, 3], 3)) for p in poses]
    assert poses[0].checks["sunk"] == 0.0
