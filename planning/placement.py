"""Where held objects go: dishwasher rack slots, a cup stack, the counter drop zone.

- Plates stand upright in the lower rack's slots (their face normal along the rack's slot pitch x axis);
  cups, glasses, bowls and mugs go upside down into the upper rack (water runs off).
- :class:`SlotBook` remembers which slots are taken as the task goes (fill on success, free on undo).
- Stacking: a cup on a cup of the same model; the placed cup's pose is the base cup's perceived pose raised
  along the base z axis by the nesting height, computed once per model from its mesh by ray casting (the
  lowest drop that keeps the upper copy's underside above the lower copy's top surface everywhere).
- Drop zone: objects upright on the counter on a grid of spots.

Every target is the object's ``T_base_obj`` a little (``drop_height``) above its resting pose, so the release
pose keeps clearance; the planner turns it into ``T_base_tcp = T_base_obj @ T_obj_tcp(grasp used)``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import open3d as o3d

from kitchenbot.perception.cell import Cell
from kitchenbot.perception.inventory import ObjectModel
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget
from kitchenbot.transforms import inv, make_T, rot_x, rot_y, rot_z, trans

DROP_HEIGHT = 0.006  # m above the resting pose at release
CUP_CLASSES = ("cup", "glass", "bowl", "mug")


def rack_kind_for(cls: str) -> str:
    """Which rack kind takes an object class: 'plates' or 'cups'."""
    return "plates" if cls == "plate" else "cups"


def _half_extents(model: ObjectModel) -> np.ndarray:
    bb = model.mesh.get_axis_aligned_bounding_box()
    return (np.asarray(bb.get_max_bound()) - np.asarray(bb.get_min_bound())) / 2


def slot_pose(model: ObjectModel, T_base_slot: np.ndarray, kind: str, drop: float = DROP_HEIGHT) -> np.ndarray:
    """T_base_obj of `model` resting in a rack slot (plus `drop`)."""
    h = _half_extents(model)
    if kind == "plates":
        # upright: object z (the plate's axis) along base x; its radius sets the height above the floor
        return T_base_slot @ trans(0.0, 0.0, h[0] + drop) @ rot_y(np.pi / 2)
    # upside down: object z points down; half height above the floor
    return T_base_slot @ trans(0.0, 0.0, h[2] + drop) @ rot_x(np.pi)


@lru_cache(maxsize=64)
def _nesting_height_cached(key: int, vertices: bytes, triangles: bytes, nv: int, nt: int) -> float:
    V = np.frombuffer(vertices, np.float64).reshape(nv, 3)
    F = np.frombuffer(triangles, np.int32).reshape(nt, 3)
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(V.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(F.astype(np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    lo, hi = V.min(0), V.max(0)
    g = 0.002
    xs = np.arange(lo[0] + g / 2, hi[0], g)
    ys = np.arange(lo[1] + g / 2, hi[1], g)
    X, Y = np.meshgrid(xs, ys)
    xy = np.column_stack([X.ravel(), Y.ravel()]).astype(np.float32)
    n = len(xy)
    up = np.hstack([xy, np.full((n, 1), lo[2] - 0.01, np.float32), np.tile([0, 0, 1], (n, 1)).astype(np.float32)])
    down = np.hstack([xy, np.full((n, 1), hi[2] + 0.01, np.float32), np.tile([0, 0, -1], (n, 1)).astype(np.float32)])
    t_up = scene.cast_rays(o3d.core.Tensor(up))["t_hit"].numpy()
    t_dn = scene.cast_rays(o3d.core.Tensor(down))["t_hit"].numpy()
    ok = np.isfinite(t_up) & np.isfinite(t_dn)
    underside = lo[2] - 0.01 + t_up[ok]
    top = hi[2] + 0.01 - t_dn[ok]
    return float(max(np.max(top - underside), 0.0))


def nesting_height(model: ObjectModel) -> float:
    """How far (m) a copy of `model` sits above another it is stacked on (same orientation)."""
    V = np.ascontiguousarray(np.asarray(model.mesh.vertices), np.float64)
    F = np.ascontiguousarray(np.asarray(model.mesh.triangles), np.int32)
    return _nesting_height_cached(model.obj_id, V.tobytes(), F.tobytes(), len(V), len(F))


def stack_target(model: ObjectModel, base: ObjectPose, drop: float = DROP_HEIGHT) -> PlaceTarget:
    """Put `model` onto the perceived `base` object (same model expected) by its nesting height."""
    if base.cls not in CUP_CLASSES:
        raise ValueError(f"stack_target: base object class {base.cls!r} is not stackable (expected one of {CUP_CLASSES})")
    h = nesting_height(model)
    T = trans(0.0, 0.0, h + drop) @ np.asarray(base.T_base_obj, float)
    return PlaceTarget(T, "stack", None, free_yaw=True, support=f"instance {base.instance_id}")


class SlotBook:
    """Free/taken rack slots and drop-zone spots for one task run."""

    def __init__(self, cell: Cell, drop_spacing: float = 0.12):
        self.cell = cell
        self.taken: set[str] = set()
        self.slots = {s.name: s for s in cell.slots}
        a = cell.spec.drop_zone
        xs = np.arange(a.origin_xy[0] + drop_spacing / 2, a.origin_xy[0] + a.size_xy[0], drop_spacing)
        ys = np.arange(a.origin_xy[1] + drop_spacing / 2, a.origin_xy[1] + a.size_xy[1], drop_spacing)
        self.drop_spots = {f"drop_{i}_{j}": make_T(t=(x, y, a.z)) for i, x in enumerate(xs) for j, y in enumerate(ys)}

    # ---- bookkeeping ---------------------------------------------------------------------------------
    def fill(self, name: str) -> None:
        if name not in self.slots and name not in self.drop_spots:
            raise KeyError(f"SlotBook.fill: unknown slot {name!r}")
        self.taken.add(name)

    def free(self, name: str) -> None:
        self.taken.discard(name)

    def free_slots(self, kind: str) -> list[str]:
        return [n for n, s in self.slots.items() if s.kind == kind and n not in self.taken]

    # ---- targets ---------------------------------------------------------------------------------------
    def targets_for(self, model: ObjectModel) -> list[PlaceTarget]:
        """Every free rack slot that fits `model`'s class, in rack order (plates upright, others inverted)."""
        kind = rack_kind_for(model.cls)
        out = []
        for name in self.free_slots(kind):
            s = self.slots[name]
            T = slot_pose(model, s.T_base_slot, kind)
            sym = model.is_rotationally_symmetric
            out.append(PlaceTarget(T, "slot", name, free_yaw=sym, support=f"rack_{s.rack}"))
            if kind == "plates":  # a plate may face either way in its slot
                out.append(PlaceTarget(s.T_base_slot @ rot_z(np.pi) @ inv(s.T_base_slot) @ T, "slot", name,
                                       free_yaw=sym, support=f"rack_{s.rack}"))
        return out

    def target_for(self, model: ObjectModel) -> PlaceTarget | NoFreeSlot:
        t = self.targets_for(model)
        if not t:
            return NoFreeSlot(f"no free {rack_kind_for(model.cls)} slot for a {model.cls}", {"taken": sorted(self.taken)})
        return t[0]

    def drop_targets(self, model: ObjectModel) -> list[PlaceTarget]:
        """Free spots in the counter drop zone, object upright."""
        h = _half_extents(model)
        out = []
        for name, T in self.drop_spots.items():
            if name in self.taken:
                continue
            out.append(PlaceTarget(T @ trans(0, 0, h[2] + DROP_HEIGHT), "drop", name, free_yaw=True, support="counter"))
        return out
