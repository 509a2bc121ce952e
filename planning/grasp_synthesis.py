"""Grasp synthesis for the Fin-Ray gripper: the grasps an inventory model offers, in its object frame.

The inventory (world/inventory.py) holds grasps as data; this module fills them for models that come without:
``ensure_grasps(inventory)`` (the Planner calls it) gives the builtin dishware its hand-designed grasp families
(``generate_grasps``) and any other mesh grasps synthesised from its surface (``synthesise_grasps``: antipodal
pairs, see below), cached on disk. ``pad_span`` measures the width the pads would close to on a mesh.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import open3d as o3d

from kitchenbot.transforms import make_T, rot_x, rot_y, rot_z
from kitchenbot.world.gripper import MAX_OPENING, PAD_ENVELOPE
from kitchenbot.world.inventory import GraspSpec, Inventory, ObjectModel


def ensure_grasps(inventory: Inventory, cache_dir: str | Path | None = None) -> Inventory:
    """Give every model without grasps its synthesised ones (in place; idempotent). Returns the inventory.

    The builtin dishware gets its hand-designed families (``generate_grasps``); any other mesh the antipodal
    synthesis (``synthesise_grasps``), cached in `cache_dir` under a hash of the mesh and the gripper."""
    for model in inventory:
        if model.grasps:
            continue
        if model.dish is not None:
            model.grasps = generate_grasps(model, foot=model.dish.foot)
        else:
            model.grasps = cached_synthesis(model, cache_dir)
    return inventory


def synthesis_key(model: ObjectModel) -> str:
    """Hash of the mesh, the gripper geometry and the synthesis parameters: the grasp cache's key."""
    from kitchenbot.world.gripper import FINGERS, PAD_DEPTH

    h = hashlib.sha1()
    h.update(np.asarray(model.mesh.vertices, np.float32).tobytes())
    h.update(np.asarray(model.mesh.triangles, np.int32).tobytes())
    h.update(repr((SYNTHESIS_VERSION, MAX_OPENING, PAD_DEPTH, PAD_ENVELOPE, FINGERS, FRICTION_COEFF, SURFACE_SAMPLES,
                   APPROACHES, CONTACT_DEPTHS, OPEN_SLACKS, WIDTH_TOLERANCE, CONTACT_TOLERANCE, MIN_CONTACT,
                   CENTRE_WEIGHT, MAX_GRASPS, PINCH_MAX_WIDTH, WRAP_CONE_DEG, ROUND_COPIES, PINCH_TILTS,
                   PINCH_TILT_AZIMUTHS, SLANTED_PINCH_CLASSES, model.cls in SLANTED_PINCH_CLASSES, MAX_RIM_SLANT,
                   MAX_RIM_LEVEL, MAX_LEVEL_ACROSS, LEVEL_ACROSS_MIN_TILT)).encode())
    return h.hexdigest()[:20]


def cached_synthesis(model: ObjectModel, cache_dir: str | Path | None) -> list[GraspSpec]:
    """``synthesise_grasps(model)``, read from / written to `cache_dir` (None: always synthesise)."""
    path = Path(cache_dir).expanduser() / f"grasps_{synthesis_key(model)}.json" if cache_dir else None
    if path is not None and path.is_file():
        try:
            recs = json.loads(path.read_text())
            return [GraspSpec(r["name"], np.asarray(r["T_obj_tcp"], float), float(r["opening"]), float(r["width"]))
                    for r in recs]
        except (OSError, ValueError, KeyError, TypeError):
            pass  # a damaged cache entry is synthesised again and rewritten
    grasps = synthesise_grasps(model)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps([{"name": g.name, "T_obj_tcp": g.T_obj_tcp.tolist(), "opening": g.opening,
                                    "width": g.width} for g in grasps]))
        tmp.replace(path)  # atomic: parallel benchmark workers may write the same entry
    return grasps


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
    T = np.asarray(T_obj_tcp, float)
    span = _pad_spans(scene, T[None, :3, 1], T[None, :3, 2], T[None, :3, 3], half_length)[0]
    return float(span) if np.isfinite(span) else None


def _pad_spans(scene: o3d.t.geometry.RaycastingScene, y: np.ndarray, z: np.ndarray, p: np.ndarray,
               half_length: float = 0.06) -> np.ndarray:
    """pad_span for n TCP poses at once (closing axes `y`, approach axes `z`, TCP points `p`: n x 3): the widest
    extent of the mesh along the closing axis through the TCP and 5 mm either side along the pads' depth; -inf
    where every line misses."""
    span = np.full(len(p), -np.inf)
    for depth in (-0.005, 0.0, 0.005):
        c = p + z * depth
        t0, _ = _cast(scene, c - y * half_length, y)
        t1, _ = _cast(scene, c + y * half_length, -y)
        span = np.fmax(span, np.where(np.isfinite(t0) & np.isfinite(t1), 2 * half_length - t0 - t1, -np.inf))
    return span


# The planner's pad boxes (world.gripper.PAD_ENVELOPE), for the check that a grasp's open pads do not cut into
# the item itself.
PAD_BOX_X = PAD_ENVELOPE.width / 2
PAD_BOX_THICKNESS = PAD_ENVELOPE.thickness
PAD_BOX_Z = (PAD_ENVELOPE.root, PAD_ENVELOPE.tip)


def pads_clear(points: np.ndarray, T_obj_tcp: np.ndarray, opening: float, tol: float = 0.001) -> bool:
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


