"""Surfaces from the data, the configured cell checked against the scan, and things outside the inventory:
hand-made scenes rendered with perception/synthetic.py."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from kitchenbot.world.cell import Cell, CellSpec
from kitchenbot.perception.cell_check import check_cell
from kitchenbot.perception.metrics import adi
from kitchenbot.perception.pipeline import Perceiver
from kitchenbot.perception.rgbd import point_map
from kitchenbot.perception.surfaces import find_surfaces
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses
from kitchenbot.perception.types import View


def _shifted(cell: Cell, dx: float) -> Cell:
    s = cell.spec.sink
    return Cell(cell.spec.model_copy(update={"sink": s.model_copy(update={"centre_xy": (s.centre_xy[0] + dx,
                                                                                       s.centre_xy[1])})}))


def _right(result, placed, inventory):
    """Every pose is of a placed object (same model, ADI < 0.1 d, axis the right way); returns the indices found."""
    found = set()
    for po in result.poses:
        errs = [adi(po.T_base_obj, T, inventory[oid].points) if oid == po.obj_id else np.inf for oid, T in placed]
        k = int(np.argmin(errs))
        assert errs[k] < 0.1 * inventory[po.obj_id].diameter, \
            f"{inventory[po.obj_id].name} at {np.round(po.T_base_obj[:3, 3], 3)}: fitted to no placed object"
        assert po.T_base_obj[:3, 2] @ placed[k][1][:3, 2] > 0.9, f"{inventory[po.obj_id].name} flipped"
        assert k not in found, "two poses for one object"
        found.add(k)
    return found


@pytest.fixture(scope="module")
def near_walls(inventory, cell):
    """Cups and a glass standing against the basin's walls and in its corners, a plate in the middle."""
    lo, hi = cell.sink_interior
    r_cup, r_glass = inventory[4].diameter * 0.36, inventory[6].diameter * 0.4
    return [(4, resting_pose(inventory, 4, lo[0] + r_cup + 0.004, lo[1] + r_cup + 0.004, 0.0, cell)),
            (4, resting_pose(inventory, 4, hi[0] - r_cup - 0.004, 0.02, 1.0, cell)),
            (6, resting_pose(inventory, 6, 0.45, hi[1] - r_glass - 0.004, 0.0, cell)),
            (2, resting_pose(inventory, 2, 0.52, -0.05, 0.0, cell))]


def test_surfaces_of_an_empty_sink(cell, inventory):
    """The floor and the counter are supports, the basin's sides walls; nothing else stands out."""
    views, _ = render(inventory, [], scan_poses(cell), cell, noise=0.002)
    sm = find_surfaces(views)
    lo, hi = cell.sink_interior
    heights = sorted(-s.offset for s in sm.supports)
    assert any(abs(h - lo[2]) < 0.005 for h in heights) and any(abs(h) < 0.005 for h in heights), heights
    assert len(sm.walls) >= 2 and all(abs(w.normal[2]) < 0.1 for w in sm.walls)
    for v in views:  # everything seen is a surface: no foreground left
        fg = sm.foreground(point_map(v, 2), v.T_base_cam[:3, 3])
        assert fg.mean() < 0.002, fg.mean()


def test_drain_is_no_object(cell, inventory):
    """A drain (a hole in the basin floor: depth 4 cm behind it) is seen through the floor, so it is surface."""
    views, _ = render(inventory, [], scan_poses(cell), cell, noise=0.002)
    lo, hi = cell.sink_interior
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    drained = []
    for v in views:
        P = point_map(v)
        hole = (np.linalg.norm(P[..., :2] - centre[:2], axis=2) < 0.04) & (np.abs(P[..., 2] - lo[2]) < 0.003)
        d = v.depth.copy()
        ray_z = (P[..., 2] - v.T_base_cam[2, 3])  # the depth along the ray grows as the point drops 4 cm
        d[hole] = d[hole] * (1.0 + (-0.04) / ray_z[hole])
        drained.append(View(v.rgb, d, v.K, v.T_base_cam))
        assert hole.sum() > 500
    sm = find_surfaces(drained)
    assert any(abs(-s.offset - lo[2]) < 0.005 for s in sm.supports)
    for v in drained:
        assert sm.foreground(point_map(v, 2), v.T_base_cam[:3, 3]).mean() < 0.002


def test_without_a_cell_nothing_is_fitted_to_the_walls(perceiver, inventory, cell, near_walls):
    """No cell description: walls, floor and counter come from the scan; the items against the walls are found
    and nothing else (the splashback and the basin sides were fitted by cups before)."""
    views, _ = render(inventory, near_walls, scan_poses(cell), cell, noise=0.002)
    p = Perceiver(perceiver.settings, inventory, None, use_cell=False, database=perceiver.database)
    r = p.perceive(views)
    assert r.surfaces_from == "data" and r.cell_check is None
    found = _right(r, near_walls, inventory)
    assert len(found) >= 3, f"found {len(found)} of {len(near_walls)}"


