"""Random sink scenes from a seed: 3-10 dishware items with clutter, stacks, leaning plates and occlusion.

Items are placed largest first (plates, then bowls, then cups), each in a random resting mode (upright,
upside down, on its side, leaning on a basin wall, stacked/nested on one of its kind), dropped onto what
is already there and tipped over their support until stable (fakes/placement.py). Two kitchen styles: stainless and white ceramic sinks.

`SceneOptions.surface="table"`: no basin to drop into. A flat table top (a board of a random colour, flush with
the counter, covering the basin's opening) carries the items: dishware among boxes, cans and bottles on a desk,
as public RGB-D sets (YCB-Video, LM-O) show it. Nothing leans on walls there, and piles may stand taller.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kitchenbot.fakes.placement import drop_onto, settle
from kitchenbot.fakes.world import SimWorld
from kitchenbot.world.cell import Cell, CellSpec
from kitchenbot.world.inventory import Inventory, ObjectModel
from kitchenbot.transforms import make_T, rot_x, rot_y, rot_z, trans
from scipy.spatial.transform import Rotation

MAX_TOP_Z = 0.08  # m above the counter: higher piles are re-drawn
TABLE_MAX_TOP_Z = 0.22  # on a table (no basin around them) items stand up to this high
SURFACES = ("sink", "table")
TABLE_COLOURS = [(0.62, 0.45, 0.30), (0.80, 0.70, 0.55), (0.30, 0.30, 0.32), (0.92, 0.92, 0.90)]


@dataclass
class SceneOptions:
    min_objects: int = 3
    max_objects: int = 10
    style: str = "random"  # stainless | ceramic | random
    stack_probability: float = 0.35
    lean_probability: float = 0.3
    # The wide variety (kitchenbot scenes generate --variety wide / --distractors N). Drawn from a second
    # random stream of the seed, so the defaults give exactly the scenes they always gave.
    distractors: int = 0  # non-inventory objects added per scene, drawn from `distractor_models`
    distractor_models: list[ObjectModel] = field(default_factory=list)
    fixtures: bool = False  # rounded corners, drain, faucet, floor grid (fakes/sink_fixtures.py)
    vary_sink: bool = False  # basin size and depth drawn per scene (the cell spec is then the scene's own)
    surface: str = "sink"  # sink | table: what the items rest on (module docstring)


_ORDER = {"plate": 0, "bowl": 1, "mug": 2, "cup": 2, "glass": 3}


def _resting_rotation(model: ObjectModel, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """A random resting orientation (4x4) and its name."""
    yaw = rot_z(rng.uniform(0, 2 * np.pi))
    tilt = rot_x(rng.normal(0, 0.03)) @ rot_y(rng.normal(0, 0.03))
    r = rng.random()
    if model.cls == "plate":
        return yaw @ tilt, "flat"
    if model.cls == "bowl":
        if r < 0.65:
            return yaw @ tilt, "upright"
        return yaw @ rot_x(np.pi) @ tilt, "upside_down"
    # cups, mugs, glasses
    if r < 0.45:
        return yaw @ tilt, "upright"
    if r < 0.7:
        return yaw @ rot_x(np.pi) @ tilt, "upside_down"
    return yaw @ rot_x(np.pi / 2) @ rot_z(rng.uniform(0, 2 * np.pi)), "on_side"


def _footprint_radius(model: ObjectModel, R: np.ndarray) -> float:
    V = np.asarray(model.mesh.vertices) @ R[:3, :3].T
    return float(np.max(np.linalg.norm(V[:, :2] - (V[:, :2].max(0) + V[:, :2].min(0)) / 2, axis=1)))


def _region(cell: Cell, surface: str) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners of where items go: the basin's inside, or on a table the same footprint at the
    table top (z 0)."""
    lo, hi = cell.sink_interior
    if surface == "table":
        lo = np.array([lo[0], lo[1], 0.0])
    return lo, hi


