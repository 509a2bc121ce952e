"""Things in a sink that are not dishware: a food box, a can, a bottle, a sponge, cutlery, food scraps.

Simple primitives (Open3D boxes, cylinders, spheres; a lathe for the bottle) with realistic sizes and
colours. They are SimWorld objects like the dishware (rendered, labelled, collided with, written to the
ground truth) but their models are not in the inventory: perception must give them no pose, and
evaluation counts a dishware pose on one as a false positive. Ids start at ``DISTRACTOR_ID0`` so they
never clash with inventory ids; class ``distractor``.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.world.dishware import lathe
from kitchenbot.world.inventory import ObjectModel, _diameter
from kitchenbot.transforms import rot_x, rot_y, rot_z

DISTRACTOR_ID0 = 101
DISTRACTOR_CLASS = "distractor"


def _box(x: float, y: float, z: float) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_box(x, y, z)
    m.translate((-x / 2, -y / 2, -z / 2))
    return m


def _cyl(r: float, h: float, res: int = 32) -> o3d.geometry.TriangleMesh:
    return o3d.geometry.TriangleMesh.create_cylinder(r, h, resolution=res)  # centred, axis z


def food_box(rng):
    return _box(rng.uniform(0.10, 0.16), rng.uniform(0.04, 0.07), rng.uniform(0.12, 0.20)), \
        tuple(rng.choice([(0.85, 0.2, 0.15), (0.95, 0.8, 0.2), (0.2, 0.4, 0.8)]))


def can(rng):
    return _cyl(rng.uniform(0.030, 0.042), rng.uniform(0.07, 0.12)), (0.75, 0.76, 0.78)


def bottle(rng):
    r, h = rng.uniform(0.028, 0.04), rng.uniform(0.18, 0.26)
    neck = rng.uniform(0.011, 0.015)
    prof = np.array([(0.0, 0.0), (r - 0.003, 0.0), (r, 0.004), (r, h * 0.62), (neck * 1.6, h * 0.78), (neck, h * 0.86),
                     (neck, h), (0.0, h)])
    return lathe(prof, 32), tuple(rng.choice([(0.2, 0.5, 0.3), (0.55, 0.35, 0.15), (0.8, 0.85, 0.9)]))


def sponge(rng):
    return _box(rng.uniform(0.08, 0.11), rng.uniform(0.055, 0.07), rng.uniform(0.02, 0.035)), \
        tuple(rng.choice([(0.95, 0.85, 0.2), (0.3, 0.7, 0.3), (0.95, 0.5, 0.6)]))


def cutlery(rng):
    """A knife, fork or spoon: a thin handle with a flat blade / tines / shallow bowl."""
    length = rng.uniform(0.16, 0.21)
    kind = rng.integers(3)
    handle = _box(length * 0.55, 0.012, 0.004)
    handle.translate((-length * 0.22, 0, 0))
    if kind == 0:  # knife blade
        head = _box(length * 0.45, 0.018, 0.0025)
    elif kind == 1:  # fork: four tines
        head = o3d.geometry.TriangleMesh()
        for k in range(4):
            t = _box(length * 0.4, 0.003, 0.003)
            t.translate((0, (k - 1.5) * 0.006, 0))
            head += t
    else:  # spoon: a flattened sphere
        head = o3d.geometry.TriangleMesh.create_sphere(0.02, resolution=10)
        head.scale(1.0, center=(0, 0, 0))
        head.vertices = o3d.utility.Vector3dVector(np.asarray(head.vertices) * np.array([1.0, 0.7, 0.2]))
    head.translate((length * 0.28, 0, 0))
    return handle + head, (0.8, 0.8, 0.82)


def food_scrap(rng):
    """A lumpy blob (a sphere with its vertices pushed in and out): peel, bread, leftovers."""
    m = o3d.geometry.TriangleMesh.create_sphere(rng.uniform(0.015, 0.03), resolution=8)
    V = np.asarray(m.vertices)
    V = V * (1 + rng.uniform(-0.25, 0.25, (len(V), 1))) * np.array([1.0, rng.uniform(0.6, 1.0), rng.uniform(0.4, 0.8)])
    m.vertices = o3d.utility.Vector3dVector(V)
    return m, tuple(rng.choice([(0.8, 0.6, 0.2), (0.45, 0.6, 0.2), (0.6, 0.3, 0.15)]))


KINDS = {"box": food_box, "can": can, "bottle": bottle, "sponge": sponge, "cutlery": cutlery, "scrap": food_scrap}


def make_distractor(obj_id: int, kind: str, rng: np.random.Generator) -> ObjectModel:
    if kind not in KINDS:
        raise ValueError(f"distractor kind: expected one of {sorted(KINDS)}, got {kind!r}")
    mesh, colour = KINDS[kind](rng)
    mesh.translate(-mesh.get_axis_aligned_bounding_box().get_center())
    mesh.compute_vertex_normals()
    return ObjectModel(obj_id=obj_id, name=f"{kind}_{obj_id}", cls=DISTRACTOR_CLASS, mesh=mesh,
                       diameter=_diameter(np.asarray(mesh.vertices)), colour=tuple(float(c) for c in colour))


def sample_distractors(rng: np.random.Generator, n: int, first_id: int = DISTRACTOR_ID0) -> list[ObjectModel]:
    """`n` distractors of random kinds, each its own model (ids from `first_id`)."""
    kinds = list(KINDS)
    return [make_distractor(first_id + k, kinds[int(rng.integers(len(kinds)))], rng) for k in range(n)]


def resting_rotation(model: ObjectModel, rng: np.random.Generator) -> np.ndarray:
    """A plausible way for a distractor to land: on one of its faces/sides, random yaw (settled afterwards)."""
    yaw = rot_z(rng.uniform(0, 2 * np.pi))
    face = [np.eye(4), rot_x(np.pi / 2), rot_y(np.pi / 2)][int(rng.integers(3))]
    return yaw @ face


def is_distractor(model: ObjectModel) -> bool:
    return model.cls == DISTRACTOR_CLASS
