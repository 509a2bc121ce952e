"""How far a support found in the scan reaches (perception/surfaces.py): to the walls rising from it, where the
items on it hide it; and not under the rest of an opening, where a pile hides what is below."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.perception.rgbd import point_map
from kitchenbot.perception.surfaces import find_surfaces
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses
from kitchenbot.perception.types import View
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory


def _box(x: float, y: float, z: float, size) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate((x - size[0] / 2, y - size[1] / 2, z))
    return m


def test_the_floor_reaches_to_the_walls_where_items_hide_it():
    """A basin floor seen only in its middle (items along the sides hide it: here the floor's pixels within 8 cm of
    the sides have no depth) still reaches to the sides rising from it: what stands beside a side, over the floor,
    stands on a support (before, the floor's hull stopped 8 cm short and a plate leaning there was background).
    Outside the basin, under the counter, nothing stands on a support."""
    cell = Cell()
    views, _ = render(Inventory.builtin(), [], scan_poses(cell), cell, noise=0.002)
    lo, hi = cell.sink_interior
    hidden = []
    for v in views:
        P = point_map(v)
        to_side = np.minimum.reduce([P[..., 0] - lo[0], hi[0] - P[..., 0], P[..., 1] - lo[1], hi[1] - P[..., 1]])
        edge = (np.abs(P[..., 2] - lo[2]) < 0.01) & (to_side < 0.08)
        assert edge.sum() > 1000
        d = v.depth.copy()
        d[edge] = 0.0
        hidden.append(View(v.rgb, d, v.K, v.T_base_cam))
    sm = find_surfaces(hidden)
    assert any(abs(-s.offset - lo[2]) < 0.005 for s in sm.supports)
    cy = (lo[1] + hi[1]) / 2
    beside_sides = np.array([[lo[0] + 0.03, cy, lo[2] + 0.05], [hi[0] - 0.03, cy - 0.05, lo[2] + 0.10],
                             [0.5 * (lo[0] + hi[0]), lo[1] + 0.02, lo[2] + 0.04]])
    assert sm.on_support(beside_sides).all()
    under_counter = np.array([[lo[0] - 0.05, cy, lo[2] + 0.05], [0.5 * (lo[0] + hi[0]), hi[1] + 0.06, lo[2] + 0.1]])
    assert not sm.on_support(under_counter).any()


def test_under_a_pile_reaching_over_the_counter_is_no_solid():
    """A board resting 2 cm over the counter's height on a post in the basin, a glass standing under it: no
    camera sees the basin under the board, but those cells join the counter's opening, which the cameras saw
    through. The glass is not inside solid matter (before: 'a hole of the counter never seen through', and
    the glass's right pose was scored down)."""
    inventory, cell = Inventory.builtin(), Cell()
    lo, hi = cell.sink_interior
    cx, cy = (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2
    post = _box(cx + 0.08, cy, lo[2], (0.03, 0.03, -lo[2] + 0.02))
    board = _box(cx + 0.02, cy, 0.02, (0.22, 0.18, 0.01))
    glass = resting_pose(inventory, 6, cx - 0.03, cy, 0.0, cell)
    views, _ = render(inventory, [(6, glass)], scan_poses(cell), cell, noise=0.002,
                      extra=[(post, (0.5, 0.5, 0.5)), (board, (0.8, 0.6, 0.2))])
    sm = find_surfaces(views)
    assert any(abs(s.offset) < 0.005 for s in sm.supports)  # the counter
    P = inventory[6].points @ glass[:3, :3].T + glass[:3, 3]
    assert sm.inside_solid(P).mean() < 0.02, sm.inside_solid(P).mean()
