"""The object inventory: CAD models, symmetries and grasps (as data: planning.grasp_synthesis fills the grasps of
models that come without).

Two sources, one type:
- ``Inventory.builtin()``: the project's procedural dishware (world/dishware.py).
- ``Inventory.load(models_dir, grasps_file)``: any BOP ``models/`` folder (PLY in mm + ``models_info.json``),
  optionally with a grasps JSON (format below), so users can bring their own dishware.

Grasps JSON (metres)::

    {"units": "m",
     "objects": {"1": {"name": "dinner_plate", "class": "plate",
                       "grasps": [{"name": "rim_00", "T_obj_tcp": [[...4x4...]], "opening": 0.05, "width": 0.01}]}}}

TCP frame of the Fin-Ray gripper: z is the approach direction (out of the gripper, into the object), y is the
closing axis between the two finger pads, x = y x z. ``opening`` is the pre-grasp pad distance, ``width``
the expected pad distance when closed on the object.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import open3d as o3d

from kitchenbot.jsonfile import read_json
from kitchenbot.transforms import check_rigid, make_T
from kitchenbot.world.dishware import BUILTIN_DISHES, DishSpec, build_mesh
from kitchenbot.world.shape import CLASSES, classify


class InventoryError(ValueError):
    """A model folder, mesh or grasps file is missing or malformed."""


@dataclass
class GraspSpec:
    name: str
    T_obj_tcp: np.ndarray
    opening: float
    width: float


# A grasp's name says where it came from: ``kind_NN`` is copy NN of one grasp turned about a round item's axis (the
# same pinch, elsewhere round the rim), ``<grasp>_tilt+15`` is a grasp tilted about its closing axis by planning, and
# ``<grasp>_spin+15`` one turned about a round item's axis by planning (between the copies), ``<grasp>_narrow16``
# the grasp approached with its pads opened only 16 mm wider than the item (planning.grasps, NARROW_SLACKS;
# ``_narrow8``: 8 mm, the last resort).
TILT_TAG = "_tilt"
SPIN_TAG = "_spin"
NARROW_TAG = "_narrow"


def tilted_name(name: str, tilt: float) -> str:
    """The name of grasp `name` tilted by `tilt` (radians) about its closing axis."""
    return f"{name}{TILT_TAG}{np.degrees(tilt):+.0f}"


def spun_name(name: str, spin: float) -> str:
    """The name of grasp `name` turned by `spin` (radians) about its round item's axis."""
    return f"{name}{SPIN_TAG}{np.degrees(spin):+.0f}"


def narrowed_name(name: str, slack: float) -> str:
    """The name of grasp `name` approached with its pads open `slack` (m) wider than the item."""
    return f"{name}{NARROW_TAG}{slack * 1000:.0f}"


def grasp_base_name(name: str) -> str:
    """The grasp a tilted, spun or narrowed variant was made from (`name` itself when it is none of them)."""
    return name.split(TILT_TAG)[0].split(SPIN_TAG)[0].split(NARROW_TAG)[0]


def grasp_kind(name: str) -> str | None:
    """The kind of a turned copy ``kind_NN`` (tilt ignored); None for a grasp that is not one of several copies."""
    base = grasp_base_name(name)
    kind, _, copy = base.rpartition("_")
    return kind if kind and copy.isdigit() else None