# Rolls (degrees, about the closing axis) of the narrow plate rim pinch (see _narrow_lip_frames).
NARROW_ROLLS = (0, 45, -45)
NARROW_SLACK = 0.016  # m added to the lip's width when opening a narrow pinch (8 mm per pad, as `rimlean`)


def _narrow_lip_frames(axis: np.ndarray, radial: np.ndarray, r_rim: float, z_top: float) -> list:
    """[(kind, T_obj_tcp)] of a plate's narrow lip pinches at the rim azimuth `radial` (its rim ring of radius
    `r_rim` round `axis`, its top at `z_top`; the plate's axis is z).

    A plate leaning against a basin wall (its upper lip touching the wall): the standard pinch (12 mm bite, 15 mm
    slack per pad) puts the outer pad into the wall, and a pinch of the lip's side, where there is room, comes in
    nearly level (along the plate's axis), which puts the wrist into the opposite wall. So a narrow pinch (8 mm
    bite, opened NARROW_SLACK / 2 per pad past the lip, as `rimlean`), also rolled 45 degrees about its closing
    axis towards the rim's tangent: from above at a leaning plate's side. The inner pad overlaps the sloped lip
    as much as the standard pinch's does."""
    p_narrow = axis + radial * (r_rim - 0.004) + np.array([0, 0, z_top - 0.008])
    T_narrow = _tcp_frame(np.array([0, 0, -1.0]), radial, p_narrow)
    return [(f"rimnarrow{roll:+d}", T_narrow @ rot_y(np.radians(roll))) for roll in NARROW_ROLLS]


def narrow_lip_pinches(model: ObjectModel, n_around: int = 12) -> list[GraspSpec]:
    """A round plate's narrow lip pinches (`_narrow_lip_frames`) all round its rim, for a plate known only by its
    mesh (its axis z through the origin): the antipodal synthesis finds pinches of the lip too, but none this
    narrow and rolled, and without them a plate leaning against a basin wall has no grasp free of the wall and
    the counter (the rim ring and top are measured on the mesh as for the builtin plates). Each kept only where
    its pads close across the lip (`pad_span`, narrower than PINCH_MAX_WIDTH: a wide flat rim, a pasta plate's,
    is not pinched across by it); as the builtin plates' lip pinches, the inner
    pad rests on the sloped lip (the planner lets the pads touch the item they grasp). Fallbacks
    (planning.grasps.FALLBACK_GRASPS), as the builtin plates' are."""
    V = np.asarray(model.mesh.vertices)
    z_top = float(V[:, 2].max())
    rim = V[V[:, 2] > z_top - 0.004]
    r_rim = float(np.max(np.hypot(rim[:, 0], rim[:, 1])))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(model.mesh))
    out = []
    for k in range(n_around):
        a = 2 * np.pi * k / n_around
        radial = np.array([np.cos(a), np.sin(a), 0.0])
        for kind, T in _narrow_lip_frames(np.zeros(3), radial, r_rim, z_top):
            w = pad_span(model, T, scene=scene)
            if w is None or w <= 0 or w >= PINCH_MAX_WIDTH:
                continue  # closing on nothing, or along a rim that lies nearly flat (not across a lip)
            out.append(GraspSpec(f"{kind}_{k:02d}", T, opening=min(MAX_OPENING, w + NARROW_SLACK), width=w))
    return out
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
    cut into the item (see `pads_clear`), are dropped.
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
            grasps += [(name, k, T) for name, T in _narrow_lip_frames(axis, radial, r_rim, z_top)]
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
            pivot = T_foot @ make_T(t=(0.0, 0.0, 0.003 + (PAD_ENVELOPE.tip - 0.003) / 2))
            for pitch in FOOT_PITCHES:
                T_p = pivot @ rot_x(np.radians(pitch)) @ make_T(t=(0.0, 0.0, -(0.003 + (PAD_ENVELOPE.tip - 0.003) / 2)))
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
    if model.cls in ("cup", "mug", "glass"):
        grasps += _handle_grasps(V, axis, r_rim)
    out = []
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(model.mesh))
    if model.cls == "plate":
        grasps += _underside_pinches(model, scene, axis, r_rim, grasps)
    surface = None
    if model.cls != "plate":
        o3d.utility.random.seed(2)
        # ~2 mm apart: a wall crossing a 16 x 26 mm pad leaves dozens of points inside it
        surface = np.vstack([np.asarray(model.mesh.sample_points_uniformly(30000).points), V]).astype(np.float32)
    under_surface = None
    if model.cls == "plate":
        o3d.utility.random.seed(2)
        under_surface = np.vstack([np.asarray(model.mesh.sample_points_uniformly(30000).points), V]).astype(np.float32)
    for kind, k, Ts in grasps:
        # (a pitched foot pinch comes as its backed-off alternatives, nearest first: the first that fits is kept)
        for T in (Ts if isinstance(Ts, list) else [Ts]):
            w = pad_span(model, T, scene=scene)
            if w is not None and kind.startswith("handle"):
                # the handle's extent along the axis changes across the pad's width (the loop curves away from
                # the body): the conforming pads stop on the widest within 5 mm of their centre (as the simulated
                # ones do, fakes.gripper), so that is the width they close to
                spans = [pad_span(model, T @ make_T(t=(dx, 0.0, 0.0)), scene=scene) for dx in (-0.005, 0.0, 0.005)]
                w = max((v for v in spans if v is not None), default=None)
            if w is None or w > MAX_OPENING - 0.01 or w <= 0:
                continue
            if kind.startswith("footpitch") and abs(w - foot[1]) > 0.002:
                continue  # the slanted line across the ring leaves its wall (through the chamfered edge)
            slack = NARROW_SLACK if kind.startswith(("rimlean", "rimnarrow", "foot")) else 0.03
            opening = min(MAX_OPENING, w + slack)
            if surface is not None and not pads_clear(surface, T, opening):
                continue
            if kind.startswith(UNDERSIDE) and not pads_clear(under_surface, T, opening):
                continue  # mirrored, a pad would cut into the plate's well (checked on the mesh, not assumed)
            out.append(GraspSpec(f"{kind}_{k:02d}", T, opening=opening, width=w))
            break
    # A rim pinch that also takes in something else (the root of a mug's handle) is not a rim pinch.
    rim_w = [g.width for g in out if g.name.startswith("rim_")]
    if rim_w:
        limit = 2.0 * float(np.median(rim_w))
        out = [g for g in out if not (g.name.startswith(("rim_", "rimroll")) and g.width > limit)]
    return out