def test_a_shifted_cell_is_flagged_and_not_used(perceiver, inventory, cell, near_walls):
    views, _ = render(inventory, near_walls, scan_poses(cell), cell, noise=0.002)
    ok = check_cell(views, cell)
    off = check_cell(views, _shifted(cell, 0.10))
    assert ok.fits and ok.behind < 0.01, ok
    assert not off.fits and "does not fit" in off.message, off
    p = Perceiver(perceiver.settings, inventory, _shifted(cell, 0.10), use_cell="auto", database=perceiver.database)
    r = p.perceive(views)
    assert r.cell_check is not None and not r.cell_check.fits and r.surfaces_from == "data"
    assert len(_right(r, near_walls, inventory)) >= 3
    # The right cell passes the check and is used.
    p_ok = Perceiver(perceiver.settings, inventory, cell, use_cell="auto", database=perceiver.database)
    r_ok = p_ok.perceive(views)
    assert r_ok.cell_check.fits and r_ok.surfaces_from == "cell"
    assert _right(r_ok, near_walls, inventory) == set(range(len(near_walls)))


def test_a_table_over_the_sink_is_flagged_and_not_used(perceiver, inventory, cell):
    """A board over the basin (dishware on a table, not in a sink): nothing is seen behind the cell, but the
    basin's floor is seen covered by one level surface; the cell is not used, the board is found as a support
    and the cup standing on it gets its pose."""
    lo, hi = cell.sink_interior
    w = cell.spec.sink.wall
    board = _box((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, -0.03,
                 (hi[0] - lo[0] + 2 * w, hi[1] - lo[1] + 2 * w, 0.03))
    T = resting_pose(inventory, 4, 0.45, -0.05, 0.0, cell)
    T[2, 3] -= lo[2]  # on the board (z 0), not on the basin floor
    placed = [(4, T)]
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002, extra=[(board, (0.62, 0.45, 0.30))])
    c = check_cell(views, cell)
    assert c.behind < 0.01 and c.covered > 0.9 and not c.fits and "level" in c.message, c
    p = Perceiver(perceiver.settings, inventory, cell, use_cell="auto", database=perceiver.database)
    r = p.perceive(views)
    assert r.surfaces_from == "data" and _right(r, placed, inventory) == {0} and len(r.poses) == 1


def test_a_table_under_boxes_of_two_heights_is_flagged(cell):
    """A board over the basin with four food boxes on it, two 5 cm and two 10 cm tall: what is seen over the
    basin's floor is split between three levels (the board, two box tops), none over 60 % of it, so the one-level
    test alone took the cell as fitting (the board then foreground, dishware fitted to it). The basin's own floor
    and walls are hardly seen where the cell puts them: covered, the cell not used. A sink with items in it is
    still the cell (`test_a_shifted_cell_is_flagged_and_not_used`)."""
    lo, hi = cell.sink_interior
    w = cell.spec.sink.wall
    cx, cy = (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2
    extra = [(_box(cx, cy, -0.03, (hi[0] - lo[0] + 2 * w, hi[1] - lo[1] + 2 * w, 0.03)), (0.62, 0.45, 0.30))]
    for dx, dy, h in [(-0.12, -0.09, 0.05), (0.12, 0.09, 0.05), (-0.12, 0.09, 0.10), (0.12, -0.09, 0.10)]:
        extra.append((_box(cx + dx, cy + dy, 0.0, (0.17, 0.13, h)), (0.8, 0.2, 0.2)))
    views, _ = render([], [], scan_poses(cell), cell, noise=0.002, extra=extra)
    c = check_cell(views, cell)
    assert c.behind < 0.01 and c.covered < c.max_covered, c  # the one-level test alone is fooled
    assert c.basin_seen < 0.01 and c.is_covered and not c.fits and "walls" in c.message, c


def _can(x: float, y: float, z: float) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_cylinder(0.033, 0.122, resolution=40)
    m.translate((x, y, z + 0.061))
    return m


def _box(x: float, y: float, z: float, size=(0.16, 0.06, 0.10)) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate((x - size[0] / 2, y - size[1] / 2, z))
    return m


@pytest.mark.parametrize("use_cell", [True, False])
def test_a_box_and_a_sponge_get_no_pose_and_stay_obstacles(perceiver, inventory, cell, use_cell):
    """Things outside the inventory yield no pose; their points stay in the map, and the planner's collision
    world sees them as occupied voxels (what no pose and no cell surface explains)."""
    from kitchenbot.executive.config import load_config
    from kitchenbot.planning.collision import CollisionWorld, SceneObject
    from kitchenbot.planning.robot import RobotModel

    lo, _ = cell.sink_interior
    placed = [(4, resting_pose(inventory, 4, 0.38, -0.10, 0.0, cell))]
    extra = [(_box(0.55, 0.08, lo[2]), (0.85, 0.35, 0.15)),
             (_box(0.60, -0.10, lo[2], (0.10, 0.07, 0.03)), (0.95, 0.85, 0.2))]
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002, extra=extra)
    p = Perceiver(perceiver.settings, inventory, cell if use_cell else None, use_cell=use_cell,
                  database=perceiver.database)
    r = p.perceive(views)
    assert _right(r, placed, inventory) == {0}
    assert len(r.poses) == 1 and r.rejected >= 2
    world = CollisionWorld(RobotModel.from_config(load_config()), cell)
    objs = [SceneObject(f"o{k}", inventory[po.obj_id], po.T_base_obj) for k, po in enumerate(r.poses)]
    vox = world.unexplained_voxels(r.map_points, objs, instance_points=[po.points for po in r.poses])
    for centre in ((0.55, 0.08), (0.60, -0.10)):
        near = np.linalg.norm(vox[:, :2] - centre, axis=1) < 0.05
        assert near.sum() >= 3, f"no obstacle voxels at {centre}"


