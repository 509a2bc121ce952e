"""Parametric dishware families: new plates, saucers, bowls, cups, mugs, tumblers and stemmed glasses drawn
from ranges of their real dimensions, as closed meshes and inventory models (BOP-ready).

Each family turns a random generator into a profile (rim shape, well depth, bowl depth, belly, foot) and
optionally a handle; the mesh is a lathe of that closed profile (perception/dishware.py), so it is
watertight with a wall thickness like the builtin items. A stemmed glass gets its own profile (foot disc,
stem, bowl with an inner wall) because offsetting a whole stem inward would hollow it.
Dimensions in metres, from catalogue ranges of household dishware.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.world.dishware import _profile_closed, lathe, tube
from kitchenbot.world.inventory import ObjectModel, _diameter

CERAMIC = [(0.95, 0.95, 0.92), (0.92, 0.90, 0.82), (0.62, 0.78, 0.90), (0.35, 0.45, 0.70), (0.85, 0.75, 0.55),
           (0.55, 0.70, 0.50), (0.30, 0.30, 0.32), (0.90, 0.60, 0.60), (0.70, 0.55, 0.80)]
GLASS = [(0.78, 0.86, 0.94), (0.72, 0.82, 0.78), (0.85, 0.85, 0.88)]


def _colour(rng: np.random.Generator, glass: bool = False) -> tuple[float, float, float]:
    base = np.array((GLASS if glass else CERAMIC)[int(rng.integers(len(GLASS if glass else CERAMIC)))])
    return tuple(float(c) for c in np.clip(base + rng.normal(0, 0.03, 3), 0.05, 0.98))


def plate_profile(diam: float, height: float, foot_r: float, well_frac: float, rim_lift: float) -> np.ndarray:
    """Outer profile of a plate: foot ring radius `foot_r`, flat well out to `well_frac` x radius, then a
    rim rising to `height` (a higher `rim_lift` makes a coupe/soup-plate rim, a lower one a flat rim)."""
    R = diam / 2
    rw = max(R * well_frac, foot_r + 0.012)
    return np.array([(0.0, 0.0), (foot_r * 0.9, 0.0), (foot_r, 0.003), (foot_r + 0.008, height * 0.3),
                     (rw, height * (0.35 + 0.2 * rim_lift)), (R * 0.5 + rw * 0.5 + 0.01, height * (0.55 + 0.3 * rim_lift)),
                     (R * 0.96, height * 0.92), (R, height)])


def vessel_profile(r_bottom: float, r_top: float, height: float, belly: float = 0.0) -> np.ndarray:
    zs = np.linspace(0.008, height, 8)
    rs = r_bottom + (r_top - r_bottom) * (zs / height) + belly * np.sin(np.pi * zs / height)
    return np.vstack([[(0.0, 0.0), (r_bottom - 0.006, 0.0), (r_bottom - 0.002, 0.002)], np.column_stack([rs, zs])])


def bowl_profile(r_bottom: float, r_top: float, height: float, belly: float) -> np.ndarray:
    zs = np.linspace(0.006, height, 9)
    s = zs / height
    rs = r_bottom + (r_top - r_bottom) * s ** 0.8 + belly * np.sin(np.pi * s)
    return np.vstack([[(0.0, 0.0), (r_bottom - 0.004, 0.0), (r_bottom - 0.001, 0.002)], np.column_stack([rs, zs])])


def stemmed_glass_loop(foot_r: float, stem_r: float, stem_h: float, bowl_r: float, bowl_h: float,
                       thickness: float) -> np.ndarray:
    """Closed (r, z) loop of a stemmed glass: foot disc, solid stem, then a bowl with an inner wall."""
    ft = 0.004
    z0 = stem_h
    zs = np.linspace(0, 1, 9)
    bowl_outer = np.column_stack([stem_r + (bowl_r - stem_r) * np.sin(zs * np.pi / 2) ** 0.7, z0 + zs * bowl_h])
    inner = np.column_stack([np.maximum(bowl_outer[:, 0] - thickness, 0.0), bowl_outer[:, 1] + thickness * 0.5])
    inner[0] = (0.0, z0 + thickness * 2)
    return np.vstack([[(0.0, 0.0), (foot_r, 0.0), (foot_r, ft * 0.5), (foot_r * 0.6, ft), (stem_r * 1.6, ft * 2),
                       (stem_r, ft * 3), (stem_r, z0 * 0.95)],
                      bowl_outer[1:], [(bowl_r - thickness * 0.5, z0 + bowl_h + thickness * 0.3)],
                      inner[::-1][:-1], [(0.0, inner[0, 1])]])


def _handle(top: float, r_body: float, reach: float, span: float, radius: float) -> o3d.geometry.TriangleMesh:
    s = np.linspace(-np.pi / 2 + 0.25, np.pi / 2 - 0.25, 20)
    path = np.stack([r_body - 0.004 + reach * np.cos(s), np.zeros_like(s), top * 0.5 + top * span * np.sin(s)], 1)
    return tube(path, radius)


def _finish(mesh: o3d.geometry.TriangleMesh) -> o3d.geometry.TriangleMesh:
    mesh.translate(-mesh.get_axis_aligned_bounding_box().get_center())
    mesh.compute_vertex_normals()
    return mesh


# ---- the families: rng -> (class, mesh, colour, handle?, foot) ------------------------------------------------
def plate(rng):
    d, h = rng.uniform(0.19, 0.28), rng.uniform(0.016, 0.028)
    outer = plate_profile(d, h, rng.uniform(0.055, 0.09), rng.uniform(0.55, 0.8), rng.uniform(0.0, 0.6))
    return "plate", lathe(_profile_closed(outer, rng.uniform(0.004, 0.0055))), _colour(rng), False


def saucer(rng):
    d, h = rng.uniform(0.13, 0.165), rng.uniform(0.014, 0.02)
    outer = plate_profile(d, h, rng.uniform(0.035, 0.05), rng.uniform(0.45, 0.6), rng.uniform(0.3, 1.0))
    return "plate", lathe(_profile_closed(outer, rng.uniform(0.0035, 0.0045))), _colour(rng), False


def deep_plate(rng):
    d, h = rng.uniform(0.21, 0.26), rng.uniform(0.035, 0.05)
    outer = plate_profile(d, h, rng.uniform(0.06, 0.08), rng.uniform(0.45, 0.6), rng.uniform(0.6, 1.0))
    return "plate", lathe(_profile_closed(outer, 0.005)), _colour(rng), False


def bowl(rng):
    r_top, h = rng.uniform(0.055, 0.09), rng.uniform(0.045, 0.085)
    outer = bowl_profile(rng.uniform(0.03, 0.045), r_top, h, rng.uniform(0.0, 0.014))
    return "bowl", lathe(_profile_closed(outer, rng.uniform(0.004, 0.0055))), _colour(rng), False


def cup(rng):
    h = rng.uniform(0.075, 0.105)
    outer = vessel_profile(rng.uniform(0.025, 0.033), rng.uniform(0.036, 0.046), h, rng.uniform(0.0, 0.006))
    return "cup", lathe(_profile_closed(outer, rng.uniform(0.003, 0.0045))), _colour(rng), False


def espresso_cup(rng):
    h, r_top = rng.uniform(0.05, 0.065), rng.uniform(0.028, 0.034)
    mesh = lathe(_profile_closed(vessel_profile(rng.uniform(0.018, 0.024), r_top, h, rng.uniform(0, 0.004)), 0.004))
    mesh += _handle(h, r_top, rng.uniform(0.018, 0.024), rng.uniform(0.22, 0.3), rng.uniform(0.0035, 0.0045))
    return "mug", mesh, _colour(rng), True


def mug(rng):
    h, r = rng.uniform(0.08, 0.11), rng.uniform(0.036, 0.046)
    mesh = lathe(_profile_closed(vessel_profile(r - rng.uniform(0, 0.006), r, h, rng.uniform(0, 0.004)), 0.005))
    mesh += _handle(h, r, rng.uniform(0.026, 0.036), rng.uniform(0.26, 0.36), rng.uniform(0.005, 0.007))
    return "mug", mesh, _colour(rng), True


def tumbler(rng):
    h = rng.uniform(0.08, 0.13)
    outer = vessel_profile(rng.uniform(0.026, 0.034), rng.uniform(0.032, 0.042), h, 0.0)
    return "glass", lathe(_profile_closed(outer, rng.uniform(0.002, 0.003))), _colour(rng, glass=True), False


def stemmed_glass(rng):
    loop = stemmed_glass_loop(rng.uniform(0.03, 0.04), rng.uniform(0.0035, 0.005), rng.uniform(0.06, 0.09),
                              rng.uniform(0.035, 0.045), rng.uniform(0.08, 0.105), 0.0022)
    return "glass", lathe(loop), _colour(rng, glass=True), False


FAMILIES = {"plate": plate, "saucer": saucer, "deep_plate": deep_plate, "bowl": bowl, "cup": cup,
            "espresso_cup": espresso_cup, "mug": mug, "tumbler": tumbler, "stemmed_glass": stemmed_glass}


def make_model(obj_id: int, name: str, family: str, rng: np.random.Generator) -> ObjectModel:
    """One member of `family`, drawn from `rng`, as an inventory model (no grasps: planning synthesises them,
    `planning.grasp_synthesis.ensure_grasps`)."""
    cls, mesh, colour, handle = FAMILIES[family](rng)
    mesh = _finish(mesh)
    model = ObjectModel(obj_id=obj_id, name=name, cls=cls, mesh=mesh, diameter=_diameter(np.asarray(mesh.vertices)),
                        symmetries_continuous=[] if handle else [{"axis": [0, 0, 1], "offset": [0, 0, 0]}],
                        colour=colour)
    return model


def sample_dishware(rng: np.random.Generator, first_id: int, families: list[str] | None = None) -> list[ObjectModel]:
    """One new model of each family (default: all), ids from `first_id`, names ``<family>_<id>``."""
    out = []
    for k, fam in enumerate(families or list(FAMILIES)):
        if fam not in FAMILIES:
            raise ValueError(f"dishware family: expected one of {sorted(FAMILIES)}, got {fam!r}")
        oid = first_id + k
        out.append(make_model(oid, f"{fam}_{oid}", fam, rng))
    return out
