"""Sink fixtures beyond the cell's boxes: rounded basin corners, a drain, a faucet, a wire grid on the floor.

Each function returns SimWorld fixtures (base-frame triangle meshes) for a cell's basin; `random_fixtures`
draws a combination for one scene. The basin itself stays the cell's boxes, so the configured cell still
describes it; the fixtures are what a real sink adds that the cell description does not.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.fakes.world import Fixture
from kitchenbot.world.dishware import tube

CHROME = (0.80, 0.81, 0.83)


def fillet_prism(r: float, length: float, n: int = 8) -> o3d.geometry.TriangleMesh:
    """A closed prism along z (0..length) whose cross-section fills the corner x, y in [0, r] outside the
    circle of radius r about (r, r): what rounds an inside corner of radius r."""
    a = np.linspace(-np.pi / 2, -np.pi, n + 1)  # arc from (r, 0) to (0, r) about (r, r)
    arc = np.column_stack([r + r * np.cos(a), r + r * np.sin(a)])
    poly = np.vstack([[0.0, 0.0], arc])  # fan centre first
    m = len(poly)
    V = np.vstack([np.column_stack([poly, np.zeros(m)]), np.column_stack([poly, np.full(m, length)])])
    tris = []
    for i in range(1, m - 1):
        tris += [(0, i + 1, i), (m, m + i, m + i + 1)]  # caps
    for i in range(m):
        j = (i + 1) % m
        tris += [(i, j, m + j), (i, m + j, m + i)]
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(np.array(tris)))
    mesh.compute_vertex_normals()
    return mesh


def _placed(mesh: o3d.geometry.TriangleMesh, R: np.ndarray, t) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh(mesh)
    m.rotate(R, center=(0, 0, 0))
    m.translate(np.asarray(t, float))
    return m


def rounded_corners(cell, radius: float, colour) -> list[Fixture]:
    """Fillets in the basin's four vertical corners and along its four floor edges."""
    (x0, y0, z0), (x1, y1, _) = cell.sink_interior
    depth = -z0
    out = []
    Rz = lambda a: np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])  # noqa: E731
    for k, (x, y, a) in enumerate([(x0, y0, 0), (x1, y0, np.pi / 2), (x1, y1, np.pi), (x0, y1, -np.pi / 2)]):
        m = _placed(fillet_prism(radius, depth), Rz(a), (x, y, z0))
        out.append(Fixture(f"fillet_v{k}", "fillet", m, colour, 0.5))
    # Floor edges: the prism's z axis laid along x (walls at y0, y1) or y (walls at x0, x1); local y -> up.
    # (The maps for the far walls are reflections: harmless, nothing reads the winding of a fixture.)
    L = x1 - x0
    for k, (side, y) in enumerate([(1, y0), (-1, y1)]):  # along x, walls at y0 (section opens +y) and y1 (-y)
        R = np.array([[0, 0, 1], [side, 0, 0], [0, 1, 0]], float)
        m = _placed(fillet_prism(radius, L), R, (x0, y, z0))
        out.append(Fixture(f"fillet_fx{k}", "fillet", m, colour, 0.5))
    W = y1 - y0
    for k, (side, x) in enumerate([(1, x0), (-1, x1)]):
        R = np.array([[side, 0, 0], [0, 0, 1], [0, 1, 0]], float)  # local x -> +/-x, y -> z, z -> y
        m = _placed(fillet_prism(radius, W), R, (x, y0, z0))
        out.append(Fixture(f"fillet_fy{k}", "fillet", m, colour, 0.5))
    return out


def drain(cell, xy: tuple[float, float], radius: float = 0.045) -> list[Fixture]:
    """A drain: a chrome flange ring 3 mm proud of the floor round a dark strainer."""
    z0 = cell.sink_interior[0][2]
    ring = o3d.geometry.TriangleMesh.create_cylinder(radius, 0.003, resolution=40)
    ring.translate((xy[0], xy[1], z0 + 0.0015))
    grate = o3d.geometry.TriangleMesh.create_cylinder(radius * 0.75, 0.0034, resolution=32)
    grate.translate((xy[0], xy[1], z0 + 0.0017))
    return [Fixture("drain_ring", "drain", ring, CHROME, 0.6), Fixture("drain_grate", "drain", grate, (0.15, 0.15, 0.16), 0.2)]


def faucet(cell, y: float, height: float, reach: float) -> list[Fixture]:
    """A faucet on the counter behind the basin (far side, +x): a column and a spout arching over the sink."""
    (_, _, _), (x1, _, _) = cell.sink_interior
    xc = x1 + cell.spec.sink.wall + 0.05
    col = o3d.geometry.TriangleMesh.create_cylinder(0.018, height, resolution=24)
    col.translate((xc, y, height / 2))
    s = np.linspace(0, np.pi / 2, 12)
    path = np.column_stack([xc - reach * np.sin(s), np.full_like(s, y), height - 0.03 + 0.05 * np.cos(s) - 0.05 * (1 - np.cos(s))])
    path[0, 2] = height - 0.01
    spout = tube(path, 0.011, sides=14)
    spout.compute_vertex_normals()
    return [Fixture("faucet_column", "faucet", col, CHROME, 0.6), Fixture("faucet_spout", "faucet", spout, CHROME, 0.6)]


def floor_grid(cell, pitch: float = 0.03, rod: float = 0.005, lift: float = 0.008) -> list[Fixture]:
    """A stainless wire grid lying on the basin floor (rods along x on feet, cross rods along y), 2 cm in."""
    (x0, y0, z0), (x1, y1, _) = cell.sink_interior
    x0, y0, x1, y1 = x0 + 0.02, y0 + 0.02, x1 - 0.02, y1 - 0.02
    mesh = o3d.geometry.TriangleMesh()
    for y in np.arange(y0, y1, pitch):
        b = o3d.geometry.TriangleMesh.create_box(x1 - x0, rod, rod)
        b.translate((x0, y, z0 + lift))
        mesh += b
    for x in (x0, (x0 + x1) / 2, x1 - rod):
        b = o3d.geometry.TriangleMesh.create_box(rod, y1 - y0, lift)
        b.translate((x, y0, z0))
        mesh += b
    mesh.compute_vertex_normals()
    return [Fixture("floor_grid", "rack", mesh, (0.70, 0.72, 0.74), 0.5)]


def random_fixtures(cell, rng: np.random.Generator) -> list[Fixture]:
    """A random combination for one scene: rounded corners, a drain, a faucet, a floor grid."""
    (x0, y0, _), (x1, y1, _) = cell.sink_interior
    colour = tuple(float(c) for c in cell.boxes[[b.kind for b in cell.boxes].index("sink")].colour)
    out: list[Fixture] = []
    if rng.random() < 0.5:
        out += rounded_corners(cell, float(rng.uniform(0.02, 0.05)), colour)
    if rng.random() < 0.7:
        out += drain(cell, (float(rng.uniform(x0 + 0.08, x1 - 0.08)), float(rng.uniform(y0 + 0.08, y1 - 0.08))))
    if rng.random() < 0.6:
        out += faucet(cell, float(rng.uniform(y0 + 0.05, y1 - 0.05)), float(rng.uniform(0.22, 0.32)),
                      float(rng.uniform(0.14, 0.22)))
    if rng.random() < 0.3:
        out += floor_grid(cell)
    return out