@pytest.mark.parametrize("lying", [False, True])
def test_a_drink_can_gets_no_pose(perceiver, inventory, cell, lying):
    """A can is a cylinder of about a cup's, a mug's or a glass's size: at one voxel a cup or a glass upside down
    explains it (the lid where the base is), so the coarse checks passed it as a mug. At the sensor's precision
    the straight can is millimetres off the tapered cup and glass over much of its surface (verify.py, fine).
    Lying, it was fitted as a lying mug: the can (12 cm) goes on past the mug's ends (verify.py, continued)."""
    lo, _ = cell.sink_interior
    placed = [(4, resting_pose(inventory, 4, 0.38, -0.10, 0.0, cell))]
    can = _can(0.60, -0.10, lo[2])
    if lying:
        can.rotate(o3d.geometry.get_rotation_matrix_from_xyz((np.pi / 2, 0.0, 0.4)), center=can.get_center())
        can.translate((0.0, 0.0, lo[2] - can.get_min_bound()[2]))
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002, extra=[(can, (0.75, 0.1, 0.12))])
    p = Perceiver(perceiver.settings, inventory, None, use_cell=False, database=perceiver.database)
    r = p.perceive(views)
    assert _right(r, placed, inventory) == {0} and len(r.poses) == 1


@pytest.mark.parametrize("use_cell", [True, False])
def test_a_lying_bottle_gets_no_pose(perceiver, inventory, cell, use_cell):
    """A bottle lying in the sink is a cylinder of a cup's or a glass's width, twice as long: cups were fitted
    along its body one after the other, each explaining its stretch at the sensor's precision. Its body goes on
    past each cup's ends (verify.py, continued)."""
    from kitchenbot.world.dishware import lathe

    lo, _ = cell.sink_interior
    placed = [(4, resting_pose(inventory, 4, 0.38, -0.10, 0.0, cell))]
    r, h, neck = 0.036, 0.23, 0.013
    prof = np.array([(0.0, 0.0), (r - 0.003, 0.0), (r, 0.004), (r, h * 0.62), (neck * 1.6, h * 0.78), (neck, h * 0.86),
                     (neck, h), (0.0, h)])
    bottle = lathe(prof, 32)
    bottle.rotate(o3d.geometry.get_rotation_matrix_from_xyz((np.pi / 2, 0.0, 0.3)), center=(0.0, 0.0, 0.0))
    bottle.translate((0.58, 0.02, 0.0) - bottle.get_center())
    bottle.translate((0.0, 0.0, lo[2] - bottle.get_min_bound()[2]))
    bottle.compute_vertex_normals()
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002, extra=[(bottle, (0.2, 0.5, 0.3))])
    p = Perceiver(perceiver.settings, inventory, cell if use_cell else None, use_cell=use_cell,
                  database=perceiver.database)
    r_ = p.perceive(views)
    assert _right(r_, placed, inventory) == {0} and len(r_.poses) == 1


