"""Procedural dishware of the project's own design: closed meshes with wall thickness.

Round items are surfaces of revolution of a closed profile (outer wall up, rim, inner wall down), so each
mesh is watertight by construction; the mug adds a swept-tube handle. Dimensions are typical of household
dishware (metres). Frames follow BOP: origin at the bounding-box centre, z up (the item's rim up).

Written by hand because what is needed is tiny (a lathe and a sweep) and Open3D/trimesh have no lathe with
wall thickness; everything downstream (sampling, raycasting, I/O) uses Open3D.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d


@dataclass(frozen=True)
class DishSpec:
    name: str
    cls: str
    colour: tuple[float, float, float]
    outer: tuple[tuple[float, float], ...]  # (r, z) outer profile from the bottom centre to the rim, metres
    thickness: float
    handle: bool = False
    # (outer radius, radial width, height) of a foot ring under the body (bowls), metres; `outer` then starts
    # at the body's underside, `height` above the bottom, and the ring is added below it
    foot: tuple[float, float, float] | None = None


def _profile_closed(outer: np.ndarray, thickness: float,
                    foot: tuple[float, float, float] | None = None) -> np.ndarray:
    """Closed (r, z) loop: outer wall bottom->rim, then the inner wall rim->bottom offset by `thickness`.

    The inner wall is the outer one offset along its inward normal; the loop starts and ends on the axis.
    With `foot` = (outer radius, width, height) a solid foot ring (chamfered 1 mm at its standing edge) is
    added under the body's underside, which `outer` starts at (z = height).
    """
    pts = np.asarray(outer, float)
    # Tangents and inward normals (pointing towards the axis/up, i.e. inside the vessel).
    t = np.gradient(pts, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    n = np.stack([-t[:, 1], t[:, 0]], axis=1)  # rotate tangent +90 deg: for a profile going out/up, points in/up
    inner = pts + thickness * n
    inner[0, 0] = 0.0  # inner bottom centre stays on the axis
    inner[:, 0] = np.maximum(inner[:, 0], 0.0)
    # Round the rim with a half-circle between the outer and inner rim points.
    a, b = pts[-1], inner[-1]
    c, r = (a + b) / 2, np.linalg.norm(a - b) / 2
    d = (a - c) / max(r, 1e-9)
    ang = np.linspace(0, np.pi, 7)[1:-1]
    perp = np.array([-d[1], d[0]])
    if perp[1] < 0:
        perp = -perp
    rim = c + r * (np.cos(ang)[:, None] * d + np.sin(ang)[:, None] * perp)
    if foot is not None:
        ro, w, h = foot
        ri, c = ro - w, 0.001
        if not (0 < ri and abs(pts[0, 1] - h) < 1e-9 and pts[0, 0] == 0 and pts[1, 0] >= ro):
            raise ValueError(f"foot {foot}: the body profile must start on the axis at z = {h} and its underside "
                             f"must reach past the ring's outer radius")
        ring = np.array([[ri, h], [ri, c], [ri + c, 0.0], [ro - c, 0.0], [ro, c], [ro, h]])
        if pts[1, 0] - ro < 1e-9:
            ring = ring[:-1]
        pts = np.vstack([pts[:1], ring, pts[1:]])
    loop = np.vstack([pts, rim, inner[::-1]])
    return loop


def lathe(profile: np.ndarray, segments: int = 64) -> o3d.geometry.TriangleMesh:
    """Revolve a (r, z) polyline whose first and last points lie on the axis into a closed mesh."""
    assert abs(profile[0, 0]) < 1e-12 and abs(profile[-1, 0]) < 1e-12, "profile ends must be on the axis"
    ring = profile[1:-1]
    m = len(ring)
    th = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    verts = [np.array([0.0, 0.0, profile[0, 1]])]
    for r, z in ring:
        verts.extend(np.stack([r * np.cos(th), r * np.sin(th), np.full(segments, z)], axis=1))
    verts.append(np.array([0.0, 0.0, profile[-1, 1]]))
    V = np.vstack([np.atleast_2d(v) for v in verts])
    tris = []
    top = len(V) - 1
    idx = lambda i, j: 1 + i * segments + (j % segments)  # noqa: E731
    for j in range(segments):  # bottom fan (outer bottom, normal -z)
        tris.append((0, idx(0, j + 1), idx(0, j)))
    for i in range(m - 1):
        for j in range(segments):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j), idx(i + 1, j + 1)
            tris.append((a, b, d))
            tris.append((a, d, c))
    for j in range(segments):  # inner bottom fan (normal +z)
        tris.append((top, idx(m - 1, j), idx(m - 1, j + 1)))
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(np.array(tris)))
    return mesh


def tube(path: np.ndarray, radius: float, sides: int = 16) -> o3d.geometry.TriangleMesh:
    """A closed tube (capped) swept along a 3D polyline."""
    n = len(path)
    t = np.gradient(path, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    ref = np.array([0.0, 1.0, 0.0])
    verts = []
    ang = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    for p, ti in zip(path, t):
        u = np.cross(ti, ref)
        u /= np.linalg.norm(u)
        v = np.cross(ti, u)
        verts.extend(p + radius * (np.cos(a) * u + np.sin(a) * v) for a in ang)
    V = np.array(verts + [path[0], path[-1]])
    c0, c1 = len(V) - 2, len(V) - 1
    tris = []
    for i in range(n - 1):
        for j in range(sides):
            a, b = i * sides + j, i * sides + (j + 1) % sides
            c, d = a + sides, b + sides
            tris += [(a, b, d), (a, d, c)]
    for j in range(sides):
        tris.append((c0, (j + 1) % sides, j))
        tris.append((c1, (n - 1) * sides + j, (n - 1) * sides + (j + 1) % sides))
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(np.array(tris)))


def _plate(diam: float, height: float, foot: float) -> tuple[tuple[float, float], ...]:
    R = diam / 2
    return ((0.0, 0.0), (foot * 0.9, 0.0), (foot, 0.003), (foot + 0.01, height * 0.35),
            (R * 0.78, height * 0.55), (R * 0.95, height * 0.9), (R, height))


def _vessel(r_bottom: float, r_top: float, height: float, belly: float = 0.0) -> tuple[tuple[float, float], ...]:
    zs = np.linspace(0.008, height, 8)
    rs = r_bottom + (r_top - r_bottom) * (zs / height) + belly * np.sin(np.pi * zs / height)
    return ((0.0, 0.0), (r_bottom - 0.006, 0.0), (r_bottom - 0.002, 0.002)) + tuple(zip(rs, zs))


def _bowl_body(r_bottom: float, r_top: float, height: float, foot_h: float, belly: float) -> tuple[tuple[float, float], ...]:
    """Outer profile of a bowl's body from its flat underside (z = foot_h, on the axis) to the rim."""
    zs = np.linspace(foot_h + 0.004, height, 9)
    s = (zs - foot_h) / (height - foot_h)
    rs = r_bottom + (r_top - r_bottom) * s + belly * np.sin(np.pi * s)
    return ((0.0, foot_h), (r_bottom - 0.003, foot_h), (r_bottom - 0.001, foot_h + 0.001)) + tuple(zip(rs, zs))


