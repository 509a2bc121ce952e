"""The object inventory: CAD models, symmetries and predefined grasps.

Two sources, one type:
- ``Inventory.builtin()``: the project's procedural dishware (perception/dishware.py) with generated grasps.
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

from kitchenbot.perception.dishware import BUILTIN_DISHES, build_mesh
from kitchenbot.transforms import check_rigid, make_T, rot_x, rot_y

GRIPPER_MAX_OPENING = 0.10  # m, Fin-Ray pads fully open
PAD_DEPTH = 0.035  # m, how far the pads reach past the TCP along the approach axis


class InventoryError(ValueError):
    """A model folder, mesh or grasps file is missing or malformed."""


@dataclass
class GraspSpec:
    name: str
    T_obj_tcp: np.ndarray
    opening: float
    width: float


@dataclass
class ObjectModel:
    obj_id: int
    name: str
    cls: str
    mesh: o3d.geometry.TriangleMesh  # metres, object frame
    diameter: float  # metres (BOP: max distance between vertices)
    symmetries_discrete: list[np.ndarray] = field(default_factory=list)  # 4x4, metres
    symmetries_continuous: list[dict] = field(default_factory=list)  # {"axis": [..], "offset": [.. m]}
    grasps: list[GraspSpec] = field(default_factory=list)
    colour: tuple[float, float, float] = (0.8, 0.8, 0.8)

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
            )
            model.grasps = generate_grasps(model, foot=spec.foot)
            models.append(model)
        return cls(models, "builtin")

    # ---- BOP models/ folders ------------------------------------------------------------------------------
    @classmethod
    def load(cls, models_dir: str | Path, grasps_file: str | Path | None = None) -> "Inventory":
        models_dir = Path(models_dir)
        info_path = models_dir / "models_info.json"
        if not info_path.is_file():
            raise InventoryError(f"{info_path}: missing; a BOP models/ folder needs models_info.json")
        try:
            info = json.loads(info_path.read_text())
        except json.JSONDecodeError as e:
            raise InventoryError(f"{info_path}: not valid JSON ({e})") from None
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
            models.append(
                ObjectModel(
                    obj_id=obj_id,
                    name=ex.get("name", f"obj_{obj_id:06d}"),
                    cls=ex.get("class", ex.get("name", f"obj_{obj_id:06d}")),
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
    try:
        data = json.loads(path.read_text())
    except OSError as e:
        raise InventoryError(f"{path}: cannot read the grasps file ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise InventoryError(f"{path}: not valid JSON ({e})") from None
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


# ---- grasp generation for the builtin dishware ------------------------------------------------------------
def _tcp_frame(approach: np.ndarray, closing: np.ndarray, position: np.ndarray) -> np.ndarray:
    z = approach / np.linalg.norm(approach)
    y = closing - z * (closing @ z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return make_T(np.stack([x, y, z], axis=1), position)


def pad_span(
    model: ObjectModel, T_obj_tcp: np.ndarray, half_length: float = 0.06, scene: o3d.t.geometry.RaycastingScene | None = None
) -> float | None:
    """Width the pads would close to: extent of the mesh along the closing axis through the TCP point.

    Casts rays from both sides along the closing axis at the TCP and a few points along the pad depth;
    returns None when the line misses the object.
    """
    if scene is None:
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(model.mesh))
    y, z, p = T_obj_tcp[:3, 1], T_obj_tcp[:3, 2], T_obj_tcp[:3, 3]
    widths = []
    for depth in (-0.005, 0.0, 0.005):
        c = p + z * depth
        rays = np.array([[*(c - y * half_length), *y], [*(c + y * half_length), *(-y)]], np.float32)
        t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        if np.all(np.isfinite(t)):
            widths.append(2 * half_length - t[0] - t[1])
    return float(max(widths)) if widths else None


# The planner's pad boxes (planning.collision.GripperGeometry), TCP frame: 26 mm wide (x), 16 mm thick (y),
# from the pad roots 70 mm behind the TCP to the tips 12 mm past it. Repeated here (perception does not import
# planning) for the check that a grasp's open pads do not cut into the item itself.
PAD_BOX_X = 0.013
PAD_BOX_THICKNESS = 0.016
PAD_BOX_Z = (-0.07, 0.012)


def _pads_clear(points: np.ndarray, T_obj_tcp: np.ndarray, opening: float, tol: float = 0.001) -> bool:
    """Whether the open pads (at `opening`) keep out of the item: no surface point deeper than `tol` inside
    either pad box. The planner lets the pads touch the target they grasp, so a predefined grasp whose pads
    would pass through the item's own wall (an inner pad sweeping through a lying cup's side) must not exist."""
    R = T_obj_tcp[:3, :3].astype(points.dtype)
    d = points - T_obj_tcp[:3, 3].astype(points.dtype)
    x = np.abs(d @ R[:, 0])
    near = x < PAD_BOX_X - tol
    d = d[near]
    z = d @ R[:, 2]
    d = d[(z > PAD_BOX_Z[0] + tol) & (z < PAD_BOX_Z[1] - tol)]
    y = np.abs(d @ R[:, 1])
    o = opening / 2
    return not bool(np.any((y > o + tol) & (y < o + PAD_BOX_THICKNESS - tol)))


# Rolls (degrees, about the closing axis) of the narrow plate rim pinch (see generate_grasps).
NARROW_ROLLS = (0, 45, -45)
# Pitches (degrees, about the pad width axis, leaning in from outside the ring) of the bowl's foot-ring pinch, and
# how far (m) such a pinch may back off along its approach to keep its open pads out of the body (generate_grasps).
FOOT_PITCHES = (10, 20)
FOOT_PITCH_BACK = (0.0, 0.001, 0.002, 0.003, 0.004)


def generate_grasps(model: ObjectModel, n_around: int = 12, foot: tuple[float, float, float] | None = None) -> list[GraspSpec]:
    """Predefined Fin-Ray grasps for a builtin item.

    - rim pinch (all items): approach from above the rim, pads straddling the wall, closing radially;
    - rolled rim pinches (cups, mugs, glasses, bowls): the same pinch with the approach turned about the
      closing axis by 30-60 degrees towards the rim's tangent, the inner pad entering through the mouth: from
      above when the item lies on its side or leans (the approach along the axis is then level);
    - side grasps (cups, mugs, glasses, bowls): approach perpendicular to the axis at three heights, closing
      across the body (from above across a lying body);
    - base grasps (cups, mugs, glasses): approach along +z, closing across the body just above its base (from
      above an upside-down item);
    - foot-ring pinch (items with a foot ring, bowls): approach along +z (from below the upright item, from
      above an upside-down one), one pad inside the ring, one outside, the tips short of the recessed bottom.
    Expected widths are measured on the mesh; grasps wider than the gripper, and grasps whose open pads would
    cut into the item (see `_pads_clear`), are dropped.
    """
    V = np.asarray(model.mesh.vertices)
    z_top = V[:, 2].max()
    z_bot = V[:, 2].min()
    # The body's axis passes through the centre of the rim ring (not the bounding-box centre: a mug's handle
    # shifts that off the axis).
    rim = V[V[:, 2] > z_top - 0.004][:, :2]
    axis_xy = (rim.max(axis=0) + rim.min(axis=0)) / 2
    r_rim = np.max(np.linalg.norm(rim - axis_xy, axis=1))
    axis = np.array([axis_xy[0], axis_xy[1], 0.0])
    vessel = model.cls in ("cup", "mug", "glass", "bowl")
    grasps: list[GraspSpec] = []
    bite = 0.012 if model.cls in ("plate",) else 0.015
    for k in range(n_around):
        a = 2 * np.pi * k / n_around
        radial = np.array([np.cos(a), np.sin(a), 0.0])
        pos = axis + radial * (r_rim - 0.004) + np.array([0, 0, z_top - bite])
        T = _tcp_frame(np.array([0, 0, -1.0]), radial, pos)
        grasps.append(("rim", k, T))
        if vessel:
            for roll in (30, 45, 60):
                for sgn in (1, -1):
                    grasps.append((f"rimroll{sgn * roll:+d}", k, T @ rot_y(np.radians(sgn * roll))))
        if model.cls == "plate":
            # A shallow, narrow pinch of the lip from outside, leaning in by 25/40 degrees (opened only 8 mm
            # per pad past the lip): the fingers stay above the plate's sloped well and close to the lip, so
            # they keep clear of a plate nested below (a vertical pinch's inner finger reaches it through the
            # well; a 45/60 degree pinch opened 15 mm per pad sweeps over the lower plate's rim).
            p_lip = axis + radial * (r_rim - 0.002) + np.array([0, 0, z_top - 0.006])
            for lean in (25, 40):
                grasps.append((f"rimlean{lean}", k,
                               _tcp_frame(np.array([0, 0, -1.0]), radial, p_lip) @ rot_x(np.radians(lean))))
        if model.cls == "plate":
            # A plate leaning against a basin wall (its upper lip touching the wall): the standard pinch (12 mm
            # bite, 15 mm slack per pad) puts the outer pad into the wall, and a pinch of the lip's side, where
            # there is room, comes in nearly level (along the plate's axis), which puts the wrist into the
            # opposite wall. So a narrow pinch too (8 mm bite, opened 8 mm per pad past the lip, as `rimlean`),
            # also rolled 45 degrees about its closing axis towards the rim's tangent: from above at a leaning
            # plate's side. The inner pad overlaps the sloped lip as much as the standard pinch's does.
            p_narrow = axis + radial * (r_rim - 0.004) + np.array([0, 0, z_top - 0.008])
            T_narrow = _tcp_frame(np.array([0, 0, -1.0]), radial, p_narrow)
            for roll in NARROW_ROLLS:
                grasps.append((f"rimnarrow{roll:+d}", k, T_narrow @ rot_y(np.radians(roll))))
        if model.cls in ("plate", "bowl"):
            # A plate or bowl lying on a flat floor leaves no room for a pad under a vertical pinch; tilt the
            # approach inwards (gripper outside the rim, one pad under the lip, one on top of it).
            edge = axis + radial * (r_rim - 0.003) + np.array([0, 0, z_top - 0.005])
            for tilt in (np.radians(45), np.radians(60)):
                grasps.append((f"rimtilt{int(round(np.degrees(tilt)))}", k, _tcp_frame(np.array([0, 0, -1.0]), radial, edge) @ rot_x(tilt)))
        if foot is not None:
            ro, w, h = foot
            # TCP 3 mm short of the ring's end: the pad tips (12 mm past the TCP) stop 1 mm short of the
            # recessed bottom of a 10 mm ring, and the pads hold the ring over its last 9 mm.
            p_foot = axis + radial * (ro - w / 2) + np.array([0, 0, z_bot - 0.003])
            T_foot = _tcp_frame(np.array([0, 0, 1.0]), radial, p_foot)
            grasps.append(("foot", k, T_foot))
            # A bowl lying on its side across a pile offers its foot ring tilted: the pinch along the bowl's
            # axis then comes in nearly level and puts the palm into a basin wall (a bowl lying at about 130
            # degrees). So the pinch also leans in from outside the ring, pitched about the ring's tangent
            # (the pad width axis) about the middle of the gripped length: the pads close across the ring
            # wall at a slant. Pitched further the outer pad's tip cuts into the body's underside; candidates
            # backed off along the approach (1 mm steps, see below) until the open pads clear the item.
            pivot = T_foot @ make_T(t=(0.0, 0.0, 0.003 + (0.012 - 0.003) / 2))
            for pitch in FOOT_PITCHES:
                T_p = pivot @ rot_x(np.radians(pitch)) @ make_T(t=(0.0, 0.0, -(0.003 + (0.012 - 0.003) / 2)))
                grasps.append((f"footpitch{pitch:+d}", k, [T_p @ make_T(t=(0.0, 0.0, -b)) for b in FOOT_PITCH_BACK]))
    if model.cls in ("cup", "mug", "glass"):
        # Across the body just above its base, approaching along +z: from above when the item stands upside
        # down (in the sink, or inverted in the rack), the pads down its sides to 27 mm below the base.
        for k in range(n_around):
            a = 2 * np.pi * k / n_around
            tangent = np.array([-np.sin(a), np.cos(a), 0.0])
            T = _tcp_frame(np.array([0, 0, 1.0]), tangent, axis + np.array([0, 0, z_bot + 0.015]))
            grasps.append(("base", k, T))
    if vessel:
        # 10 % (cups, mugs, glasses): across the base end, the pads' edge at the base. A glass lying on its side
        # with a neighbour along its body (a glass on a mug's handle, the mug 5 mm beside it)
        # leaves no room for a pad beside the body; tilted towards the base, this grasp comes in past the base
        # end, its pads above and below the body. It holds less of the body: ranked after the others
        # (planning.grasps.FALLBACK_GRASPS).
        fracs = (0.1, 0.3, 0.55, 0.8) if model.cls in ("cup", "mug", "glass") else (0.3, 0.55, 0.8)
        for frac in fracs:
            z = z_bot + frac * (z_top - z_bot)
            tag = "side" if frac == 0.55 else f"side{int(round(frac * 100))}"
            for k in range(n_around):
                a = 2 * np.pi * k / n_around
                radial = np.array([np.cos(a), np.sin(a), 0.0])
                tangent = np.array([-np.sin(a), np.cos(a), 0.0])
                T = _tcp_frame(-radial, tangent, axis + np.array([0, 0, z]))
                grasps.append((tag, k, T))
    out = []
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(model.mesh))
    surface = None
    if model.cls != "plate":
        o3d.utility.random.seed(2)
        # ~2 mm apart: a wall crossing a 16 x 26 mm pad leaves dozens of points inside it
        surface = np.vstack([np.asarray(model.mesh.sample_points_uniformly(30000).points), V]).astype(np.float32)
    for kind, k, Ts in grasps:
        # (a pitched foot pinch comes as its backed-off alternatives, nearest first: the first that fits is kept)
        for T in (Ts if isinstance(Ts, list) else [Ts]):
            w = pad_span(model, T, scene=scene)
            if w is None or w > GRIPPER_MAX_OPENING - 0.01 or w <= 0:
                continue
            if kind.startswith("footpitch") and abs(w - foot[1]) > 0.002:
                continue  # the slanted line across the ring leaves its wall (through the chamfered edge)
            slack = 0.016 if kind.startswith(("rimlean", "rimnarrow", "foot")) else 0.03
            opening = min(GRIPPER_MAX_OPENING, w + slack)
            if surface is not None and not _pads_clear(surface, T, opening):
                continue
            out.append(GraspSpec(f"{kind}_{k:02d}", T, opening=opening, width=w))
            break
    # A rim pinch that also takes in something else (the root of a mug's handle) is not a rim pinch.
    rim_w = [g.width for g in out if g.name.startswith("rim_")]
    if rim_w:
        limit = 2.0 * float(np.median(rim_w))
        out = [g for g in out if not (g.name.startswith(("rim_", "rimroll")) and g.width > limit)]
    return out