@dataclass
class ObjectModel:
    obj_id: int
    name: str
    cls: str
    mesh: o3d.geometry.TriangleMesh  # metres, object frame
    diameter: float  # metres (BOP: max distance between vertices)
    symmetries_discrete: list[np.ndarray] = field(default_factory=list)  # 4x4, metres
    symmetries_continuous: list[dict] = field(default_factory=list)  # {"axis": [..], "offset": [.. m]}
    grasps: list[GraspSpec] = field(default_factory=list)  # filled by planning.grasp_synthesis when empty
    colour: tuple[float, float, float] = (0.8, 0.8, 0.8)
    dish: DishSpec | None = None  # the procedural design it was built from (builtin dishware), else None

    @property
    def extents(self) -> np.ndarray:
        return np.asarray(self.mesh.get_axis_aligned_bounding_box().get_extent())

    @cached_property
    def points(self) -> np.ndarray:
        """2048 surface points (metres, object frame), evenly spread (Poisson disk)."""
        if not len(self.mesh.triangles):
            return np.zeros((0, 3))
        o3d.utility.random.seed(1)  # deterministic sampling
        return np.asarray(self.mesh.sample_points_poisson_disk(2048).points)

    @cached_property
    def nest_pitch(self) -> float:
        """How far (m) along its z axis a copy of this item rests above another it is stacked on or nested in,
        same way up: the largest gap, over a 2 mm grid of vertical lines, between where a line leaves the top
        of the item and enters its underside (a plate on a plate ~6 mm, a cup in a cup ~4 cm). Two poses of
        one item closer than this along a shared axis would interpenetrate."""
        V = np.asarray(self.mesh.vertices, np.float32)
        if len(V) < 4 or not len(self.mesh.triangles):
            return 0.0
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(self.mesh))
        lo, hi = V.min(0), V.max(0)
        g = 0.002
        X, Y = np.meshgrid(np.arange(lo[0] + g / 2, hi[0], g), np.arange(lo[1] + g / 2, hi[1], g))
        n = X.size
        xy = np.column_stack([X.ravel(), Y.ravel()]).astype(np.float32)

        def cast(z0: float, dz: float) -> np.ndarray:
            rays = np.hstack([xy, np.full((n, 1), z0, np.float32), np.tile([0, 0, dz], (n, 1)).astype(np.float32)])
            return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()

        t_up, t_dn = cast(lo[2] - 0.01, 1.0), cast(hi[2] + 0.01, -1.0)
        ok = np.isfinite(t_up) & np.isfinite(t_dn)
        if not ok.any():
            return 0.0
        underside, top = lo[2] - 0.01 + t_up[ok], hi[2] + 0.01 - t_dn[ok]
        return float(max(np.max(top - underside), 0.0))

    @property
    def is_rotationally_symmetric(self) -> bool:
        return bool(self.symmetries_continuous)

    def symmetry_transforms(self, n_continuous: int = 36) -> list[np.ndarray]:
        """Discretised symmetry group (identity first), as used for symmetry-aware scoring and metrics."""
        out = [np.eye(4)]
        for S in self.symmetries_discrete:
            out.append(S)
        for sym in self.symmetries_continuous:
            axis = np.asarray(sym["axis"], float)
            axis /= np.linalg.norm(axis)
            off = np.asarray(sym.get("offset", [0, 0, 0]), float)
            from scipy.spatial.transform import Rotation

            for k in range(1, n_continuous):
                R = Rotation.from_rotvec(axis * 2 * np.pi * k / n_continuous).as_matrix()
                out.append(make_T(R, off - R @ off))
        return out


def _diameter(points: np.ndarray) -> float:
    """Max pairwise distance, via the convex hull vertices (exact, fast)."""
    from scipy.spatial import ConvexHull

    if len(points) < 4:
        return 0.0
    hull = points[ConvexHull(points).vertices]
    d = np.linalg.norm(hull[:, None] - hull[None], axis=-1)
    return float(d.max())