# A plate lying upside down (tipped over from leaning on a wall, a stack of them face down) offers its lip from
# its underside only: every rim pinch above approaches along -z of the plate, so upside down they all come from
# below and the plate had no grasp at all. A plate is a thin sloped band at its lip, pinched the same from either
# face, so the lip pinches that lean in from outside (`rimtilt`, `rimlean`) are mirrored through the lip's
# mid-surface: the gripper outside the rim, one pad on the underside, the other under the (now lower) edge. Each
# is kept only where its pads close across the lip (`pad_span`) and the open pads keep out of the plate's mesh
# (`pads_clear`: the reflected band slopes the other way, so that is checked, not assumed). Fallbacks
# (planning.grasps.FALLBACK_GRASPS): an upright plate's grasps are unchanged, and these come from below for it.
UNDERSIDE = "rimunder"
UNDERSIDE_FROM = ("rimtilt", "rimlean")


def _underside_pinches(model: ObjectModel, scene, axis: np.ndarray, r_rim: float, grasps: list) -> list:
    """The plate's lip pinches from its underside: `UNDERSIDE_FROM` grasps reflected through the lip's
    mid-surface (the plane half-way between its top and its underside 4 mm in from the edge, along the top's
    normal there: the band maps onto itself), as (kind, k, T) rows like `grasps`'."""
    out = []
    for kind, k, T in grasps:
        if not kind.startswith(UNDERSIDE_FROM) or isinstance(T, list):
            continue
        radial = np.asarray(T[:3, 3], float) - axis
        radial[2] = 0.0
        radial /= np.linalg.norm(radial)
        q = axis + radial * (r_rim - 0.004)
        rays = np.array([[q[0], q[1], 1.0, 0.0, 0.0, -1.0], [q[0], q[1], -1.0, 0.0, 0.0, 1.0]], np.float32)
        ans = scene.cast_rays(o3d.core.Tensor(rays))
        t, n = ans["t_hit"].numpy().astype(float), ans["primitive_normals"].numpy().astype(float)
        if not np.all(np.isfinite(t)):
            continue
        c = np.array([q[0], q[1], ((1.0 - t[0]) + (-1.0 + t[1])) / 2])
        nz = n[0] / np.linalg.norm(n[0])
        H = np.eye(3) - 2.0 * np.outer(nz, nz)
        M = np.eye(4)
        # reflect the frame (approach and closing axes), then flip its pad-width axis so it stays right-handed
        M[:3, :3] = H @ T[:3, :3] @ np.diag([-1.0, 1.0, 1.0])
        M[:3, 3] = T[:3, 3] - 2.0 * ((T[:3, 3] - c) @ nz) * nz
        out.append((f"{UNDERSIDE}{kind[len('rim'):]}", k, M))
    return out


# A handle: mesh beyond the body's radius by more than HANDLE_MARGIN, all within HANDLE_HALF_WIDTH of one
# half-plane through the axis (a lump on one side, not a flange or a flared foot all around).
HANDLE_MARGIN = 0.003
HANDLE_HALF_WIDTH = 0.015
HANDLE_MIN_REACH = 0.010  # m beyond the body: a smaller lump is not a handle a pad can close on
HANDLE_PAD_GAP = (0.002, 0.006)  # m between the body and the pads' inner edge


