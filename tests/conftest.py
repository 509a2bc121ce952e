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


@pytest.fixture(scope="session")
def own_dishware(tmp_path_factory):
    """(models_dir, {obj_id: (name, expected class)}) of dishware this project has never seen."""
    folder = tmp_path_factory.mktemp("own_dishware") / "models"
    return folder, write_own_dishware(folder)