class Inventory:
    def __init__(self, models: list[ObjectModel], source: str = "builtin"):
        self.models: dict[int, ObjectModel] = {m.obj_id: m for m in models}
        self.source = source

    def __iter__(self):
        return iter(self.models.values())

    def __len__(self) -> int:
        return len(self.models)

    def __getitem__(self, obj_id: int) -> ObjectModel:
        try:
            return self.models[obj_id]
        except KeyError:
            raise KeyError(f"object id {obj_id} is not in the inventory ({sorted(self.models)})") from None

    def by_name(self, name: str) -> ObjectModel:
        for m in self.models.values():
            if m.name == name:
                return m
        raise KeyError(f"no model named {name!r} (have {[m.name for m in self.models.values()]})")

    @property
    def classes(self) -> list[str]:
        return sorted({m.cls for m in self.models.values()})

    def fingerprint(self) -> str:
        """Hash of the geometry and ids: the key of caches derived from this inventory."""
        h = hashlib.sha1()
        for m in sorted(self.models.values(), key=lambda m: m.obj_id):
            h.update(str(m.obj_id).encode())
            h.update(np.asarray(m.mesh.vertices, np.float32).tobytes())
        return h.hexdigest()[:16]

    # ---- the builtin dishware -----------------------------------------------------------------------------
    @classmethod
    def builtin(cls) -> "Inventory":
        models = []
        for i, spec in enumerate(BUILTIN_DISHES, start=1):
            mesh = build_mesh(spec)
            model = ObjectModel(
                obj_id=i,
                name=spec.name,
                cls=spec.cls,
                mesh=mesh,
                diameter=_diameter(np.asarray(mesh.vertices)),
                symmetries_continuous=[] if spec.handle else [{"axis": [0, 0, 1], "offset": [0, 0, 0]}],
                colour=spec.colour,
                dish=spec,
            )
            models.append(model)
        return cls(models, "builtin")

    # ---- BOP models/ folders ------------------------------------------------------------------------------
    @classmethod
    def load(cls, models_dir: str | Path, grasps_file: str | Path | None = None,
             classes: dict[int, str] | None = None) -> "Inventory":
        """A BOP ``models/`` folder: ``obj_XXXXXX.ply`` (mm) and ``models_info.json``, each mesh in its object frame
        with z along the item's axis, rim up (how it stands on a table). The class of each model: `classes`
        (obj_id -> class, the config's one-line override), else the grasps file's, else from the mesh's shape
        (world/shape.py). A round mesh whose models_info gives no symmetries gets the continuous one about z."""
        models_dir = Path(models_dir)
        for obj_id, c in (classes or {}).items():
            if c not in CLASSES:
                raise InventoryError(f"inventory.classes: object {obj_id}: unknown class {c!r} (expected one of "
                                     f"{', '.join(CLASSES)})")
        info_path = models_dir / "models_info.json"
        if not info_path.is_file():
            raise InventoryError(f"{info_path}: missing; a BOP models/ folder needs models_info.json")
        info = read_json(info_path, InventoryError, "models_info.json")
        extra = _read_grasps(Path(grasps_file)) if grasps_file else {}
        models = []
        for key, rec in sorted(info.items(), key=lambda kv: int(kv[0])):
            obj_id = int(key)
            ply = models_dir / f"obj_{obj_id:06d}.ply"
            mesh = _read_mesh(ply)
            mesh.scale(0.001, center=(0, 0, 0))  # BOP meshes are in mm
            mesh.compute_vertex_normals()
            if "diameter" not in rec:
                raise InventoryError(f"{info_path}: object {key} has no 'diameter'")
            sym_d = []
            for k, S in enumerate(rec.get("symmetries_discrete", [])):
                S = np.asarray(S, float).reshape(4, 4)
                S[:3, 3] *= 0.001
                sym_d.append(check_rigid(S, f"{info_path}: object {key} symmetries_discrete[{k}]"))
            sym_c = [
                {"axis": list(map(float, s["axis"])), "offset": [0.001 * float(v) for v in s.get("offset", [0, 0, 0])]}
                for s in rec.get("symmetries_continuous", [])
            ]
            ex = extra.get(obj_id, {})
            colour = _mesh_colour(mesh)
            shape = classify(mesh)
            if ("symmetries_continuous" not in rec and "symmetries_discrete" not in rec and shape.round
                    and np.hypot(*shape.axis_xy) < 0.001):
                sym_c = [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.0]}]
            models.append(
                ObjectModel(
                    obj_id=obj_id,
                    name=ex.get("name", f"obj_{obj_id:06d}"),
                    cls=(classes or {}).get(obj_id) or ex.get("class") or shape.cls,
                    mesh=mesh,
                    diameter=float(rec["diameter"]) * 0.001,
                    symmetries_discrete=sym_d,
                    symmetries_continuous=sym_c,
                    grasps=ex.get("grasps", []),
                    colour=colour,
                )
            )
        if not models:
            raise InventoryError(f"{info_path}: lists no models")
        return cls(models, str(models_dir))

    def save_bop(self, models_dir: str | Path, grasps_file: str | Path | None = None) -> None:
        """Write BOP models (PLY in mm with vertex normals/colours, models_info.json) and the grasps JSON."""
        models_dir = Path(models_dir)
        models_dir.mkdir(parents=True, exist_ok=True)
        info = {}
        for m in self:
            mesh_mm = o3d.geometry.TriangleMesh(m.mesh)
            mesh_mm.scale(1000.0, center=(0, 0, 0))
            mesh_mm.compute_vertex_normals()
            mesh_mm.paint_uniform_color(m.colour)
            o3d.io.write_triangle_mesh(str(models_dir / f"obj_{m.obj_id:06d}.ply"), mesh_mm, write_ascii=False)
            bb = mesh_mm.get_axis_aligned_bounding_box()
            lo, ext = bb.get_min_bound(), bb.get_extent()
            rec = {
                "diameter": m.diameter * 1000.0,
                "min_x": lo[0], "min_y": lo[1], "min_z": lo[2],
                "size_x": ext[0], "size_y": ext[1], "size_z": ext[2],
            }
            if m.symmetries_continuous:
                rec["symmetries_continuous"] = [
                    {"axis": s["axis"], "offset": [1000.0 * v for v in s["offset"]]} for s in m.symmetries_continuous
                ]
            if m.symmetries_discrete:
                out = []
                for S in m.symmetries_discrete:
                    S = S.copy()
                    S[:3, 3] *= 1000.0
                    out.append(S.reshape(-1).tolist())
                rec["symmetries_discrete"] = out
            info[str(m.obj_id)] = rec
        (models_dir / "models_info.json").write_text(json.dumps(info, indent=2))
        if grasps_file is not None:
            write_grasps(self, grasps_file)


