"""Shared pytest fixtures and the hardware-in-the-loop switch.

Tests marked ``@pytest.mark.hil`` talk to real devices named in the config given by
``KITCHENBOT_HIL_CONFIG``; they run only when ``KITCHENBOT_HIL=1`` (never in CI).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

# Every planner in the suite (in this process, in `kitchenbot` subprocesses, in the daemon's worker) stops
# RRT-Connect after a fixed number of iterations from a fixed seed instead of after a wall-clock budget: a plan
# is then the same on an idle machine and on a loaded one. Set before kitchenbot is imported (the config's
# defaults read them). ~200 iterations are about the default 1 s budget on an idle machine.
os.environ.setdefault("KITCHENBOT_PLANNER_MAX_ITERATIONS", "200")
os.environ.setdefault("KITCHENBOT_PLANNER_SEED", "0")


def pytest_collection_modifyitems(config, items):
    if os.environ.get("KITCHENBOT_HIL") == "1":
        return
    skip = pytest.mark.skip(reason="hardware-in-the-loop test: set KITCHENBOT_HIL=1 and KITCHENBOT_HIL_CONFIG")
    for item in items:
        if "hil" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@pytest.fixture(scope="session")
def empty_sim_cell():
    """A function giving the simulated cell (config/sim.yaml) with its sink emptied, and a planner for it:
    `cfg, world, planner = empty_sim_cell()`; for tests that build their own hand-made situation in the sink."""
    from kitchenbot.executive.assembly import make_sim_world
    from kitchenbot.executive.config import load_config
    from kitchenbot.planning.pick_place import Planner

    def make(config: str = "config/sim.yaml"):
        cfg = load_config(config)
        world = make_sim_world(cfg, 0)
        for u in list(world.objects):
            world.remove_object(u)
        return cfg, world, Planner.from_config(cfg, world.inventory)
    return make


def write_own_dishware(folder, cup: bool = False):
    """A BOP models/ folder of dishware this project has never seen, made here from parametric profiles: meshes
    (mm) and models_info.json with diameters only (no classes, no grasps, no symmetries). `cup`: also a handle-less
    teacup (class cup: what cup-stacking takes). Returns {obj_id: (name, expected class)}."""
    from kitchenbot.world.dishware import DishSpec, _bowl_body, _plate, _vessel, build_mesh
    from kitchenbot.world.inventory import Inventory, ObjectModel, _diameter

    specs = [  # (name, expected class, spec)
        ("saucer", "plate", DishSpec("saucer", "?", (0.85, 0.80, 0.70), _plate(0.150, 0.019, 0.040), 0.004)),
        ("tumbler", "glass", DishSpec("tumbler", "?", (0.70, 0.80, 0.85), _vessel(0.031, 0.035, 0.110), 0.003)),
        ("espresso_cup", "mug", DishSpec("espresso_cup", "?", (0.95, 0.90, 0.60), _vessel(0.024, 0.031, 0.064),
                                         0.004, handle=True)),
        ("deep_bowl", "bowl", DishSpec("deep_bowl", "?", (0.40, 0.55, 0.75),
                                       _bowl_body(0.036, 0.072, 0.088, 0.008, belly=0.006), 0.004,
                                       foot=(0.031, 0.005, 0.008))),
    ]
    if cup:  # tapered (it nests in its own kind), wider and shorter than the builtin cup
        specs.append(("teacup", "cup", DishSpec("teacup", "?", (0.55, 0.35, 0.60), _vessel(0.026, 0.040, 0.078),
                                                0.003)))
    models = []
    for i, (name, _, spec) in enumerate(specs, start=1):
        mesh = build_mesh(spec)
        models.append(ObjectModel(i, name, "?", mesh, _diameter(np.asarray(mesh.vertices)), colour=spec.colour))
    Inventory(models).save_bop(folder)
    return {i: (name, cls) for i, (name, cls, _) in enumerate(specs, start=1)}


def write_own_dishware_b(folder):
    """A second models/ folder of unseen dishware, with other proportions than `write_own_dishware`'s: a shallow
    pasta plate with a wide flat rim, a straight-walled conical bowl, a tall mug with a big handle, a stemmed wine
    glass and a small ramekin (thick, straight walls). Meshes (mm) and diameters only. Returns {obj_id: (name,
    expected class)}."""
    from kitchenbot.world.dishware import _profile_closed, lathe, tube

    def vessel(outer, thickness):
        return lathe(_profile_closed(np.array(outer, float), thickness))

    pasta = vessel([(0, 0), (0.050, 0), (0.054, 0.003), (0.062, 0.012), (0.080, 0.030), (0.092, 0.036),
                    (0.120, 0.040), (0.145, 0.044)], 0.005)
    cone = vessel([(0, 0), (0.022, 0), (0.025, 0.002)] + [(0.025 + 0.060 * z / 0.075, z)
                                                         for z in np.linspace(0.006, 0.075, 8)], 0.004)
    mug = vessel([(0, 0), (0.034, 0), (0.038, 0.002)] + [(0.040, z) for z in np.linspace(0.008, 0.125, 8)], 0.005)
    s = np.linspace(-np.pi / 2 + 0.25, np.pi / 2 - 0.25, 24)
    mug += tube(np.stack([0.036 + 0.045 * np.cos(s), np.zeros_like(s), 0.0625 + 0.045 * np.sin(s)], 1), 0.007)
    zs = np.linspace(0, 1, 10)
    stem_h, bowl_h, bowl_r, t = 0.075, 0.110, 0.043, 0.0022
    bowl = np.column_stack([0.0045 + (bowl_r - 0.0045) * np.sin(zs * np.pi * 0.62) ** 0.8 / np.sin(np.pi * 0.62) ** 0.8,
                            stem_h + zs * bowl_h])
    inner = np.column_stack([np.maximum(bowl[:, 0] - t, 0.0), bowl[:, 1] + t * 0.5])
    inner[0] = (0.0, stem_h + 2 * t)
    wine = lathe(np.vstack([[(0, 0), (0.036, 0), (0.036, 0.002), (0.022, 0.004), (0.007, 0.008), (0.0045, 0.012),
                             (0.0045, stem_h * 0.95)], bowl[1:], [(bowl_r - t * 0.5, stem_h + bowl_h + t * 0.3)],
                            inner[::-1][:-1], [(0.0, inner[0, 1])]]))
    ramekin = vessel([(0, 0), (0.040, 0), (0.044, 0.003)] + [(0.045, z) for z in np.linspace(0.008, 0.050, 5)],
                     0.0065)
    specs = [("pasta_plate", "plate", pasta, (0.93, 0.92, 0.88)), ("conical_bowl", "bowl", cone, (0.35, 0.45, 0.70)),
             ("tall_mug", "mug", mug, (0.75, 0.30, 0.20)), ("wine_glass", "glass", wine, (0.80, 0.88, 0.93)),
             ("ramekin", "bowl", ramekin, (0.95, 0.95, 0.95))]
    return _save_own_set(folder, specs)


def _save_own_set(folder, specs):
    """Write (name, expected class, mesh in metres, colour) specs as a BOP models/ folder with no classes (ids from
    1, meshes centred). Returns {obj_id: (name, expected class)}."""
    from kitchenbot.world.inventory import Inventory, ObjectModel, _diameter

    models = []
    for i, (name, _, mesh, colour) in enumerate(specs, start=1):
        mesh.translate(-mesh.get_axis_aligned_bounding_box().get_center())
        mesh.compute_vertex_normals()
        models.append(ObjectModel(i, name, "?", mesh, _diameter(np.asarray(mesh.vertices)), colour=colour))
    Inventory(models).save_bop(folder)
    return {i: (name, cls) for i, (name, cls, _, _) in enumerate(specs, start=1)}


def write_own_dishware_c(folder):
    """A third models/ folder of unseen dishware, shapes neither other set has: a square plate (rounded corners),
    an oval gravy-boat-like bowl (not round), a stemless glass whose mouth is narrower than its belly, and a
    fluted ramekin (a wavy wall, not round). Meshes (mm) and diameters only. Returns {obj_id: (name, expected
    class)}."""
    from kitchenbot.world.dishware import _profile_closed, lathe

    def vessel(outer, thickness):
        return lathe(_profile_closed(np.array(outer, float), thickness), segments=96)

    def warp(mesh, radius_factor):  # each vertex moved radially by radius_factor(azimuth): a closed mesh stays closed
        V = np.asarray(mesh.vertices).copy()
        V[:, :2] *= radius_factor(np.arctan2(V[:, 1], V[:, 0]))[:, None]
        mesh.vertices = o3d.utility.Vector3dVector(V)
        return mesh

    import open3d as o3d

    square = warp(vessel([(0, 0), (0.060, 0), (0.064, 0.002), (0.080, 0.014), (0.095, 0.018), (0.118, 0.022)],
                         0.0045),
                  lambda a: (np.abs(np.cos(a)) ** 6 + np.abs(np.sin(a)) ** 6) ** (-1 / 6))
    oval = vessel([(0, 0), (0.030, 0), (0.034, 0.003), (0.050, 0.020), (0.060, 0.045), (0.064, 0.068)], 0.004)
    oval = warp(oval, lambda a: 1.0 / np.sqrt((np.cos(a) / 1.35) ** 2 + (np.sin(a) / 0.9) ** 2))
    stemless = vessel([(0, 0), (0.026, 0), (0.029, 0.003), (0.038, 0.025), (0.041, 0.045), (0.039, 0.070),
                       (0.035, 0.095), (0.033, 0.110)], 0.0025)
    fluted = warp(vessel([(0, 0), (0.036, 0), (0.040, 0.003)] + [(0.042, z) for z in np.linspace(0.008, 0.045, 5)],
                         0.005),
                  lambda a: 1.0 + 0.05 * np.cos(12 * a))
    specs = [("square_plate", "plate", square, (0.92, 0.90, 0.85)), ("oval_bowl", "bowl", oval, (0.85, 0.80, 0.60)),
             ("stemless_glass", "glass", stemless, (0.82, 0.88, 0.92)),
             ("fluted_ramekin", "bowl", fluted, (0.95, 0.93, 0.90))]
    return _save_own_set(folder, specs)


def write_own_dishware_d(folder):
    """A fourth models/ folder of unseen dishware, sized from retail catalogues: a small side plate (19 cm, a foot
    ring and a raised rim), a rimmed pasta plate (27 cm, a deep well inside a wide sloping rim), a shallow cereal
    bowl (16 cm, 5.5 cm tall, a foot ring), a tall latte glass (a thick base, 14 cm), a mug with a large ear handle
    and a handle-less stackable tea cup (tapered: class cup, what cup-stacking takes). Meshes (mm) and diameters
    only. Returns {obj_id: (name, expected class)}."""
    from kitchenbot.world.dishware import _profile_closed, lathe, tube

    def vessel(outer, thickness, foot=None):
        return lathe(_profile_closed(np.array(outer, float), thickness, foot=foot), segments=96)

    side = vessel([(0, 0.004), (0.045, 0.004), (0.050, 0.006), (0.072, 0.011), (0.082, 0.014), (0.090, 0.018),
                   (0.095, 0.021)], 0.004, foot=(0.044, 0.004, 0.004))
    pasta = vessel([(0, 0.005), (0.060, 0.005), (0.064, 0.008), (0.078, 0.024), (0.088, 0.032), (0.105, 0.036),
                    (0.125, 0.041), (0.135, 0.044)], 0.0045, foot=(0.058, 0.005, 0.005))
    cereal = vessel([(0, 0.007), (0.036, 0.007), (0.040, 0.009), (0.058, 0.020), (0.070, 0.033), (0.077, 0.045),
                     (0.080, 0.055)], 0.004, foot=(0.035, 0.005, 0.007))
    latte = vessel([(0, 0.010), (0.031, 0.010)] + [(0.032 + 0.0055 * z / 0.140, z) for z in np.linspace(0.016, 0.140, 8)],
                   0.0028, foot=(0.031, 0.029, 0.010))  # a heavy solid base, 1 cm
    mug = vessel([(0, 0), (0.037, 0), (0.041, 0.003)] + [(0.042, z) for z in np.linspace(0.010, 0.095, 7)], 0.0045)
    s = np.linspace(-np.pi / 2 + 0.3, np.pi / 2 - 0.3, 24)
    mug += tube(np.stack([0.038 + 0.036 * np.cos(s), np.zeros_like(s), 0.050 + 0.036 * np.sin(s)], 1), 0.0065)
    tea = vessel([(0, 0), (0.024, 0), (0.027, 0.003)] + [(0.027 + 0.013 * (z / 0.080) ** 0.9, z)
                                                         for z in np.linspace(0.010, 0.080, 8)], 0.003)
    specs = [("side_plate", "plate", side, (0.96, 0.95, 0.90)), ("pasta_plate_rimmed", "plate", pasta,
                                                                  (0.90, 0.88, 0.82)),
             ("cereal_bowl", "bowl", cereal, (0.70, 0.20, 0.25)), ("latte_glass", "glass", latte, (0.84, 0.90, 0.94)),
             ("big_handle_mug", "mug", mug, (0.25, 0.45, 0.35)), ("tea_cup", "cup", tea, (0.95, 0.92, 0.80))]
    return _save_own_set(folder, specs)


@pytest.fixture(scope="session")
def own_dishware(tmp_path_factory):
    """(models_dir, {obj_id: (name, expected class)}) of dishware this project has never seen."""
    folder = tmp_path_factory.mktemp("own_dishware") / "models"
    return folder, write_own_dishware(folder)


@pytest.fixture(scope="session")
def own_dishware_b(tmp_path_factory):
    """(models_dir, {obj_id: (name, expected class)}) of the second set (`write_own_dishware_b`)."""
    folder = tmp_path_factory.mktemp("own_dishware_b") / "models"
    return folder, write_own_dishware_b(folder)


@pytest.fixture(scope="session")
def own_dishware_c(tmp_path_factory):
    """(models_dir, {obj_id: (name, expected class)}) of the third set (`write_own_dishware_c`)."""
    folder = tmp_path_factory.mktemp("own_dishware_c") / "models"
    return folder, write_own_dishware_c(folder)


@pytest.fixture(scope="session")
def own_dishware_d(tmp_path_factory):
    """(models_dir, {obj_id: (name, expected class)}) of the fourth set (`write_own_dishware_d`)."""
    folder = tmp_path_factory.mktemp("own_dishware_d") / "models"
    return folder, write_own_dishware_d(folder)


def tulip_glass_mesh():
    """Set E's red-wine glass: a disc foot, a thin stem, a tulip bowl (2.2 mm wall) widest at a third of its height,
    its mouth leaning inwards."""
    from kitchenbot.world.dishware import lathe

    stem_h, bowl_h, bowl_r, t = 0.085, 0.135, 0.046, 0.0022
    s = np.linspace(0, 1, 12)
    shape = np.sin(s * np.pi * 0.78) ** 0.7  # widest at 2/3 of pi/2's height, then leaning inwards to the mouth
    bowl = np.column_stack([0.0045 + (bowl_r - 0.0045) * shape / shape.max(), stem_h + s * bowl_h])
    inner = np.column_stack([np.maximum(bowl[:, 0] - t, 0.0), bowl[:, 1] + t * 0.5])
    inner[0] = (0.0, stem_h + 2 * t)
    return lathe(np.vstack([[(0, 0), (0.040, 0), (0.040, 0.002), (0.025, 0.005), (0.008, 0.010), (0.004, 0.015),
                             (0.004, stem_h * 0.95)], bowl[1:], [(bowl[-1, 0] - t * 0.5, stem_h + bowl_h + t * 0.3)],
                            inner[::-1][:-1], [(0.0, inner[0, 1])]]), segments=96)


@pytest.fixture
def tulip_glass():
    """A fresh tulip_glass_mesh() (callers move it)."""
    return tulip_glass_mesh()


def write_own_dishware_e(folder):
    """A fifth models/ folder of unseen dishware, sized from retail catalogues (rounded): a tulip-shaped red-wine
    glass (22 cm tall, 9.2 cm bowl narrowing to a 7.2 cm mouth, 8 cm foot), a square plate with a raised rim
    (21 x 21 cm, sharper corners than set C's), a small oval serving bowl (16 x 11 cm, 5.5 cm tall), an espresso
    cup on a flared foot wider than its body (6 cm rim, 6.6 cm foot, 6 cm tall, an ear handle), a ramekin (9 cm,
    4.5 cm tall, slightly flared), a tall latte mug (8.5 cm, 14 cm tall, a handle), a thick-walled stoneware
    bowl (15 cm, 7 cm tall, 8 mm walls, a foot ring), a coupe plate (26 cm, no rim: one continuous curve) and a
    handle-less tapered tea cup (7 cm rim, 8.5 cm tall: class cup, what cup-stacking takes). Meshes (mm) and diameters only. Returns {obj_id: (name, expected class)}."""
    import open3d as o3d

    from kitchenbot.world.dishware import _profile_closed, lathe, tube

    def vessel(outer, thickness, foot=None):
        return lathe(_profile_closed(np.array(outer, float), thickness, foot=foot), segments=96)

    def warp(mesh, radius_factor):  # each vertex moved radially by radius_factor(azimuth): a closed mesh stays closed
        V = np.asarray(mesh.vertices).copy()
        V[:, :2] *= radius_factor(np.arctan2(V[:, 1], V[:, 0]))[:, None]
        mesh.vertices = o3d.utility.Vector3dVector(V)
        return mesh

    def handle(mesh, r0, z0, reach, thickness):  # an ear handle on the +x side, centred at height z0
        s = np.linspace(-np.pi / 2 + 0.3, np.pi / 2 - 0.3, 24)
        return mesh + tube(np.stack([r0 + reach * np.cos(s), np.zeros_like(s), z0 + reach * np.sin(s)], 1),
                           thickness)

    wine = tulip_glass_mesh()
    square = warp(vessel([(0, 0.004), (0.070, 0.004), (0.074, 0.006), (0.080, 0.016), (0.086, 0.024),
                          (0.092, 0.027)], 0.0045, foot=(0.065, 0.004, 0.004)),
                  lambda a: (np.abs(np.cos(a)) ** 10 + np.abs(np.sin(a)) ** 10) ** (-1 / 10) * 1.14)
    oval = vessel([(0, 0.005), (0.032, 0.005), (0.036, 0.007), (0.050, 0.020), (0.060, 0.040), (0.064, 0.055)],
                  0.0045, foot=(0.031, 0.004, 0.005))
    oval = warp(oval, lambda a: 1.0 / np.sqrt((np.cos(a) / 1.25) ** 2 + (np.sin(a) / 0.86) ** 2))
    espresso = vessel([(0, 0.008), (0.033, 0.008), (0.026, 0.012), (0.024, 0.016)]
                      + [(0.024 + 0.006 * (z - 0.016) / 0.044, z) for z in np.linspace(0.022, 0.060, 5)], 0.0035,
                      foot=(0.033, 0.006, 0.008))
    espresso = handle(espresso, 0.027, 0.036, 0.017, 0.0045)
    ramekin = vessel([(0, 0), (0.040, 0), (0.043, 0.003)] + [(0.043 + 0.002 * z / 0.045, z)
                                                             for z in np.linspace(0.008, 0.045, 5)], 0.006)
    latte = vessel([(0, 0), (0.038, 0), (0.042, 0.003)] + [(0.042 + 0.001 * z / 0.14, z)
                                                           for z in np.linspace(0.010, 0.140, 9)], 0.004)
    latte = handle(latte, 0.039, 0.075, 0.038, 0.0065)
    stoneware = vessel([(0, 0.007), (0.040, 0.007), (0.044, 0.010), (0.060, 0.024), (0.070, 0.042), (0.074, 0.058),
                        (0.075, 0.070)], 0.008, foot=(0.039, 0.006, 0.007))
    # a handle-less stoneware tea cup (yunomi style: tapered, so it nests in its own kind; a 6 mm base)
    yunomi = vessel([(0, 0), (0.026, 0), (0.029, 0.003)] + [(0.029 + 0.006 * (z / 0.085), z)
                                                            for z in np.linspace(0.010, 0.085, 7)], 0.004)
    coupe = vessel([(0, 0.004), (0.055, 0.004)] + [(r, 0.004 + 0.022 * ((r - 0.055) / 0.075) ** 1.8)
                                                   for r in np.linspace(0.062, 0.130, 8)], 0.005,
                   foot=(0.054, 0.004, 0.004))
    specs = [("red_wine_glass", "glass", wine, (0.82, 0.88, 0.93)), ("square_rim_plate", "plate", square,
                                                                      (0.93, 0.93, 0.90)),
             ("oval_serving_bowl", "bowl", oval, (0.30, 0.40, 0.55)),
             ("footed_espresso_cup", "mug", espresso, (0.20, 0.20, 0.22)),
             ("ramekin_e", "bowl", ramekin, (0.85, 0.25, 0.20)), ("latte_mug", "mug", latte, (0.95, 0.95, 0.93)),
             ("stoneware_bowl", "bowl", stoneware, (0.55, 0.45, 0.35)), ("coupe_plate", "plate", coupe,
                                                                           (0.94, 0.92, 0.86)),
             ("yunomi_cup", "cup", yunomi, (0.45, 0.50, 0.40))]
    return _save_own_set(folder, specs)


@pytest.fixture(scope="session")
def own_dishware_e(tmp_path_factory):
    """(models_dir, {obj_id: (name, expected class)}) of the fifth set (`write_own_dishware_e`)."""
    folder = tmp_path_factory.mktemp("own_dishware_e") / "models"
    return folder, write_own_dishware_e(folder)


def write_own_dishware_f(folder):
    """A sixth models/ folder of unseen dishware, sized from retail catalogues (rounded): a deep pasta plate (23.5 cm,
    4.2 cm tall, a deep well in a narrow rim, a foot ring), a cereal bowl on a tall foot (14 cm, 7.5 cm tall), a tall
    latte glass with a belly (7.4 cm, 15.5 cm tall, a 1.2 cm solid base), a stemmed water glass (a goblet: 8.6 cm bowl,
    17 cm tall, a 7.6 cm disc foot), a mug with a squared handle (8.2 cm, 9.5 cm tall), a small side plate (16 cm,
    1.8 cm tall), a conical bowl (17 cm rim on a 6 cm foot, 7 cm tall), a double-walled cup (8 cm, 9.5 cm tall, 7 mm
    walls, its inner floor 2.5 cm up) and a matcha bowl (chawan: 11.5 cm, 7.5 cm tall, straight walls, a foot ring).
    Meshes (mm) and diameters only. Returns {obj_id: (name, expected class)}."""
    from kitchenbot.world.dishware import _profile_closed, lathe, tube

    def vessel(outer, thickness, foot=None):
        return lathe(_profile_closed(np.array(outer, float), thickness, foot=foot), segments=96)

    def rounded_corner_path(points, radius, per_corner=6):
        """A polyline through `points` (x, z in the xz plane) with each inner corner replaced by a quarter-ish arc."""
        P = np.asarray(points, float)
        out = [P[0]]
        for a, b, c in zip(P[:-2], P[1:-1], P[2:]):
            u, v = (a - b) / np.linalg.norm(a - b), (c - b) / np.linalg.norm(c - b)
            p0, p1 = b + radius * u, b + radius * v
            for s in np.linspace(0, 1, per_corner):  # a quadratic Bezier with b as its control point
                out.append((1 - s) ** 2 * p0 + 2 * (1 - s) * s * b + s ** 2 * p1)
        out.append(P[-1])
        xz = np.array(out)
        return np.stack([xz[:, 0], np.zeros(len(xz)), xz[:, 1]], 1)

    pasta = vessel([(0, 0.005), (0.065, 0.005), (0.070, 0.008), (0.085, 0.020), (0.095, 0.032), (0.103, 0.038),
                    (0.112, 0.040), (0.1175, 0.042)], 0.0045, foot=(0.064, 0.005, 0.005))
    cereal = vessel([(0, 0.015), (0.032, 0.015), (0.036, 0.018), (0.052, 0.030), (0.064, 0.048), (0.069, 0.064),
                     (0.070, 0.075)], 0.0042, foot=(0.030, 0.008, 0.015))  # a 1.5 cm tall foot
    latte = vessel([(0, 0.012), (0.030, 0.012)] + [(0.030 + 0.007 * np.sin(np.pi * (z - 0.012) / 0.16), z)
                                                   for z in np.linspace(0.018, 0.155, 9)],
                   0.0025, foot=(0.030, 0.028, 0.012))  # a heavy solid base, widest two thirds of the way up
    stem_h, t = 0.070, 0.0022
    zs = np.linspace(0, 1, 10)
    bowl = np.column_stack([0.005 + 0.038 * np.sin(zs * np.pi / 2) ** 0.6, stem_h + 0.100 * zs])
    inner = np.column_stack([np.maximum(bowl[:, 0] - t, 0.0), bowl[:, 1] + t * 0.5])
    inner[0] = (0.0, stem_h + 2 * t)
    goblet = lathe(np.vstack([[(0, 0), (0.038, 0), (0.038, 0.003), (0.020, 0.006), (0.006, 0.012), (0.005, 0.018),
                               (0.005, stem_h * 0.95)], bowl[1:], [(bowl[-1, 0] - t * 0.5, stem_h + 0.100 + t * 0.3)],
                              inner[::-1][:-1], [(0.0, inner[0, 1])]]), segments=96)
    mug = vessel([(0, 0), (0.037, 0), (0.040, 0.003)] + [(0.041, z) for z in np.linspace(0.010, 0.095, 7)], 0.0045)
    mug += tube(rounded_corner_path([(0.038, 0.022), (0.072, 0.022), (0.072, 0.080), (0.038, 0.080)], 0.009),
                0.006)  # a squared (D-shaped) handle, 3.4 cm out, 5.8 cm tall
    side = vessel([(0, 0.003), (0.050, 0.003), (0.054, 0.005), (0.066, 0.010), (0.074, 0.014), (0.080, 0.018)],
                  0.004, foot=(0.049, 0.004, 0.003))
    cone = vessel([(0, 0.006), (0.030, 0.006)] + [(0.032 + 0.053 * (z - 0.006) / 0.064, z)
                                                  for z in np.linspace(0.008, 0.070, 8)], 0.0045,
                  foot=(0.030, 0.005, 0.006))
    # double-walled: the outer wall from the standing base to the rim, the inner wall 7 mm in, its floor 2.5 cm up
    outer = [(0, 0), (0.031, 0), (0.033, 0.003)] + [(0.033 + 0.007 * z / 0.095, z) for z in np.linspace(0.010, 0.095, 6)]
    inner_wall = [(0.033 + 0.007 * z / 0.095 - 0.007, z) for z in np.linspace(0.092, 0.030, 6)] + [(0.024, 0.025),
                                                                                                  (0.0, 0.025)]
    rim = [(0.0365 + 0.0035 * np.cos(a), 0.095 + 0.0035 * np.sin(a)) for a in np.linspace(0.3, np.pi - 0.3, 5)]
    double = lathe(np.array(outer + rim + inner_wall, float), segments=96)
    chawan = vessel([(0, 0.008), (0.030, 0.008), (0.036, 0.012), (0.050, 0.022), (0.056, 0.040), (0.0575, 0.075)],
                    0.005, foot=(0.029, 0.006, 0.008))
    specs = [("deep_pasta_plate", "plate", pasta, (0.94, 0.93, 0.89)), ("footed_cereal_bowl", "bowl", cereal,
                                                                          (0.30, 0.50, 0.65)),
             ("belly_latte_glass", "glass", latte, (0.85, 0.90, 0.94)), ("water_goblet", "glass", goblet,
                                                                          (0.78, 0.86, 0.92)),
             ("square_handle_mug", "mug", mug, (0.80, 0.55, 0.25)), ("small_side_plate", "plate", side,
                                                                      (0.92, 0.92, 0.95)),
             ("conical_bowl_f", "bowl", cone, (0.20, 0.25, 0.30)), ("double_walled_cup", "cup", double,
                                                                     (0.90, 0.88, 0.84)),
             ("matcha_bowl", "bowl", chawan, (0.35, 0.40, 0.25))]
    return _save_own_set(folder, specs)


@pytest.fixture(scope="session")
def own_dishware_f(tmp_path_factory):
    """(models_dir, {obj_id: (name, expected class)}) of the sixth set (`write_own_dishware_f`)."""
    folder = tmp_path_factory.mktemp("own_dishware_f") / "models"
    return folder, write_own_dishware_f(folder)


@pytest.fixture
def run_pick_on_fake_arm():
    """Run a planned pick (approach, grasp-in, grasp, lift) on the simulated arm and gripper; it must hold the item
    and neither collide nor stop."""

    def run(cfg, world, pick) -> None:
        from kitchenbot.fakes.arm import FakeArm
        from kitchenbot.fakes.gripper import FakeGripper

        arm, grip = FakeArm(world, cfg.safety_limits()), FakeGripper(world)
        arm.connect()
        grip.connect()
        grip.open(pick.grasp.spec.opening)
        for t in (pick.approach, pick.grasp_in):
            arm.execute_trajectory(t.times, t.q)
        assert grip.grasp(0.5).holding
        arm.execute_trajectory(pick.lift.times, pick.lift.q)
        assert arm.log.collisions == 0 and arm.log.protective_stops == 0
        assert world.held_uid is not None

    return run