@pytest.mark.parametrize("radius,height", [(0.033, 0.22), (0.037, 0.25)])
def test_an_upright_bottle_gets_no_pose(perceiver, inventory, cell, radius, height):
    """A bottle standing in the sink: its straight body is as wide as a cup's, and a cup upside down (or two, one
    above the other) was fitted along it, within the sensor's precision over half its points (verification
    0.88-1.0). The bottle's body, shoulder and neck go on past the cup's base along its axis, within its radius,
    where a real cup ends (verify.py, continued, now judged for standing vessels where nothing reaches across)."""
    from kitchenbot.world.dishware import lathe

    lo, _ = cell.sink_interior
    placed = [(4, resting_pose(inventory, 4, 0.38, -0.10, 0.0, cell))]
    neck = 0.013
    prof = np.array([(0.0, 0.0), (radius - 0.003, 0.0), (radius, 0.004), (radius, height * 0.62),
                     (neck * 1.6, height * 0.78), (neck, height * 0.86), (neck, height), (0.0, height)])
    bottle = lathe(prof, 32)
    bottle.translate((0.58, 0.02, lo[2]) - np.array([0.0, 0.0, bottle.get_min_bound()[2]]))
    bottle.compute_vertex_normals()
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002, extra=[(bottle, (0.2, 0.5, 0.3))])
    p = Perceiver(perceiver.settings, inventory, cell, use_cell=True, database=perceiver.database)
    r = p.perceive(views)
    assert _right(r, placed, inventory) == {0} and len(r.poses) == 1


def test_under_a_support_is_solid_where_it_was_never_seen_through(inventory, cell):
    """A board over the basin with a box standing on it: the box hides 0.05 m^2 of the board (a hole in its
    footprint too large to fill). A glass sunk into the board there (only its base above it) puts its body in
    solid matter: nothing was seen behind the board in that hole. The sink's opening in the counter was seen
    through (the basin floor below it): a point in the basin is not solid."""
    lo, hi = cell.sink_interior
    w = cell.spec.sink.wall
    cx, cy = (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2
    board = _box(cx, cy, -0.03, (hi[0] - lo[0] + 2 * w, hi[1] - lo[1] + 2 * w, 0.03))
    box = _box(cx, cy, 0.0, (0.25, 0.20, 0.10))
    views, _ = render(inventory, [], scan_poses(cell), cell, noise=0.002,
                      extra=[(board, (0.62, 0.45, 0.30)), (box, (0.8, 0.6, 0.2))])
    sm = find_surfaces(views)
    table = [s for s in sm.supports if abs(s.offset) < 0.005]
    assert len(table) == 1
    under_box = np.array([[cx, cy, -0.05], [cx + 0.08, cy - 0.05, -0.08]])
    assert not table[0].covers(under_box).any()  # the box's shadow is a hole in the board's footprint ...
    assert sm.inside_solid(under_box).all()  # ... but never seen through: solid
    # A glass upside down, sunk into the board under the box, its base 2 cm over the board.
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [cx, cy, 0.02 + inventory[6].points[:, 2].min()]  # upside down: its base on top, at 2 cm
    P = inventory[6].points @ T[:3, :3].T + T[:3, 3]
    assert sm.inside_solid(P).mean() > 0.6

    # An empty sink: the counter's opening was seen through; the basin's inside is no solid.
    views, _ = render(inventory, [], scan_poses(cell), cell, noise=0.002)
    sm = find_surfaces(views)
    inside = np.array([[cx, cy, lo[2] + 0.05], [cx + 0.1, cy + 0.05, lo[2] + 0.10]])
    assert not sm.inside_solid(inside).any()


def _axis_pose(z, centre) -> np.ndarray:
    z = np.asarray(z, float) / np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = centre
    return T


@pytest.mark.xfail(strict=True, reason="known miss: the glass's right pose (2 mm off) is found from what the "
                   "compromise pose leaves, but fails `continued` (0.26): the can against its end has no pose, so its "
                   "points count as the glass going on past its end (fourteenth session)")
def test_a_glass_between_two_cans_is_found(perceiver, inventory, cell):
    """A glass lying between two tilted cans that touch it is one segment with them; the first pose of that
    segment is a compromise between the glass and the cans (its points 2-3 cm off the model: verification's
    `fine` 0.3) and is rejected, so the glass is lost (a development sink scene)."""
    axis_pose = _axis_pose
    glass = axis_pose([-0.97, -0.1, -0.24], [0.355, -0.015, -0.004])
    extra = []
    for z, centre in (([-0.48, -0.72, 0.5], [0.405, -0.116, -0.007]), ([-0.07, 0.59, -0.8], [0.449, 0.031, -0.011])):
        can = o3d.geometry.TriangleMesh.create_cylinder(0.038, 0.0905, resolution=40)
        can.transform(axis_pose(z, centre))
        can.compute_vertex_normals()
        extra.append((can, (0.6, 0.6, 0.62)))
    views, _ = render(inventory, [(6, glass)], scan_poses(cell), cell, noise=0.002, extra=extra)
    r = perceiver.perceive(views)
    errs = [adi(p.T_base_obj, glass, inventory[6].points) for p in r.poses if p.obj_id == 6]
    assert errs and min(errs) < 0.1 * inventory[6].diameter, [(p.cls, np.round(p.T_base_obj[:3, 3], 3)) for p in r.poses]

