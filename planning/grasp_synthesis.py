"""Grasp synthesis for the Fin-Ray gripper: the grasps an inventory model offers, in its object frame.

The inventory (world/inventory.py) holds grasps as data; this module fills them for models that come without:
``ensure_grasps(inventory)`` (the Planner calls it) gives the builtin dishware its hand-designed grasp families
(``generate_grasps``). ``pad_span`` measures the width the pads would close to on a mesh.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.transforms import make_T, rot_x, rot_y
from kitchenbot.world.gripper import MAX_OPENING, PAD_ENVELOPE
from kitchenbot.world.inventory import GraspSpec, Inventory, ObjectModel


def ensure_grasps(inventory: Inventory) -> Inventory:
    """Give every model without grasps its synthesised ones (in place; idempotent). Returns the inventory."""
    for model in inventory:
        if not model.grasps:
            model.grasps = generate_grasps(model, foot=model.dish.foot if model.dish is not None else None)
    return inventory


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


# The planner's pad boxes (world.gripper.PAD_ENVELOPE), for the check that a grasp's open pads do not cut into
# the item itself.
PAD_BOX_X = PAD_ENVELOPE.width / 2
PAD_BOX_THICKNESS = PAD_ENVELOPE.thickness
PAD_BOX_Z = (PAD_ENVELOPE.root, PAD_ENVELOPE.tip)


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
            if w is None or w > MAX_OPENING - 0.01 or w <= 0:
                continue
            if kind.startswith("footpitch") and abs(w - foot[1]) > 0.002:
                continue  # the slanted line across the ring leaves its wall (through the chamfered edge)
            slack = 0.016 if kind.startswith(("rimlean", "rimnarrow", "foot")) else 0.03
            opening = min(MAX_OPENING, w + slack)
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