# A ceramic bowl's foot ring: 3.4 cm outer radius, 5 mm wide, 10 mm tall (what it stands on; an upside-down
# bowl offers it to a pinch from above).
BOWL_FOOT = (0.034, 0.005, 0.010)

BUILTIN_DISHES: tuple[DishSpec, ...] = (
    DishSpec("dinner_plate", "plate", (0.95, 0.95, 0.92), _plate(0.270, 0.026, 0.085), 0.005),
    DishSpec("side_plate", "plate", (0.62, 0.78, 0.90), _plate(0.200, 0.020, 0.060), 0.0045),
    DishSpec("bowl", "bowl", (0.90, 0.55, 0.35), _bowl_body(0.042, 0.080, 0.070, BOWL_FOOT[2], belly=0.010), 0.0045,
             foot=BOWL_FOOT),
    DishSpec("cup", "cup", (0.30, 0.65, 0.45), _vessel(0.029, 0.042, 0.095), 0.0035),
    DishSpec("mug", "mug", (0.80, 0.25, 0.25), _vessel(0.039, 0.041, 0.095), 0.005, handle=True),
    DishSpec("glass", "glass", (0.75, 0.85, 0.95), _vessel(0.030, 0.036, 0.120), 0.0025),
)


def build_mesh(spec: DishSpec) -> o3d.geometry.TriangleMesh:
    """The item's closed mesh in its BOP object frame (bounding-box centre origin, z up), metres."""
    mesh = lathe(_profile_closed(np.array(spec.outer), spec.thickness, spec.foot))
    if spec.handle:
        top = spec.outer[-1][1]
        r_body = spec.outer[-1][0]
        s = np.linspace(-np.pi / 2 + 0.25, np.pi / 2 - 0.25, 20)
        reach, half_h = 0.032, top * 0.32
        path = np.stack([r_body - 0.004 + reach * np.cos(s), np.zeros_like(s), top * 0.5 + half_h * np.sin(s)], 1)
        mesh += tube(path, 0.006)
    bb = mesh.get_axis_aligned_bounding_box()
    mesh.translate(-bb.get_center())
    mesh.compute_vertex_normals()
    return mesh
