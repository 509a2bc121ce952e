"""Where a neighbour's part may be that its fit does not settle: a vessel symmetric but for a part (a mug's handle)
is fitted by its body, and its turn about the body's axis rests on the part alone. Among neighbours the part is
mostly hidden and the turn is a guess (a mug fitted 23.5 degrees turned: its real handle 1-3 cm from the model's,
the few map points seen of it within the 1.5 cm that the model explains, most of it never in the map), so neither
the model nor the map's points stand for the real part, and a lift beside it checked free space where the handle
was. The held item keeps clear of the part swept about the axis over the turns a fit may be off by
(`TURN_UNCERTAINTY` either way), as obstacle voxels (`Planner.scene` with an item held: lift, transport, place).

Only for perceived neighbours: the held item is what the pads close on, and an item the robot put down has a
known pose (it has no observed points). Whether the views saw the part does not tell a right turn from a wrong
one (the wrong fit's handle lies on other observed surface as often: 56 % against 71-72 % for two right fits in
one scene), so every such neighbour gets the sweep."""

from __future__ import annotations

import numpy as np

from ..world.inventory import ObjectModel
from .grasp_synthesis import find_handle

TURN_UNCERTAINTY = np.radians(30.0)  # rad either way: how far a fit may be turned about its axis (a traced one: 23.5)
TURN_STEPS = 9  # turns sampled over +-TURN_UNCERTAINTY (the part's points 7.5 degrees apart: < 1 cm at its reach)

_PARTS: dict[int, tuple] = {}  # id(mesh) -> (mesh, axis point (object frame), part points or None)


def off_axis_part(model: ObjectModel) -> tuple[np.ndarray, np.ndarray] | None:
    """(a point on the body's axis, the part's model points), object frame, for a model symmetric about z but for
    a part (planning.grasp_synthesis.find_handle); None for any other."""
    hit = _PARTS.get(id(model.mesh))
    if hit is None or hit[0] is not model.mesh:
        part, c = None, None
        if not model.is_rotationally_symmetric:
            V = np.asarray(model.points, float)
            c = np.median(V, axis=0)
            c[2] = 0.0
            r = np.linalg.norm(V[:, :2] - c[:2], axis=1)
            found = find_handle(V, c, float(np.quantile(r, 0.9)))
            if found is not None:
                part = found[1]
        hit = _PARTS[id(model.mesh)] = (model.mesh, c, part)
    return None if hit[2] is None else (hit[1], hit[2])


def swept_part(model: ObjectModel, T_base_obj: np.ndarray) -> np.ndarray:
    """The part's model points turned about the body's axis over +-TURN_UNCERTAINTY, base frame ((0, 3) for a
    model without such a part)."""
    found = off_axis_part(model)
    if found is None:
        return np.zeros((0, 3))
    c, Ph = found
    out = []
    for a in np.linspace(-TURN_UNCERTAINTY, TURN_UNCERTAINTY, TURN_STEPS):
        R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        out.append((Ph - c) @ R.T + c)
    P = np.vstack(out)
    return P @ T_base_obj[:3, :3].T + T_base_obj[:3, 3]


def unsettled_part_points(objects, models, own) -> np.ndarray:
    """Points (base frame) where the parts of the perceived neighbours in `objects` (ObjectPose-like: obj_id,
    T_base_obj, points) may be; `models`: obj_id -> ObjectModel; `own`: the objects left out (the held item)."""
    out = []
    for o in objects:
        if any(o is x for x in own) or o.points is None or len(o.points) == 0:
            continue
        m = models[o.obj_id]
        if off_axis_part(m) is None:
            continue
        out.append(swept_part(m, np.asarray(o.T_base_obj, float)))
    return np.vstack(out) if out else np.zeros((0, 3))
