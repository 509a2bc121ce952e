"""Poses the views contradict: an item posed where the camera saw another item's surface through it.

An opaque item hides what lies under it. When the points a view saw of item X lie well inside the body of item Y
as posed (inside its convex hull, more than INSIDE_DEPTH from its faces), the camera looked through the place Y is
said to fill: Y cannot be there as posed (a fit of a few of another item's points, a bowl on its side explained as
an upside-down bowl resting on the bowl beside it). Such a pose is not trusted to pin X: the item said to lie on
X is not what keeps X in the sink. What the views saw of Y stays in the map (its points become voxel obstacles
once no pose explains them), so a plan without that pose still avoids everything that was seen.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import ConvexHull

from kitchenbot.perception.types import ObjectPose
from kitchenbot.world.attitude import FACING_COS, up_cos
from kitchenbot.world.inventory import Inventory

INSIDE_DEPTH = 0.005  # m inside the hull's faces: past what a fitted pose's error puts a neighbour's surface in it
INSIDE_FRACTION = 0.05  # of X's seen points inside Y: more, and Y's pose is contradicted
INSIDE_MIN = 50  # points: fewer say nothing (a few stray points at a rim)

_hulls: dict[int, tuple[object, ConvexHull]] = {}  # id(model) -> (model, its hull): the model is kept so the id
# stays its own (two inventories in one process, e.g. the builtin one and a user's models, share object ids)


def _hull(inventory: Inventory, obj_id: int) -> ConvexHull:
    model = inventory[obj_id]
    hit = _hulls.get(id(model))
    if hit is None or hit[0] is not model:
        hit = _hulls[id(model)] = (model, ConvexHull(np.asarray(model.mesh.vertices, float)))
    return hit[1]


def points_inside(inventory: Inventory, pose: ObjectPose, points: np.ndarray, depth: float = INSIDE_DEPTH) -> int:
    """How many of `points` (base frame, (N, 3)) lie inside `pose`'s model hull, at least `depth` from its faces."""
    P = np.asarray(points, float).reshape(-1, 3)
    if not len(P) or pose.obj_id not in inventory.models:
        return 0
    T = np.asarray(pose.T_base_obj, float)
    local = (P - T[:3, 3]) @ T[:3, :3]  # into the model's frame
    eq = _hull(inventory, pose.obj_id).equations  # rows (n, d): n . x + d <= 0 inside
    return int(np.count_nonzero(np.all(local @ eq[:, :3].T + eq[:, 3] <= -depth, axis=1)))


def seen_through(inventory: Inventory, seen: ObjectPose, others: Sequence[ObjectPose]) -> list[ObjectPose]:
    """The poses among `others` that the points seen of `seen` contradict (see the module docstring). Only poses
    whose mouth faces up or down (within 60 degrees of vertical): the hull of a vessel lying on its side, or tilted
    mouth sideways, holds its open cavity, where a neighbour may really be seen."""
    P = np.asarray(seen.points, float).reshape(-1, 3)
    if len(P) < INSIDE_MIN:
        return []
    out = []
    for o in others:
        if o is seen or (seen.instance_id >= 0 and o.instance_id == seen.instance_id):
            continue
        if abs(up_cos(np.asarray(o.T_base_obj, float))) < FACING_COS:
            continue
        n = points_inside(inventory, o, P)
        if n >= INSIDE_MIN and n >= INSIDE_FRACTION * len(P):
            out.append(o)
    return out