def _read_mesh(ply: Path) -> o3d.geometry.TriangleMesh:
    if not ply.is_file():
        raise InventoryError(f"{ply}: missing model mesh (expected obj_XXXXXX.ply beside models_info.json)")
    mesh = o3d.io.read_triangle_mesh(str(ply))
    if len(mesh.triangles) == 0 or len(mesh.vertices) < 4:
        raise InventoryError(f"{ply}: not a readable triangle mesh (no faces)")
    V = np.asarray(mesh.vertices)
    if not np.all(np.isfinite(V)):
        raise InventoryError(f"{ply}: mesh has non-finite vertices")
    return mesh


def _mesh_colour(mesh: o3d.geometry.TriangleMesh) -> tuple[float, float, float]:
    if mesh.has_vertex_colors():
        return tuple(float(c) for c in np.asarray(mesh.vertex_colors).mean(axis=0))
    return (0.8, 0.8, 0.8)


def _read_grasps(path: Path) -> dict[int, dict]:
    data = read_json(path, InventoryError, "the grasps file")
    if data.get("units", "m") != "m":
        raise InventoryError(f"{path}: 'units' must be \"m\"")
    out: dict[int, dict] = {}
    for key, rec in data.get("objects", {}).items():
        grasps = []
        for k, g in enumerate(rec.get("grasps", [])):
            where = f"{path}: objects.{key}.grasps[{k}]"
            try:
                T = check_rigid(np.asarray(g["T_obj_tcp"], float), f"{where}.T_obj_tcp")
                grasps.append(GraspSpec(str(g.get("name", f"g{k}")), T, float(g["opening"]), float(g["width"])))
            except KeyError as e:
                raise InventoryError(f"{where}: missing key {e.args[0]!r}") from None
            except ValueError as e:
                raise InventoryError(str(e)) from None
        out[int(key)] = {"name": rec.get("name"), "class": rec.get("class"), "grasps": grasps}
        out[int(key)] = {k: v for k, v in out[int(key)].items() if v is not None}
    return out


def write_grasps(inv: Inventory, path: str | Path) -> None:
    data = {
        "units": "m",
        "objects": {
            str(m.obj_id): {
                "name": m.name,
                "class": m.cls,
                "grasps": [
                    {"name": g.name, "T_obj_tcp": np.round(g.T_obj_tcp, 6).tolist(), "opening": g.opening, "width": g.width}
                    for g in m.grasps
                ],
            }
            for m in inv
        },
    }
    Path(path).write_text(json.dumps(data, indent=1))
