"""What kind of dishware a mesh is, from its shape alone: plate, bowl, cup, mug or glass.

The mesh is in its object frame with z along the item's axis, rim up (the BOP convention this project uses for
dishware; ``Inventory.load`` documents it). Measured on surface samples:

- the axis: through the centre of the rim ring (the top 4 mm of the mesh), so a handle does not shift it;
- the body's radius per 10-degree sector about the axis (the farthest surface point in it); the body diameter
  ``D`` is twice their median, the height ``h`` the mesh's z extent;
- a handle: off-axis mass, i.e. a few neighbouring sectors reach ``HANDLE_MIN_REACH`` past the body over only
  part of the height (a square plate's corners reach out over all of it);
- rotational symmetry about z: no handle and every sector's radius within ``ROUND_TOLERANCE`` of the median.

Classes, by the height-to-diameter ratio ``h / D`` (thresholds below; builtin dishware: plates 0.1, bowl 0.44,
cup 1.1, mug 1.15, glass 1.6):
``h/D < PLATE_MAX_RATIO`` plate; ``< BOWL_MAX_RATIO`` bowl; else mug with a handle, glass when
``h/D >= GLASS_MIN_RATIO``, cup otherwise. A config overrides the class per model in one line
(``inventory: {classes: {<obj_id>: mug}}``) where the shape misleads (a tall mug without a handle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

CLASSES = ("plate", "bowl", "cup", "mug", "glass")

PLATE_MAX_RATIO = 0.2  # h/D below this: a plate (a saucer ~0.15, a soup plate ~0.18)
BOWL_MAX_RATIO = 0.75  # h/D below this: a bowl (a deep bowl ~0.6); above: a cup, mug or glass
GLASS_MIN_RATIO = 1.3  # h/D from this on, with no handle: a glass (tumblers and highballs are tall and narrow)
HANDLE_MIN_REACH = 0.008  # m past the body's radius (and at least 15 % of it) that counts as a handle
HANDLE_MAX_SECTORS = 0.3  # a handle spans at most this fraction of the sectors around the axis ...
HANDLE_MAX_HEIGHT = 0.85  # ... and at most this fraction of the height
ROUND_TOLERANCE = 0.03  # sector radii within 3 % of the median: round (rotationally symmetric about z)
SECTORS = 36


@dataclass(frozen=True)
class ShapeClass:
    cls: str
    height: float  # m
    diameter: float  # m, the body's (without a handle)
    ratio: float  # height / diameter
    handle: bool
    round: bool  # rotationally symmetric about z
    axis_xy: tuple[float, float]  # where the axis crosses the xy plane, object frame

    def describe(self) -> str:
        return (f"{self.cls}: h {self.height * 1000:.0f} mm, body diameter {self.diameter * 1000:.0f} mm, "
                f"h/D {self.ratio:.2f}, {'a handle' if self.handle else 'no handle'}, "
                f"{'round' if self.round else 'not round'}")


def classify(mesh: o3d.geometry.TriangleMesh, samples: int = 20000) -> ShapeClass:
    """The dishware class of a closed mesh (metres, z = the item's axis, rim up), with the measures it rests on."""
    if len(mesh.triangles) == 0:
        raise ValueError("classify: the mesh has no triangles")
    o3d.utility.random.seed(3)  # deterministic sampling
    P = np.vstack([np.asarray(mesh.sample_points_uniformly(samples).points), np.asarray(mesh.vertices)])
    z_lo, z_hi = float(P[:, 2].min()), float(P[:, 2].max())
    h = z_hi - z_lo
    rim = P[P[:, 2] > z_hi - 0.004][:, :2]
    axis = (rim.max(axis=0) + rim.min(axis=0)) / 2
    d = P[:, :2] - axis
    r = np.linalg.norm(d, axis=1)
    sector = ((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi) * SECTORS).astype(int) % SECTORS
    r_max = np.zeros(SECTORS)
    np.maximum.at(r_max, sector, r)
    r_body = float(np.median(r_max))
    reach = max(HANDLE_MIN_REACH, 0.15 * r_body)
    out = r_max > r_body + reach
    handle = False
    if out.any() and out.mean() <= HANDLE_MAX_SECTORS:
        beyond = P[r > r_body + reach / 2]
        handle = (beyond[:, 2].max() - beyond[:, 2].min()) <= HANDLE_MAX_HEIGHT * h
    round_ = not handle and bool(np.all(np.abs(r_max - r_body) <= ROUND_TOLERANCE * r_body))
    diameter = 2 * r_body
    ratio = h / diameter if diameter > 0 else float("inf")
    if ratio < PLATE_MAX_RATIO:
        cls = "plate"
    elif ratio < BOWL_MAX_RATIO:
        cls = "bowl"
    elif handle:
        cls = "mug"
    elif ratio >= GLASS_MIN_RATIO:
        cls = "glass"
    else:
        cls = "cup"
    return ShapeClass(cls, h, diameter, ratio, bool(handle), round_, (float(axis[0]), float(axis[1])))
