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

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget
from kitchenbot.transforms import rot_x, rot_y, trans
from kitchenbot.world.cell import Cell
from kitchenbot.world.gripper import DROP_HEIGHT
from kitchenbot.world.inventory import ObjectModel

CUP_CLASSES = ("cup", "glass", "bowl", "mug")


def rack_kind_for(cls: str) -> str:
    """Which rack kind takes an object class: 'plates' or 'cups'."""
    return "plates" if cls == "plate" else "cups"


def _half_extents(model: ObjectModel) -> np.ndarray:
    bb = model.mesh.get_axis_aligned_bounding_box()
    return (np.asarray(bb.get_max_bound()) - np.asarray(bb.get_min_bound())) / 2


def _footprint(model: ObjectModel, T_base_obj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """xy bounding box (base frame) of the model at a pose."""
    V = np.asarray(model.mesh.vertices)[:, :3] @ T_base_obj[:3, :3].T + T_base_obj[:3, 3]
    return V[:, :2].min(0), V[:, :2].max(0)


def slot_pose(model: ObjectModel, T_base_slot: np.ndarray, kind: str, drop: float = DROP_HEIGHT,
              inverted: bool = True) -> np.ndarray:
    """T_base_obj of `model` resting in a rack slot (plus `drop`): plates upright (axis along the rack's x),
    others upside down (or upright with ``inverted=False``)."""
    h = _half_extents(model)
    if kind == "plates":
        # upright: object z (the plate's axis) along base x; its radius sets the height above the floor
        return T_base_slot @ trans(0.0, 0.0, h[0] + drop) @ rot_y(np.pi / 2)
    if not inverted:
        return T_base_slot @ trans(0.0, 0.0, h[2] + drop)
    return T_base_slot @ trans(0.0, 0.0, h[2] + drop) @ rot_x(np.pi)


def _fit_inside(model: ObjectModel, T: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
    """T shifted in xy so the model's footprint lies within [lo, hi] (None when it is wider)."""
    flo, fhi = _footprint(model, T)
    if np.any(fhi - flo > hi - lo):
        return None
    shift = np.maximum(lo - flo, 0.0) + np.minimum(hi - fhi, 0.0)
    out = T.copy()
    out[:2, 3] += shift
    return out


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
    """Free/taken dishwasher rack slots for one task run. (The counter drop zone has no list of spots: the
    tasks find room there from what was already put down, `tasks/base.py` `_drop_zone_targets`.)"""

    def __init__(self, cell: Cell):
        self.cell = cell
        self.taken: set[str] = set()
        self.footprints: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # slot -> xy AABB of what was put there
        self.slots = {s.name: s for s in cell.slots}

    # ---- bookkeeping ---------------------------------------------------------------------------------
    def fill(self, name: str, T_base_obj: np.ndarray | None = None, model: ObjectModel | None = None) -> None:
        """Mark a rack slot taken; with the object's pose and model, also remember its footprint so that
        neighbouring slots it overlaps (a dinner plate spans two plate slots) are not offered."""
        if name not in self.slots:
            raise KeyError(f"SlotBook.fill: unknown slot {name!r}")
        self.taken.add(name)
        if T_base_obj is not None and model is not None:
            self.footprints[name] = _footprint(model, T_base_obj)

    def free(self, name: str) -> None:
        self.taken.discard(name)
        self.footprints.pop(name, None)

    def _overlaps(self, model: ObjectModel, T: np.ndarray, clearance: float = 0.005) -> bool:
        lo, hi = _footprint(model, T)
        for flo, fhi in self.footprints.values():
            if np.all(lo < fhi + clearance) and np.all(hi > flo - clearance):
                return True
        return False

    def free_slots(self, kind: str) -> list[str]:
        return [n for n, s in self.slots.items() if s.kind == kind and n not in self.taken]

    # ---- targets ---------------------------------------------------------------------------------------
    def targets_for(self, model: ObjectModel, inverted: bool = True) -> list[PlaceTarget]:
        """Every free rack slot that fits `model`'s class, in rack order: plates upright; cups, glasses, bowls
        and mugs upside down (``inverted=False``: upright, the fallback for an item whose grasp cannot turn
        it over, see README of planning/__init__). Objects are shifted to stay inside the rack's rails."""
        kind = rack_kind_for(model.cls)
        out = []
        for name in self.free_slots(kind):
            s = self.slots[name]
            rack = getattr(self.cell.spec.dishwasher, s.rack)
            lo = np.asarray(rack.origin_xy, float) + 0.006 + 0.003  # rails (6 mm wire) + clearance
            hi = np.asarray(rack.origin_xy, float) + np.asarray(rack.size_xy, float) - 0.009
            T = _fit_inside(model, slot_pose(model, s.T_base_slot, kind, inverted=inverted), lo, hi)
            if T is None or self._overlaps(model, T):
                continue
            sym = model.is_rotationally_symmetric
            # plates may face either way in their slot (flip_ok None: the planner decides so for slots)
            out.append(PlaceTarget(T, "slot", name, free_yaw=sym, support=f"rack_{s.rack}"))
        return out

    def target_for(self, model: ObjectModel) -> PlaceTarget | NoFreeSlot:
        t = self.targets_for(model)
        if not t:
            return NoFreeSlot(f"no free {rack_kind_for(model.cls)} slot for a {model.cls}", {"taken": sorted(self.taken)})
        return t[0]