def table_top(cell: Cell, colour) -> "Fixture":
    """A 3 cm board covering the basin's opening and its rim, its top flush with the counter (z 0)."""
    import open3d as o3d

    from kitchenbot.fakes.world import Fixture

    s = cell.spec.sink
    c, h = np.array(s.centre_xy), np.array(s.inner_size_xy) / 2 + s.wall
    m = o3d.geometry.TriangleMesh.create_box(2 * h[0], 2 * h[1], 0.03)
    m.translate((c[0] - h[0], c[1] - h[1], -0.03))
    m.compute_vertex_normals()
    return Fixture("table_top", "table", m, tuple(float(x) for x in colour), 0.15)


def _sample_xy(region: tuple[np.ndarray, np.ndarray], radius: float, rng: np.random.Generator) -> np.ndarray | None:
    lo, hi = region
    lo_xy, hi_xy = lo[:2] + radius + 0.003, hi[:2] - radius - 0.003
    if np.any(lo_xy > hi_xy):
        return None
    return rng.uniform(lo_xy, hi_xy)


def _lean_pose(world: SimWorld, model: ObjectModel, rng: np.random.Generator) -> np.ndarray | None:
    """A plate standing on its rim, leaning against one of the basin's long walls."""
    lo, hi = world.cell.sink_interior
    side = rng.choice([-1, 1])  # lean on the wall at y = lo or y = hi
    tilt = rng.uniform(np.radians(55), np.radians(75))  # from horizontal
    x = rng.uniform(lo[0] + model.diameter / 2 + 0.01, hi[0] - model.diameter / 2 - 0.01)
    if lo[0] + model.diameter / 2 + 0.01 > hi[0] - model.diameter / 2 - 0.01:
        return None
    R = rot_x(side * tilt)  # rim tips towards the wall on `side`
    T = trans(x, (lo[1] + hi[1]) / 2, 0.3) @ R
    # Slide towards the wall until the nearest vertex touches it.
    V = np.asarray(model.mesh.vertices) @ T[:3, :3].T + T[:3, 3]
    if side > 0:
        T[1, 3] += hi[1] - V[:, 1].max() - 0.001
    else:
        T[1, 3] += lo[1] - V[:, 1].min() + 0.001
    return T