def find_handle(V: np.ndarray, axis: np.ndarray, r_body: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The handle of a vessel found by shape (vertices `V`, item frame, z the body's axis through `axis`, the body's
    widest radius `r_body`): (its outward direction, level; its points), or None when there is none."""
    d = V[:, :2] - axis[:2]
    r = np.linalg.norm(d, axis=1)
    out = r > r_body + HANDLE_MARGIN
    if np.count_nonzero(out) < 10:
        return None
    h = d[out].mean(axis=0)
    if np.linalg.norm(h) < 1e-6:
        return None
    h = np.array([*(h / np.linalg.norm(h)), 0.0])
    side = np.cross([0.0, 0.0, 1.0], h)
    P = V[out]
    if np.abs((P[:, :2] - axis[:2]) @ side[:2]).max() > HANDLE_HALF_WIDTH or ((P[:, :2] - axis[:2]) @ h[:2]).min() < 0:
        return None
    if r[out].max() < r_body + HANDLE_MIN_REACH:
        return None
    return h, P


def _handle_grasps(V: np.ndarray, axis: np.ndarray, r_body: float) -> list:
    """Grasps of a handle (cups, mugs, glasses that have one, `find_handle`): approaching across the handle's plane
    (from either side), closing along the body's axis, the pads' inner edge just outside the body: the pads straddle
    the handle and close on its two roots. Lying on its side with the handle part-way up, a mug leaves no grasp
    across its body clear of the handle (a pad lands on it, or, turned far enough to clear it, the lower pad meets
    the floor); this one comes in across the handle's plane, that is from above, tilted by the handle's angle
    above level."""
    found = find_handle(V, axis, r_body)
    if found is None:
        return []
    h, P = found
    side = np.cross([0.0, 0.0, 1.0], h)
    mid_side = float(np.median((P[:, :2] - axis[:2]) @ side[:2]))
    z_mid = (P[:, 2].max() + P[:, 2].min()) / 2
    out = []
    for gap in HANDLE_PAD_GAP:
        pos = axis + h * (r_body + gap + PAD_ENVELOPE.width / 2) + side * mid_side + np.array([0.0, 0.0, z_mid])
        for sgn in (1, -1):
            T = _tcp_frame(-sgn * side, np.array([0.0, 0.0, 1.0]), pos)
            out.append((f"handle{sgn:+d}", int(round(gap * 1000)), T))
    return out


# ---- grasps synthesised from a mesh (any dishware: models that come without grasps) --------------------------
# Antipodal pairs (Nguyen 1988; the ray-casting form of Dex-Net / GPD): from surface samples, a ray into the
# material along the inward normal finds the points where the line leaves it; a pair (sample, exit) whose exit
# normal lies within the friction cone of the closing axis can be squeezed between two pads. Each pair gets
# approach directions all around its closing axis; a candidate is kept when the open pads and the palm come in
# clear of the item, the pads close on that pair first, and enough of each pad face touches. Written here
# because no maintained library synthesises grasps for a given two-pad gripper geometry on CPU (GPD and Dex-Net
# are unmaintained and need their own builds); Open3D does the sampling and ray casting.
FRICTION_COEFF = 0.5  # silicone pads on glazed ceramic or glass: friction cone half angle atan(0.5) = 27 deg
# A Fin-Ray finger wraps around a thin wall it pinches (a rim, a plate's lip): the far normal of a pair narrower than
# PINCH_MAX_WIDTH may lie up to this far off the closing axis (the near one is on it by construction). Without
# it a plate's lip (sloped ~20 degrees) offers no pinch from above, which is how a plate lying flat is taken.
WRAP_CONE_DEG = 70.0
SURFACE_SAMPLES = 1000  # Poisson-disk surface samples (about 5 mm apart on a mug)
APPROACHES = 8  # approach directions around each closing axis (45 degrees apart)
# m: the pair lies this far behind the TCP along the approach: deep in the pads, or near their tips (where the
# tips must stop short of a surface beyond the pair: a pinch of a bowl's foot ring short of its recessed bottom)
CONTACT_DEPTHS = (0.004, -0.006)
OPEN_SLACKS = (0.03, 0.016)  # m added to the width when opening (both pads), widest that keeps the pads clear
WIDTH_TOLERANCE = 0.003  # m: the pads must close on the pair, not on something else first
CONTACT_TOLERANCE = 0.003  # m: a pad point this close to the first contact touches (the Fin-Ray wraps around)
MIN_CONTACT = 0.1  # fraction of each pad face's sample points that must touch
CENTRE_WEIGHT = 0.5  # score = contact fraction - CENTRE_WEIGHT * (closing line to centroid) / diameter
MAX_GRASPS = 160
ROUND_COPIES = 12  # a round item's grasps are chosen at one azimuth and repeated every 30 degrees
PINCH_MAX_WIDTH = 0.02  # m: narrower pairs pinch one wall (a rim), wider ones grip across the body
MIN_SPAN = 0.002  # m: a Fin-Ray that closes to less than this along the line through the TCP has closed on a
# sliver of the item (a lip the line only grazes): its pads meet, nothing is held (the simulated gripper counts a
# stall below 2 mm as closed on nothing)
# A Fin-Ray pinch of a thin wall need not close along the wall's normal: pads closing at a slant across a plate's
# flat rim (one pad on it, one under its edge) wrap onto both faces. Pinch pairs are therefore also sought along
# the inward normal turned by each of these angles (degrees, within WRAP_CONE_DEG), towards PINCH_TILT_AZIMUTHS
# directions around it; that is where the approaches tilted in from above come from on a wall lying nearly flat
# (a pasta plate's wide rim, a saucer's), whose straight pinches close nearly vertically and so are approached
# level only (the wrist then meets the basin's walls).
PINCH_TILTS = (45.0,)
# Plates (classes whose walls lie nearly flat) get them among their standard grasps: lying flat, a saucer's straight
# pinches are all approached level and none is collision-free on the sink floor, the slanted ones are what takes it.
# On a vessel's steep walls the straight pinches come from above already, and slanted ones mixed in took places in
# the spread (13 per round item) from those (a conical bowl lost pinches it was taken by, development seed of
# sink-to-dishwasher: 2/5 placed instead of 4/5). A vessel lying on its side is different: the top of its rim is a
# wall lying flat too, whose straight pinches close vertically and so come in level (into the basin's walls, or
# beside the body into what it lies in: a tumbler lying in a bowl). So vessels get slanted pinches as well, spread
# on their own after every straight grasp (which stay exactly as before) and named as fallbacks
# (planning.grasps.FALLBACK_GRASPS): tried only when fewer straight grasps are feasible than a pick checks.
SLANTED_PINCH_CLASSES = ("plate",)
PINCH_TILT_AZIMUTHS = 4
SLANTED_PINCH = "slant"  # name prefix of the slanted pinches among a plate's standard grasps
RIM_SLANT = "rimslant"  # name prefix of a vessel's slanted pinches (fallbacks)
MAX_RIM_SLANT = MAX_GRASPS // 2  # a vessel's slanted pinches kept, on top of its MAX_GRASPS straight ones
RIM_LEVEL = "rimlevel"  # name prefix of a vessel's level pinches (fallbacks)
MAX_RIM_LEVEL = 36  # a vessel's level pinches kept, on top of the others
# A vessel's grips across its body closing level from a sloped wall (_level_across_pairs): fallbacks (named
# LEVEL_ACROSS, planning.grasps.FALLBACK_GRASPS), up to MAX_LEVEL_ACROSS kept on top of the others, from near normals
# tilted more than LEVEL_ACROSS_MIN_TILT degrees off level; as wide as the straight grips may be (1 cm under the
# pads' full opening).
LEVEL_ACROSS = "acrosslevel"
MAX_LEVEL_ACROSS = 36
LEVEL_ACROSS_MIN_TILT = 5.0
SYNTHESIS_VERSION = 16  # part of the cache key: bump when the method changes


def _cast(scene: o3d.t.geometry.RaycastingScene, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rays = np.hstack([origins, dirs]).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    return ans["t_hit"].numpy().astype(float), ans["primitive_normals"].numpy().astype(float)


def _local_rays(R: np.ndarray, t: np.ndarray, grid: np.ndarray, y_shift: np.ndarray, direction: np.ndarray):
    """Rays from `grid` points (TCP frame, k x 3) shifted by `y_shift` (n,) along y, in `direction` (TCP frame),
    for n TCP poses (R: n x 3 x 3, t: n x 3); origins and directions in the object frame, (n * k) x 3."""
    O = t[:, None, :] + np.einsum("nij,kj->nki", R, grid) + R[:, None, :, 1] * y_shift[:, None, None]
    D = np.broadcast_to((R @ direction)[:, None, :], O.shape)
    return O.reshape(-1, 3), D.reshape(-1, 3)


def _antipodal_pairs(scene, P: np.ndarray, N: np.ndarray, max_width: float, D: np.ndarray | None = None,
                     min_width: float = 0.001) -> tuple[np.ndarray, np.ndarray]:
    """(centres, closing axes) of pairs (sample, a point where the inward line leaves the material) whose far
    normal lies within the friction cone: the closing axis runs from the sample inwards, along the inward normal
    or along `D` (unit rows; directions within the friction cone of each sample's inward normal)."""
    cos_cone, cos_wrap = np.cos(np.arctan(FRICTION_COEFF)), np.cos(np.radians(WRAP_CONE_DEG))
    D = -N if D is None else D
    centres, axes = [], []
    origin, travelled = P - N * 1e-4, np.zeros(len(P))
    alive = np.ones(len(P), bool)
    for hit in range(4):  # exits are the 1st and 3rd hits (wall, then across a cavity and the far wall)
        t, n_hit = _cast(scene, origin[alive], D[alive])
        idx = np.flatnonzero(alive)
        ok = np.isfinite(t)
        travelled[idx[ok]] += t[ok]
        alive[idx[~ok]] = False
        idx, t, n_hit = idx[ok], t[ok], n_hit[ok]
        if hit % 2 == 0:
            w = travelled[idx]
            cos_far = np.einsum("ij,ij->i", n_hit, D[idx])
            good = (w <= max_width) & (w > min_width) & ((cos_far >= cos_cone) | ((w < PINCH_MAX_WIDTH) & (cos_far >= cos_wrap)))
            centres.append(P[idx[good]] + D[idx[good]] * (w[good] / 2)[:, None])
            axes.append(D[idx[good]] * w[good][:, None])  # closing axis scaled by the width
        origin[idx] = origin[idx] + D[idx] * (t + 1e-4)[:, None]
        travelled[idx] += 1e-4
        alive[idx[travelled[idx] > max_width]] = False
        if not alive.any():
            break
    return np.vstack(centres), np.vstack(axes)


def _slanted_pinch_pairs(scene, P: np.ndarray, N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centres, closing axes) of pinches of one thin wall at a slant: from each sample along its inward normal
    turned by PINCH_TILTS towards PINCH_TILT_AZIMUTHS directions, to where the line leaves the wall, narrower than
    PINCH_MAX_WIDTH, the far normal within WRAP_CONE_DEG of the closing axis (the near one is, by the tilt). Only
    from samples on a thin wall (thinner than PINCH_MAX_WIDTH along the normal): a block's edge is no wall."""
    thick, _ = _cast(scene, P - N * 1e-4, -N)
    thin = np.isfinite(thick) & (thick < PINCH_MAX_WIDTH)
    P, N = P[thin], N[thin]
    ref = np.where(np.abs(N[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(N, ref)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(N, u)
    cos_wrap = np.cos(np.radians(WRAP_CONE_DEG))
    centres, axes = [], []
    for tilt in np.radians(PINCH_TILTS):
        for phi in 2 * np.pi * np.arange(PINCH_TILT_AZIMUTHS) / PINCH_TILT_AZIMUTHS:
            d = -N * np.cos(tilt) + (np.cos(phi) * u + np.sin(phi) * v) * np.sin(tilt)
            t, n_hit = _cast(scene, P - N * 1e-4, d)
            ok = np.isfinite(t)
            w = np.where(ok, t + 1e-4, np.inf)
            good = ok & (w > 0.001) & (w < PINCH_MAX_WIDTH) & (np.einsum("ij,ij->i", n_hit, d) >= cos_wrap)
            centres.append(P[good] + d[good] * (w[good] / 2)[:, None])
            axes.append(d[good] * w[good][:, None])
    return np.vstack(centres), np.vstack(axes)


def _level_pinch_pairs(scene, P: np.ndarray, N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centres, closing axes) of pinches of one thin wall closing level (square to the item's z axis): from each
    sample on a thin wall that does not lie flat, along its inward normal with the z part taken out (within
    WRAP_CONE_DEG of the normal), to where the line leaves the wall, narrower than PINCH_MAX_WIDTH, the far normal
    within WRAP_CONE_DEG of the closing axis. The pinch a Fin-Ray makes of a flared rim from straight above."""
    thick, _ = _cast(scene, P - N * 1e-4, -N)
    thin = np.isfinite(thick) & (thick < PINCH_MAX_WIDTH)
    d = -N.copy()
    d[:, 2] = 0.0
    level = np.linalg.norm(d, axis=1)
    cos_wrap = np.cos(np.radians(WRAP_CONE_DEG))
    keep = thin & (level >= cos_wrap)  # level >= cos(angle between the normal and its level part)
    P, N, d = P[keep], N[keep], d[keep] / level[keep, None]
    t, n_hit = _cast(scene, P - N * 1e-4, d)
    ok = np.isfinite(t)
    w = np.where(ok, t + 1e-4, np.inf)
    good = ok & (w > 0.001) & (w < PINCH_MAX_WIDTH) & (np.einsum("ij,ij->i", n_hit, d) >= cos_wrap)
    return P[good] + d[good] * (w[good] / 2)[:, None], d[good] * w[good][:, None]


def _level_across_pairs(scene, P: np.ndarray, N: np.ndarray, max_width: float) -> tuple[np.ndarray, np.ndarray]:
    """(centres, closing axes) of grips across the body closing level (square to the item's z axis) from samples on
    a sloped wall: the inward normal with its z part taken out, where that level line lies within the friction cone
    of the sample's normal (and is more than LEVEL_ACROSS_MIN_TILT off it: closer, the pairs along the normal are
    the same grips), to where it leaves the far wall, wider than PINCH_MAX_WIDTH, the far normal within the cone.
    The straight pairs run along the near normal, so on a wall sloped by a angle a they cross the body at a, and
    meet the far wall (its mirror) 2 a off its normal: outside the cone from a = 14 degrees on, though the level
    line between the two walls is within it up to 27 degrees (an upside-down bowl's or tumbler's flared sides)."""
    d = -N.copy()
    d[:, 2] = 0.0
    level = np.linalg.norm(d, axis=1)
    keep = (level >= np.cos(np.arctan(FRICTION_COEFF))) & (level < np.cos(np.radians(LEVEL_ACROSS_MIN_TILT)))
    if not keep.any():
        return np.zeros((0, 3)), np.zeros((0, 3))
    P, N, d = P[keep], N[keep], d[keep] / level[keep, None]
    return _antipodal_pairs(scene, P, N, max_width, D=d, min_width=PINCH_MAX_WIDTH)


def synthesise_grasps(model: ObjectModel) -> list[GraspSpec]:
    """Fin-Ray grasps for any closed mesh: antipodal pairs within the opening, the open pads and the palm clear of
    the item along the approach, the pads closing on that pair first, each pad face touching over at least
    MIN_CONTACT of it; best contact and most centred first within each kind of grasp (approach direction,
    pinch or across the body), the kinds taken in turn, spread out (no two within 6 mm and 30 degrees)."""
    from kitchenbot.world.gripper import FINGERS, PAD_DEPTH

    mesh = o3d.geometry.TriangleMesh(model.mesh)
    mesh.compute_triangle_normals()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    o3d.utility.random.seed(4)  # deterministic sampling
    pc = mesh.sample_points_poisson_disk(SURFACE_SAMPLES, use_triangle_normal=True)
    P, N = np.asarray(pc.points), np.asarray(pc.normals)
    max_width = MAX_OPENING - 0.01
    centres, axes = _antipodal_pairs(scene, P, N, max_width)
    slant = np.zeros(len(centres), bool)
    if PINCH_TILTS:
        more = _slanted_pinch_pairs(scene, P, N)
        centres, axes = np.vstack([centres, more[0]]), np.vstack([axes, more[1]])
        slant = np.concatenate([slant, np.ones(len(more[0]), bool)])
    level = np.zeros(len(centres), bool)
    if model.cls not in SLANTED_PINCH_CLASSES:
        more = _level_pinch_pairs(scene, P, N)
        centres, axes = np.vstack([centres, more[0]]), np.vstack([axes, more[1]])
        slant = np.concatenate([slant, np.ones(len(more[0]), bool)])  # checked as slanted pinches are
        level = np.concatenate([level, np.ones(len(more[0]), bool)])
    across = np.zeros(len(centres), bool)
    if model.cls not in SLANTED_PINCH_CLASSES:
        more = _level_across_pairs(scene, P, N, max_width)
        centres, axes = np.vstack([centres, more[0]]), np.vstack([axes, more[1]])
        slant, level = np.concatenate([slant, np.zeros(len(more[0]), bool)]), np.concatenate([level, np.zeros(len(more[0]), bool)])
        across = np.concatenate([across, np.ones(len(more[0]), bool)])
    if not len(centres):
        return []
    widths = np.linalg.norm(axes, axis=1)
    y = axes / widths[:, None]
    # approach directions all around each closing axis
    ref = np.where(np.abs(y[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(y, ref)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(y, u)
    phis = 2 * np.pi * np.arange(APPROACHES) / APPROACHES
    z = (np.cos(phis)[None, :, None] * u[:, None] + np.sin(phis)[None, :, None] * v[:, None]).reshape(-1, 3)
    k = len(CONTACT_DEPTHS)
    z = np.repeat(z, k, axis=0)
    y = np.repeat(y, APPROACHES * k, axis=0)
    w = np.repeat(widths, APPROACHES * k)
    c = np.repeat(centres, APPROACHES * k, axis=0)
    slant = np.repeat(slant, APPROACHES * k)
    level = np.repeat(level, APPROACHES * k)
    across = np.repeat(across, APPROACHES * k)
    R = np.stack([np.cross(y, z), y, z], axis=2)
    t = c + z * np.tile(CONTACT_DEPTHS, len(z) // k)[:, None]
    centroid, diameter = P.mean(axis=0), max(model.diameter, 1e-3)

    # the palm's underside, and each open pad's cross-section at its tip, looking back along the approach
    gx, gy = np.meshgrid(np.linspace(-0.035, 0.035, 5), np.linspace(-0.065, 0.065, 7))
    palm = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, PAD_ENVELOPE.root)])
    hx = PAD_ENVELOPE.width / 2 - 0.002
    px, py = np.meshgrid([-hx, 0.0, hx], np.linspace(0.002, PAD_ENVELOPE.thickness - 0.002, 3))
    pad_cut = np.column_stack([px.ravel(), py.ravel(), np.full(px.size, PAD_ENVELOPE.tip)])
    # the physical pad face (contact check): 5 x 7 points over its width and its last PAD_DEPTH
    fx, fz = np.meshgrid(np.linspace(-FINGERS.finger_half_x, FINGERS.finger_half_x, 5),
                         np.linspace(FINGERS.tip_z - PAD_DEPTH, FINGERS.tip_z, 7))
    face = np.column_stack([fx.ravel(), np.zeros(fx.size), fz.ravel()])
    back = np.array([0.0, 0.0, -1.0])

    n = len(w)
    clear_palm = np.ones(n, bool)
    for lo in range(0, n, 4000):  # the palm does not depend on the opening
        sl = slice(lo, lo + 4000)
        O, D = _local_rays(R[sl], t[sl], palm, np.zeros(len(w[sl])), back)
        th, _ = _cast(scene, O, D)
        clear_palm[sl] = ~np.isfinite(th).reshape(len(w[sl]), -1).any(axis=1)
    best: dict[int, tuple[float, float, float]] = {}  # candidate -> (score, opening, closed width)
    for slack in OPEN_SLACKS:
        todo = np.flatnonzero(clear_palm & ~np.isin(np.arange(n), list(best)))
        if not len(todo):
            break
        o = np.minimum(w[todo] + slack, MAX_OPENING)
        clear = np.ones(len(todo), bool)
        for sgn in (1.0, -1.0):
            grid = pad_cut * np.array([1.0, sgn, 1.0])
            O, D = _local_rays(R[todo], t[todo], grid, sgn * o / 2, back)
            th, _ = _cast(scene, O, D)
            clear &= ~np.isfinite(th).reshape(len(todo), -1).any(axis=1)
        todo, o = todo[clear], o[clear]
        if not len(todo):
            continue
        first, frac, off = [], [], []
        for sgn in (1.0, -1.0):  # pad a at +y closes along -y, pad b at -y along +y
            O, D = _local_rays(R[todo], t[todo], face, sgn * o / 2, np.array([0.0, -sgn, 0.0]))
            th, _ = _cast(scene, O, D)
            th = th.reshape(len(todo), -1)
            th[th > o[:, None]] = np.inf
            t_min = th.min(axis=1)
            first.append(t_min)
            frac.append((th <= t_min[:, None] + CONTACT_TOLERANCE).mean(axis=1))
            # where each pad first touches, from the pair's centre (a slanted pinch: on the wall it pinches)
            j = np.argmin(th, axis=1)
            hit = (O.reshape(len(todo), -1, 3)[np.arange(len(todo)), j]
                   + D.reshape(len(todo), -1, 3)[np.arange(len(todo)), j] * np.where(np.isfinite(t_min), t_min, 0)[:, None])
            off.append(np.linalg.norm(hit - c[todo], axis=1))
        closed = o - first[0] - first[1]
        area = np.minimum(frac[0], frac[1])
        # The pads close on the pair and nothing else first: at its width (straight pairs); a slanted pinch stops on
        # the wall's edges instead, wider than the pair: still a pinch of that wall where both pads first touch it
        # within PINCH_MAX_WIDTH of the pair and stop less than PINCH_MAX_WIDTH apart.
        on_pair = np.where(slant[todo], (closed < PINCH_MAX_WIDTH) & (np.maximum(off[0], off[1]) < PINCH_MAX_WIDTH),
                           np.abs(closed - w[todo]) <= WIDTH_TOLERANCE)
        # The width the Fin-Ray pads close to: they conform to the wall, so a slanted pinch closes to the wall's span
        # along the closing line through the TCP (what pad_span measures), not to the rigid pads' gap; that line
        # must cross the wall.
        span = _pad_spans(scene, y[todo], z[todo], t[todo])
        on_pair &= ~slant[todo] | (np.isfinite(span) & (span > 0) & (span < PINCH_MAX_WIDTH))
        # Straight pairs too: the rigid pad faces may touch the wall deeper along the approach while the lines near
        # the TCP only graze its lip (a rim leaning inwards, a tulip glass's mouth); the conforming pads close on
        # those lines, to less than MIN_SPAN, and hold nothing.
        # Where the pads first meet the item, then: the widest of the lines through the TCP and 5 mm either side
        # across the pads' width and along their depth (as the simulated gripper judges it).
        core = span
        for dx in (-0.005, 0.005):
            core = np.fmax(core, _pad_spans(scene, y[todo], z[todo], t[todo] + R[todo][:, :, 0] * dx))
        on_pair &= ~(np.isfinite(core) & (core < MIN_SPAN))
        closed = np.where(slant[todo], span, closed)
        ok = np.isfinite(closed) & on_pair & (area >= MIN_CONTACT)
        d_centre = np.linalg.norm(np.cross(centroid - c[todo], y[todo]), axis=1)
        score = area - CENTRE_WEIGHT * d_centre / diameter
        for i in np.flatnonzero(ok):
            best[int(todo[i])] = (float(score[i]), float(o[i]), float(closed[i]))
    round_ = _round_about_z(model)
    if round_:
        # a round item: every grasp turned about the axis is the same grasp; bring each to azimuth 0 (its TCP,
        # or its closing axis when the TCP is on the axis, along +x), choose there, and repeat the chosen ones all
        # around (a lying item's top, where a pinch comes from above, can be at any azimuth)
        ref_dir = np.where(np.hypot(t[:, 0], t[:, 1])[:, None] > 0.001, t, y)
        az = np.arctan2(ref_dir[:, 1], ref_dir[:, 0])
        ca, sa = np.cos(-az), np.sin(-az)
        Rz = np.zeros((len(az), 3, 3))
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = ca, -sa, sa, ca, 1.0
        R, t = Rz @ R, np.einsum("nij,nj->ni", Rz, t)
        y, z = R[:, :, 1], R[:, :, 2]
    per = ROUND_COPIES if round_ else 1
    if model.cls in SLANTED_PINCH_CLASSES:
        kept = _spread(best, t, y, z, w, MAX_GRASPS // per)
        fallback, rim_level, level_across = set(), set(), set()
    else:  # a vessel: its straight grasps as if there were no slanted ones, then its slanted ones as fallbacks
        kept = _spread({i: v for i, v in best.items() if not slant[i] and not across[i]}, t, y, z, w, MAX_GRASPS // per)
        more = _spread({i: v for i, v in best.items() if slant[i] and not level[i]}, t, y, z, w, MAX_RIM_SLANT // per)
        rim = _spread({i: v for i, v in best.items() if level[i]}, t, y, z, w, MAX_RIM_LEVEL // per)
        wide = _spread({i: v for i, v in best.items() if across[i]}, t, y, z, w, MAX_LEVEL_ACROSS // per)
        kept, fallback, rim_level, level_across = kept + more + rim + wide, set(more), set(rim), set(wide)
    out = []
    for rank, i in enumerate(kept):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[i], t[i]
        prefix = LEVEL_ACROSS if i in level_across else RIM_LEVEL if i in rim_level else RIM_SLANT if i in fallback else SLANTED_PINCH if slant[i] else "ap"
        if not round_:
            out.append(GraspSpec(f"{prefix}{rank:03d}", T, opening=best[i][1], width=best[i][2]))
            continue
        for k in range(ROUND_COPIES):
            out.append(GraspSpec(f"{prefix}{rank:02d}_{k:02d}", rot_z(2 * np.pi * k / ROUND_COPIES) @ T,
                                 opening=best[i][1], width=best[i][2]))
    if round_ and model.cls == "plate":
        out += narrow_lip_pinches(model, ROUND_COPIES)  # a plate leaning on a basin wall: see there
    return out


def _round_about_z(model: ObjectModel) -> bool:
    """Whether the model declares the continuous symmetry about its z axis through the origin."""
    for sym in model.symmetries_continuous:
        axis = np.asarray(sym["axis"], float)
        axis = axis / np.linalg.norm(axis)
        if abs(axis[2]) > 0.999 and np.linalg.norm(np.asarray(sym.get("offset", [0, 0, 0]), float)[:2]) < 1e-4:
            return True
    return False


def _spread(best: dict, t: np.ndarray, y: np.ndarray, z: np.ndarray, w: np.ndarray, limit: int) -> list[int]:
    """Up to `limit` candidates of `best` (index -> (score, ...)), best first within each kind of grasp (approach
    from above / tilted / level / tilted from below / from below, the item's z; a pinch of one wall or a grip
    across the body), the kinds taken in turn, no two within 6 mm and 30 degrees (approach and closing axis)."""
    by_score = sorted(best, key=lambda i: -best[i][0])
    kind = np.digitize(z[:, 2], [-0.7, -0.3, 0.3, 0.7]) * 2 + (w > PINCH_MAX_WIDTH)
    rank_in_kind: dict[int, int] = {}
    seen: dict[int, int] = {}
    for i in by_score:
        rank_in_kind[i] = seen.get(int(kind[i]), 0)
        seen[int(kind[i])] = rank_in_kind[i] + 1
    kept: list[int] = []
    cos30 = np.cos(np.radians(30))
    for i in sorted(by_score, key=lambda i: rank_in_kind[i]):
        if len(kept) >= limit:
            break
        if kept:
            k = np.array(kept)
            near = ((np.linalg.norm(t[k] - t[i], axis=1) < 0.006) & (z[k] @ z[i] > cos30)
                    & (np.abs(y[k] @ y[i]) > cos30))
            if near.any():
                continue
        kept.append(i)
    return kept