def generate_scene(
    seed: int,
    inventory: Inventory | None = None,
    cell_spec: CellSpec | None = None,
    options: SceneOptions | None = None,
    world_kwargs: dict | None = None,
) -> SimWorld:
    """A SimWorld with a random sink scene. Same seed, same scene."""
    rng = np.random.default_rng(seed)
    wide_rng = np.random.default_rng([seed, 1])  # the wide variety's own stream
    options = options or SceneOptions()
    inventory = inventory or Inventory.builtin()
    spec = cell_spec or CellSpec()
    style = options.style if options.style != "random" else str(rng.choice(["stainless", "ceramic"]))
    sink_update = {"style": style}
    if options.vary_sink:
        sink_update.update(inner_size_xy=(float(wide_rng.uniform(0.40, 0.56)), float(wide_rng.uniform(0.34, 0.44))),
                           depth=float(wide_rng.uniform(0.16, 0.22)))
    spec = spec.model_copy(update={"sink": spec.sink.model_copy(update=sink_update)})
    world = SimWorld(Cell(spec), inventory, seed=seed, **(world_kwargs or {}))
    if options.surface not in SURFACES:
        raise ValueError(f"SceneOptions.surface: expected one of {SURFACES}, got {options.surface!r}")
    table = options.surface == "table"
    region = _region(world.cell, options.surface)
    max_top = TABLE_MAX_TOP_Z if table else MAX_TOP_Z
    if table:  # drawn from its own stream: the sink scenes of a seed stay what they were
        world.add_fixture(table_top(world.cell, TABLE_COLOURS[int(np.random.default_rng([seed, 5]).integers(4))]))
    elif options.fixtures:
        from kitchenbot.fakes.sink_fixtures import random_fixtures

        for fx in random_fixtures(world.cell, wide_rng):
            world.add_fixture(fx)

    n = int(rng.integers(options.min_objects, options.max_objects + 1))
    models = list(inventory)
    picks: list[ObjectModel] = []
    while len(picks) < n:
        m = models[int(rng.integers(len(models)))]
        group = 1
        if rng.random() < options.stack_probability and m.cls in ("plate", "bowl", "cup", "glass"):
            group = int(rng.integers(2, 4))
        picks.extend([m] * min(group, n - len(picks)))
    picks.sort(key=lambda m: _ORDER.get(m.cls, 5))

    prev: tuple[ObjectModel, np.ndarray, str] | None = None
    for model in picks:
        for _attempt in range(8):
            stacked = prev is not None and prev[0] is model and prev[2] in ("flat", "upright", "upside_down") \
                and rng.random() < 0.8
            if stacked:
                base_T, mode = prev[1], prev[2]
                T = base_T.copy()
                # Stacks in a sink are messy: plates and bowls land off-centre (and then tip), cups nest.
                T[:2, 3] += rng.normal(0, 0.012 if model.cls in ("plate", "bowl") else 0.004, 2)
                T = T @ rot_z(rng.uniform(0, 2 * np.pi)) if model.is_rotationally_symmetric else T
                T[2, 3] = base_T[2, 3] + 0.25
            elif model.cls == "plate" and rng.random() < options.lean_probability and not table:
                T, mode = _lean_pose(world, model, rng), "leaning"
                if T is None:
                    continue
            else:
                R, mode = _resting_rotation(model, rng)
                xy = _sample_xy(region, _footprint_radius(model, R), rng)
                if xy is None:
                    continue
                T = make_T(R[:3, :3], (xy[0], xy[1], 0.3))
            uid = world.add_object(model, T)
            if mode == "leaning":
                T_rest = drop_onto(world, uid, T)  # posed against the wall already
            else:
                T_rest = settle(world, uid, T, keep_inside=region)
            V = np.asarray(model.mesh.vertices) @ T_rest[:3, :3].T + T_rest[:3, 3]
            lo, hi = region
            inside = np.all(V[:, :2] >= lo[:2] - 1e-3) and np.all(V[:, :2] <= hi[:2] + 1e-3)
            if V[:, 2].max() > max_top or not inside or V[:, 2].min() < lo[2] - 0.002:
                world.remove_object(uid)
                continue
            world.set_pose(uid, T_rest)
            prev = (model, T_rest, mode)
            break
    if options.distractors > 0:
        if not options.distractor_models:
            raise ValueError("SceneOptions.distractors > 0 needs distractor_models to draw from")
        _add_distractors(world, options, wide_rng, region, max_top)
    return world


def _add_distractors(world: SimWorld, options: SceneOptions, rng: np.random.Generator,
                     region: tuple[np.ndarray, np.ndarray], max_top: float) -> None:
    """Drop `options.distractors` non-inventory objects into `region` (the basin, or on the table), among and
    onto the dishware."""
    from kitchenbot.fakes.distractors import resting_rotation

    lo, hi = region
    for _ in range(options.distractors):
        model = options.distractor_models[int(rng.integers(len(options.distractor_models)))]
        for _attempt in range(8):
            R = resting_rotation(model, rng)
            xy = _sample_xy(region, _footprint_radius(model, R), rng)
            if xy is None:
                continue
            uid = world.add_object(model, make_T(R[:3, :3], (xy[0], xy[1], 0.3)))
            T_rest = settle(world, uid, world.objects[uid].T_base_obj, keep_inside=region)
            V = np.asarray(model.mesh.vertices) @ T_rest[:3, :3].T + T_rest[:3, 3]
            inside = np.all(V[:, :2] >= lo[:2] - 1e-3) and np.all(V[:, :2] <= hi[:2] + 1e-3)
            if V[:, 2].max() > max_top + 0.05 or not inside or V[:, 2].min() < lo[2] - 0.002:
                world.remove_object(uid)
                continue
            world.set_pose(uid, T_rest)
            break


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    return make_T(Rotation.random(random_state=int(rng.integers(2**31))).as_matrix())
