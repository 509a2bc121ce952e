"""Grasp selection (paper sec. III-D): predefined grasps per CAD model, filtered and ranked.

For every perceived object: drop it when it is hidden more than ``settings.max_occlusion`` (hidden = 1 -
visible_fraction / settings.visible_fraction_unoccluded: perception's visible_fraction is the share of all
model points its views confirmed, about 0.5 at best from above); express each
predefined grasp of its model in the base frame (``T_base_tcp = T_base_obj @ T_obj_tcp``); keep those that
approach from above-ish (TCP z, the approach, must not point up by more than ``settings.max_approach_up``),
that take in no other object between the pads (multi-object grasps), that have IK for the grasp and pre-grasp
poses, whose gripper at the grasp collides with nothing but the target's pads contact, and whose pre-grasp is
collision-free. Ranked by gripper clearance at the grasp and motion cost from the current configuration; the
planner then tries them in order until one is plannable.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import coal
import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.bite import fingers_reach_backed_off
from kitchenbot.planning.collision import Scene, coal_transform
from kitchenbot.planning.pad_give import pad_contacts
from kitchenbot.planning.robot import RobotModel
from kitchenbot.planning.types import (
    Grasp,
    NoCollisionFreeGrasp,
    NoFeasiblePlacement,
    NoGraspableObject,
    NoIK,
    PlanningFailure,
)
from kitchenbot.transforms import from_rotvec, make_T, rot_y, trans
from kitchenbot.world.gripper import PAD_DEPTH
from kitchenbot.world.inventory import GraspSpec, Inventory, grasp_base_name, narrowed_name, spun_name, tilted_name


def too_hidden(o: ObjectPose, settings) -> bool:
    """Whether grasp selection skips `o` as buried: hidden (1 - visible_fraction / visible_fraction_unoccluded)
    more than settings.max_occlusion."""
    hidden = 1.0 - min(1.0, float(o.visible_fraction) / settings.visible_fraction_unoccluded)
    return hidden > float(settings.max_occlusion)


def object_name(o: ObjectPose, index: int) -> str:
    """Name of a perceived object in the collision world (its instance id, else its index)."""
    return str(o.instance_id if o.instance_id >= 0 else f"i{index}")


@dataclass
class GraspStats:
    considered: int = 0
    occluded: int = 0
    from_below: int = 0
    multi_object: int = 0
    no_ik: int = 0
    in_collision: int = 0
    no_placement: int = 0  # the placement asked for is unreachable with this grasp
    feasible: int = 0
    observed_in_tool: int = 0  # feasible, but observed points lie where a pad or the palm would be (ranked last)
    empty_grip: int = 0  # feasible, but none of the item's observed points lies between the pads (ranked last)
    pad_contact: int = 0  # feasible with the pads brushing a neighbour within their give (ranked after clear ones)
    swivelled: int = 0  # collision-free only swivelled about its closing axis (second pass, SWIVELS)
    spun: int = 0  # found only with the grasps turned about a round item's axis between their copies (SPIN_STEPS)
    narrowed: int = 0  # collision-free only approached with the pads opened NARROW_SLACK wider than the item
    # perceived objects (names) the rejected grasps collided with or took in, and how often; filled only when no
    # grasp is feasible (what crowds the item: Planner.plan_pick names the most frequent one as its blocker)
    crowded_by: dict = field(default_factory=dict)


def closing_volume(opening: float, pad_width: float, pad_root: float, pad_tip: float) -> tuple[coal.Box, np.ndarray]:
    """The space the pads sweep while closing, as a box in the TCP frame."""
    return coal.Box(pad_width, max(opening, 1e-3), pad_tip - pad_root), make_T(t=(0.0, 0.0, (pad_root + pad_tip) / 2))


# A Fin-Ray pad wraps a few millimetres around the contact: its sweep reaches this far past the expected width.
PAD_WRAP = 0.003


def pad_sweeps(opening: float, width: float, pad_width: float, pad_root: float,
               pad_tip: float) -> list[tuple[coal.Box, np.ndarray]]:
    """The space each pad sweeps while closing from `opening` onto an item `width` wide: two boxes (TCP frame).

    Whatever else lies there is pushed or taken in with the target. What lies between the closed pads but
    outside the sweeps (the next plate of a stack, under the target's rim on the side where the target
    overhangs it) is shielded by the target and stays where it is."""
    inner = max(width / 2 - PAD_WRAP, 0.0)
    outer = max(opening / 2, inner + 1e-3)
    zc, depth = (pad_root + pad_tip) / 2, pad_tip - pad_root
    yc = (inner + outer) / 2
    box = coal.Box(pad_width, outer - inner, depth)
    return [(box, make_T(t=(0.0, yc, zc))), (box, make_T(t=(0.0, -yc, zc)))]


def observed_in_tool(P_tcp: np.ndarray, opening: float, gripper, shrink: float = 0.002) -> int:
    """How many observed points (TCP frame, (N, 3)) lie inside a finger pad or the palm at pad distance
    `opening`, each box shrunk by `shrink` (depth noise on a surface the tool only touches).

    Where the estimated pose is off (nested items: 1-2 cm, up to ~20 degrees), the CAD model leaves a gap for a
    pad that the real item fills: a bowl's 10 mm foot ring pinched with one pad inside, one outside lands the
    inner pad on the ring (missed, or worse: a collision). The fused map points show the real surfaces."""
    if len(P_tcp) == 0:
        return 0
    x, y, z = P_tcp[:, 0], P_tcp[:, 1], P_tcp[:, 2]
    half = opening / 2
    in_x = np.abs(x) <= gripper.pad_width / 2 - shrink
    in_z = (z >= gripper.pad_root + shrink) & (z <= gripper.pad_tip - shrink)
    pads = in_x & in_z & (np.abs(np.abs(y) - (half + gripper.pad_thickness / 2)) <= gripper.pad_thickness / 2 - shrink)
    palm = ((np.abs(x) <= gripper.palm_size_xy[0] / 2 - shrink) & (np.abs(y) <= gripper.palm_size_xy[1] / 2 - shrink)
            & (z < gripper.pad_root - shrink) & (z > gripper.pad_root - 0.08))
    return int(np.count_nonzero(pads | palm))


def observed_in_grip(P_tcp: np.ndarray, opening: float, gripper, pad_depth: float) -> int:
    """How many observed points (TCP frame) lie between the pads where they close on the item: across the gap
    (2 mm in from each pad), over the pad's width and its last `pad_depth` (the contact depth)."""
    if len(P_tcp) == 0:
        return 0
    x, y, z = P_tcp[:, 0], P_tcp[:, 1], P_tcp[:, 2]
    m = ((np.abs(x) <= gripper.pad_width / 2) & (np.abs(y) <= opening / 2 - 0.002)
         & (z >= gripper.pad_tip - pad_depth) & (z <= gripper.pad_tip))
    return int(np.count_nonzero(m))


# Grasps kept for where nothing else fits (planning.grasp_synthesis.generate_grasps): the narrow plate rim pinch, for a
# plate leaning against a basin wall (opened only 8 mm per pad past the lip, it tolerates less pose error than
# the standard pinches); the foot-ring pinch pitched in from outside the ring, for a bowl lying tilted (it
# closes across the ring at a slant, the outer pad's tip next to the body); and the side grasp across a cup's,
# mug's or glass's base end (the pads' edge at the base: it holds less of the body), for one lying with a
# neighbour along its body; and the grasps that straddle a handle on its roots (held by the handle, the body's
# weight turns about the closing line), for a mug lying with its handle part-way up. They rank after every feasible
# standard grasp.
FALLBACK_GRASPS = ("rimnarrow", "footpitch", "side10", "rimslant", "rimlevel", "acrosslevel", "handle", "rimunder")
FALLBACK_PENALTY = 1.0
# A grasp whose pads brush a neighbour (planning/pad_give.py) ranks after the standard grasps that keep clear.
PAD_GIVE_PENALTY = 1.0

# Observed points inside the tool at a grasp that count as a real surface there (a few are depth noise).
OBSERVED_HITS = 20
# An item seen with at least this many points shows some of the surface a grasp closes on (a grasp whose grip
# zone holds none of them closes on nothing where the item really is: a bowl's unseen foot ring).
WELL_OBSERVED = 200

# +-5 deg: nearly level, but the wrist rides ~2 cm higher (clears a counter the item stands on) and the approach
# still counts as from above when the item is turned upside down (sin 5 deg < max_approach_up 0.1);
# +-30/50 deg: from above into a sink, where a 20 cm tool cannot come in level below the counter top.
TILTS = tuple(np.radians(a) for a in (5.0, -5.0, 30.0, -30.0, 50.0, -50.0))
# A steep tilt of an item that is not round (a mug: its handle) is kept where the tilted pads close across the
# width the untilted grasp closes across, within this (m; the handle between the pads would widen it).
STEEP_WIDTH_TOL = 0.002
_expanded: dict[int, tuple] = {}


def _steep_tilt_fits(model, spec, T_obj_tcp: np.ndarray, checks: dict) -> bool:
    """Whether a side grasp of a non-round item tilted steeply about its closing axis still closes on the body
    only: its open pads keep out of the item's own mesh (the handle; planning.grasp_synthesis.pads_clear on
    surface samples) and the pads close across the untilted grasp's width (nothing else between them).

    The planner lets the pads touch the target they grasp, so these are checked on the model here, once per
    model (`checks` holds its surface samples and ray scene)."""
    from kitchenbot.planning import grasp_synthesis as synth

    if not checks:
        import open3d as o3d

        mesh = model.mesh
        checks["surface"] = _model_surface(model)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        checks["scene"] = scene
    if not synth.pads_clear(checks["surface"], T_obj_tcp, spec.opening):
        return False
    w = synth.pad_span(model, T_obj_tcp, scene=checks["scene"])
    return w is not None and abs(w - spec.width) <= STEEP_WIDTH_TOL


_surfaces: dict[int, tuple] = {}  # id(model) -> (model, its surface samples)


def _model_surface(model) -> np.ndarray:
    """The surface samples of `model`'s mesh (`_surface_samples`), once per model: the pads-clear checks of
    steep tilts and of swivels read the same ones."""
    hit = _surfaces.get(id(model))
    if hit is None or hit[0] is not model:
        if len(_surfaces) > 256:
            _surfaces.clear()
        hit = _surfaces[id(model)] = (model, _surface_samples(np.asarray(model.mesh.vertices),
                                                              np.asarray(model.mesh.triangles)))
    return hit[1]


def _surface_samples(V: np.ndarray, F: np.ndarray, n: int = 30000) -> np.ndarray:
    """`n` points uniformly on the mesh (area-weighted), and its vertices, as float32: ~2 mm apart on a mug, as
    generate_grasps checks its own grasps. Sampled with a local generator, not Open3D's (its one global random
    state is perception's too: drawing from it here would change what perception draws next)."""
    rng = np.random.default_rng(2)
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(B - A, C - A), axis=1)
    tri = rng.choice(len(F), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    P = A[tri] + u[:, None] * (B[tri] - A[tri]) + v[:, None] * (C[tri] - A[tri])
    return np.vstack([P, V]).astype(np.float32)


def expand_grasps(model) -> list:
    """The model's predefined grasps plus each side grasp (approach perpendicular to the item's axis) tilted
    about its closing axis by +-5 degrees, and also by +-30 and +-50 degrees: for rotationally symmetric items
    all of them; for others (a mug: its handle) those whose tilted pads still close on the body only
    (`_steep_tilt_fits`), as fallbacks (`is_fallback`).

    The closing axis and the TCP point stay, so the pads pinch the same diameter; only the direction the
    gripper comes from changes (from above at an angle, not level: a 20 cm tool cannot come in level below
    the counter top). Contacts of the tilted pads with the target are allowed at the grasp anyway."""
    return _expansion(model)[0]


def is_fallback(model, spec) -> bool:
    """Whether grasp `spec` of `model` ranks after every feasible standard one: the fallback kinds
    (FALLBACK_GRASPS) and the steep tilts of a non-round item's side grasps (expand_grasps)."""
    return spec.name.startswith(FALLBACK_GRASPS) or spec.name in _expansion(model)[1]


def _expansion(model) -> tuple[list, frozenset]:
    """(expand_grasps(model), the names of the steep tilts kept for a non-round item), cached per model."""
    from kitchenbot.transforms import rot_y
    from kitchenbot.world.inventory import GraspSpec

    key = id(model)
    hit = _expanded.get(key)
    if hit is not None and hit[0] is model:  # (the model is kept in the entry: its id cannot be reused meanwhile)
        return hit[1], hit[2]
    out = list(model.grasps)
    steep: set[str] = set()
    checks: dict = {}
    sym = model.is_rotationally_symmetric
    axis = np.asarray(model.symmetries_continuous[0]["axis"], float) if sym else np.array([0.0, 0.0, 1.0])
    axis /= np.linalg.norm(axis)
    for g in model.grasps:
        if abs(float(g.T_obj_tcp[:3, 2] @ axis)) > 0.2:
            continue  # not a side grasp
        for t in TILTS:
            T = g.T_obj_tcp @ rot_y(t)
            name = tilted_name(g.name, t)
            if not sym and abs(t) > TILTS[0] + 1e-9:
                # a non-round item's steep tilt: only where the pads still close on the body alone
                if model.mesh is None or not _steep_tilt_fits(model, g, T, checks):
                    continue
                steep.add(name)
            out.append(GraspSpec(name, T, g.opening, g.width))
    if len(_expanded) > 256:
        _expanded.clear()
    _expanded[key] = (model, out, frozenset(steep))
    return out, frozenset(steep)


# Turns about a round item's axis, as fractions of the angle between neighbouring copies of its grasps, tried in
# turn when no grasp of it fits as given (select_grasps' last pass): half way between the copies, then a quarter
# either side.
SPIN_STEPS = (0.5, 0.25, -0.25)
_spins: dict[int, tuple] = {}  # id(model) -> (model, angle between neighbouring grasp copies)


def _symmetry_axis(model) -> tuple[np.ndarray, np.ndarray]:
    """(unit axis, a point on it) of a round model's continuous symmetry, in its object frame (BOP models_info)."""
    sym = model.symmetries_continuous[0]
    a = np.asarray(sym["axis"], float)
    return a / np.linalg.norm(a), np.asarray(sym.get("offset", (0.0, 0.0, 0.0)), float)


def copy_spacing(model) -> float:
    """The largest angle (rad) about a round model's symmetry axis between neighbouring azimuths of its grasps
    (each grasp's TCP point about the axis; its closing direction for one on the axis): the predefined copies of a
    pinch sit this far apart round the rim (0 for a model with no grasps)."""
    hit = _spins.get(id(model))
    if hit is not None and hit[0] is model:
        return hit[1]
    a, c = _symmetry_axis(model)
    u = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    az = []
    for g in model.grasps:
        p = g.T_obj_tcp[:3, 3] - c
        p = p - (p @ a) * a
        if np.linalg.norm(p) < 0.01:
            p = g.T_obj_tcp[:3, 1]
        az.append(np.arctan2(p @ v, p @ u) % (2 * np.pi))
    az = np.unique(np.round(np.sort(az), 3))
    gap = float(np.max(np.diff(np.append(az, az[0] + 2 * np.pi)))) if len(az) > 1 else 0.0
    if len(_spins) > 256:
        _spins.clear()
    _spins[id(model)] = (model, gap)
    return gap


def spun_grasps(model, frac: float) -> list:
    """expand_grasps(model) turned about the round model's symmetry axis by `frac` of copy_spacing (the item
    turned under them: perception cannot tell a round item's turn about its axis, so where its grasp copies sit
    round the rim is arbitrary, and a free gap between neighbours narrower than their spacing may hold none)."""
    angle = frac * copy_spacing(model)
    if angle == 0.0:
        return []
    a, c = _symmetry_axis(model)
    S = trans(*c) @ from_rotvec(a * angle) @ trans(*-c)
    return [GraspSpec(spun_name(g.name, angle), S @ g.T_obj_tcp, g.opening, g.width) for g in expand_grasps(model)]


def _may_place(specs: list, o: ObjectPose, grasp_filter) -> list:
    """The spun grasps `specs` of `o` that might pass the place filter as given or swivelled by SWIVELS (its
    `approachable`, see _spins_may_place); all of them without a filter or without that test. A spin selection
    keeps a grasp only where the filter passes it, so it need not check the others (IK, collision) at all: its
    answer is the same; only its counts, which no caller reads (select_grasps' last pass), are not."""
    approachable = getattr(grasp_filter, "approachable", None)
    if approachable is None or not specs:
        return specs
    turns = (0.0, *SWIVELS)
    ok = approachable(o, np.array([g.T_obj_tcp @ rot_y(a) for g in specs for a in turns]))
    ok = ok.reshape(len(specs), len(turns)).any(axis=1)
    return [g for g, y in zip(specs, ok) if y]


def _spins_may_place(items: Sequence[ObjectPose], inventory, grasp_filter) -> bool:
    """Whether the spin selections (every SPIN_STEPS turn) of these round items might keep a grasp with this place
    filter: False only where the filter's `approachable(obj, T_obj_tcps)` (a necessary condition, planning.
    pick_place) refuses every grasp they could ask it about (each spun grasp as given and swivelled by SWIVELS;
    the narrowed ones keep the spun grasp's pose). True without a filter or without that test."""
    approachable = getattr(grasp_filter, "approachable", None)
    if approachable is None:
        return True
    for o in items:
        model = inventory[o.obj_id]
        Ts = [g.T_obj_tcp @ rot_y(a) for frac in SPIN_STEPS for g in spun_grasps(model, frac) for a in (0.0, *SWIVELS)]
        if Ts and approachable(o, np.array(Ts)).any():
            return True
    return False


def _observed_near(o: ObjectPose, objects: Sequence[ObjectPose], reach: float = 0.25) -> np.ndarray:
    """The observed points (base frame) of `o` and of every perceived object within `reach` of it."""
    c = np.asarray(o.T_base_obj, float)[:3, 3]
    parts = [np.asarray(o.points, float).reshape(-1, 3)]
    for x in objects:
        if x is o or np.linalg.norm(np.asarray(x.T_base_obj, float)[:3, 3] - c) > reach:
            continue
        parts.append(np.asarray(x.points, float).reshape(-1, 3))
    P = np.vstack(parts)
    return P[np.linalg.norm(P - c, axis=1) <= reach] if len(P) else P


# rejected grasps whose collisions are looked at when no grasp is feasible (a few ms each)
MAX_CROWD_CHECKS = 24


# _crowded_by's key for the map's voxels (map points no perceived object explains: unexplained points, contact marks)
VOXELS = "voxels"


def _crowded_by(scenes: dict, names: list[str], collided: list, taken: list, objects) -> dict:
    """{object name, or VOXELS for the map's voxels: how many rejected grasps collided with it or would take it
    in}. The voxels count too: a grasp blocked only by map points no object explains (contact marks, an unseen
    item's points) is reported as such, not as blocked by the neighbour a few of the grasps also touched."""
    out: dict[str, int] = {}
    for o in taken:
        k = next((j for j, x in enumerate(objects) if x is o), None)
        if k is not None:
            out[names[k]] = out.get(names[k], 0) + 1
    for k, q, opening in collided:
        sc = scenes[k]
        sc.set_opening(opening)
        pairs = sc.colliding_pairs(q)
        hit = {n[4:] for p in pairs for n in p if n.startswith("obj:") and n[4:] != names[k]}
        if any(n == VOXELS for p in pairs for n in p):
            hit.add(VOXELS)
        for n in hit:
            out[n] = out.get(n, 0) + 1
    return out


def _taken_in(T: np.ndarray, spec, gripper, others, scene: Scene, req, shrink: float = 0.0) -> ObjectPose | None:
    """The first other object (``others``: (pose, model) pairs) where a pad of grasp `spec` at `T` sweeps while
    closing (it would be pushed or taken in with the target), or None. `shrink`: each sweep box that much smaller
    on every side (an object found only without it overlaps a sweep by less than `shrink`)."""
    sweeps = [(vol if shrink <= 0.0 else coal.Box(*np.maximum(2.0 * (np.asarray(vol.halfSide) - shrink), 1e-4)),
               coal_transform(T @ T_v)) for vol, T_v in
              pad_sweeps(spec.opening, spec.width, gripper.pad_width, gripper.pad_root, gripper.pad_tip)]
    for po, pm in others:
        if np.linalg.norm(po.T_base_obj[:3, 3] - T[:3, 3]) > pm.diameter / 2 + 0.15:
            continue
        if any(coal.collide(vol, T_vol, scene.world.bvh(pm), coal_transform(po.T_base_obj), req, coal.CollisionResult())
               for vol, T_vol in sweeps):
            return po
    return None


# Swivels (radians) about a grasp's closing axis tried when no grasp of an item fits as given, on the grasps that
# missed narrowly (select_grasps' second pass), and how narrowly: a pad sweep overlapping a neighbour by less than
# NEAR_MISS (m) on every side, or only the tool (pads, palm, camera) meeting a neighbour or the map.
SWIVELS = tuple(np.radians(a) for a in (3.0, -3.0, 6.0, -6.0))
NEAR_MISS = 0.002
MAX_MISSES = 4  # rejections of one grasp kept to tell whether it missed narrowly
# m: how far a grasp may back off along its approach (a shallower bite) when the finger tips would touch what the
# item rests on: a Fin-Ray grasp still holds
BITES = (0.0, 0.004, 0.008)
IK_CHUNK = 8  # candidates whose IK (at every bite) is solved in one batch (RobotModel.ik_all_batch)
FIT_MEMO_SIZE = 20000  # candidates' checks kept in select_grasps' `memo` (emptied when full)
TOOL_PARTS = ("pad_a", "pad_b", "palm", "camera")
# m: the pads' opening beyond the item's width (both sides together) of a grasp approached narrowly, where nothing
# fits as given only because an open pad meets something (a basin wall beside a glass standing in a corner): the
# widest slack the grasp synthesis gives any grasp is 30 mm, the narrowest (leaning and narrow rim pinches, foot
# pinches: grasp_synthesis) this one; where that still leaves a pad in something, the next of NARROW_SLACKS (8 mm:
# 4 mm a pad, a glass leaning on an upturned bowl by a wall, the bowl-side pad coming down between glass and dome)
NARROW_SLACK = 0.016
NARROW_SLACKS = (NARROW_SLACK, 0.008)  # tried in this order, the next only where every pass failed with the one before
PADS = ("pad_a", "pad_b")


def _pads_only(pairs) -> bool:
    """Whether every colliding pair has an open pad in it (nothing else of the arm or the tool is in the way): what
    Scene.only_pads_touch answers without listing the pairs (the reference its test compares it with)."""
    return bool(pairs) and all(a in PADS or b in PADS for a, b in pairs)


def _tool_only(pairs) -> bool:
    """Whether every colliding pair is a tool part against a perceived object or the map's voxels."""
    return bool(pairs) and all(
        (a in TOOL_PARTS and b.startswith(("obj:", "voxels"))) or (b in TOOL_PARTS and a.startswith(("obj:", "voxels")))
        for a, b in pairs)


def _swivel_fits(model, spec, T_obj_tcp: np.ndarray) -> bool:
    """Whether the open pads of grasp `spec` swivelled to `T_obj_tcp` keep out of the item's own mesh (the planner
    lets the pads touch their target, so a swivel through a handle or a wall would pass unchecked)."""
    from kitchenbot.planning import grasp_synthesis as synth

    if model.mesh is None or not len(model.mesh.triangles):
        return True
    return synth.pads_clear(_model_surface(model), T_obj_tcp, spec.opening)


def narrowed_grasp(model, spec, slack: float) -> GraspSpec | None:
    """Grasp `spec` approached with its pads open only `slack` wider than the item (same pose, same width),
    or None where it already opens no wider than that or where the narrower open pads would cut into the item's own
    mesh (the planner lets the pads touch their target, so that is checked here)."""
    from kitchenbot.planning import grasp_synthesis as synth

    opening = spec.width + slack
    if opening >= spec.opening - 1e-4:
        return None
    if model.mesh is not None and len(model.mesh.triangles) and \
            not synth.pads_clear(_model_surface(model), spec.T_obj_tcp, opening):
        return None
    return GraspSpec(narrowed_name(spec.name, slack), spec.T_obj_tcp, opening, spec.width)


def select_grasps(
    robot: RobotModel,
    scene: Scene,
    inventory: Inventory,
    objects: Sequence[ObjectPose],
    q_current: np.ndarray,
    *,
    settings,
    target: ObjectPose | None = None,
    grasp_filter=None,
    stats: GraspStats | None = None,
    limit: int | None = None,
    avoid: Sequence[str] = (),
    q_rest: np.ndarray | None = None,
    spin: float = 0.0,
    memo: dict | None = None,
    narrow_level: int = 0,
) -> list[Grasp] | PlanningFailure:
    """Ranked feasible grasps (best first), or the failure that explains why there are none.

    Candidates are checked most promising first; with `limit`, checking stops once that many are feasible
    (the ranking is then among those).

    `scene` holds every perceived object as ``obj:<object_name>``; `grasp_filter(obj, spec, T_base_tcp) -> bool`
    is an extra predicate (e.g. the placement must be reachable with this grasp). `avoid`: grasp names not to use,
    with their tilted variants (expand_grasps): a grasp that closed on nothing closes on nothing tilted by 5 degrees.
    `q_rest`: where the arm comes back to after the item (RobotModel.wrap_round_trip): each IK branch's joints
    turned by whole turns for the shortest way out from `q_current` and back there.
    `spin`: only round items, their grasps turned about the axis by this fraction of their spacing (spun_grasps;
    the last pass, where none fits as given, tries SPIN_STEPS).
    `memo`: a dict kept by the caller across selections, in which each candidate's checks (IK at every bite, the
    pads' sweeps, collision, pre-grasp; `fit`) are kept with what they depend on (the scene's content, every
    object's pose, `q_current`, `q_rest`, the candidate's grasp and pose): a later selection of the same item in
    the same scene (the pick again towards other targets, a staging regrasp's pick, the same pick with grasps
    avoided) reuses them instead of checking again. Only the answer is kept, never a decision: the place filter,
    the ranking and the later passes run as without it.
    `narrow_level`: which of NARROW_SLACKS the third pass opens the pads by; where every pass fails with one, the
    whole selection runs again with the next (the narrower slack is the last resort, after the spun grasps).
    """
    st = stats or GraspStats()
    gripper = scene.world.gripper
    names = [object_name(o, k) for k, o in enumerate(objects)]
    cands = [(k, o) for k, o in enumerate(objects) if target is None or o is target or
             (target.instance_id >= 0 and o.instance_id == target.instance_id)]
    if target is not None and not cands:
        cands = [(len(objects), target)]
        names.append(object_name(target, len(objects)))
    avoid_base = {grasp_base_name(a) for a in avoid}
    out: list[Grasp] = []
    any_model = False
    req = coal.CollisionRequest()
    ur = robot.ur
    reach = abs(ur.a[1]) + abs(ur.a[2]) + np.hypot(ur.d[3], ur.d[4]) + 0.02
    # Phase 1: cheap filters (occlusion, approach from above, reach) over every (object, grasp) pair.
    pending = []
    for k, o in cands:
        if too_hidden(o, settings):
            st.occluded += 1
            continue
        try:
            model = inventory[o.obj_id]
        except KeyError:
            continue
        if not spin:
            specs = expand_grasps(model)
        else:
            specs = spun_grasps(model, spin) if model.is_rotationally_symmetric else []
            specs = _may_place(specs, o, grasp_filter)
        if not specs:
            continue
        any_model = True
        for spec in specs:
            if avoid and grasp_base_name(spec.name) in avoid_base:
                continue
            st.considered += 1
            T = np.asarray(o.T_base_obj, float) @ spec.T_obj_tcp
            if T[2, 2] > settings.max_approach_up:
                st.from_below += 1
                continue
            # reach: the wrist centre must be within the arm's reach of the shoulder (cheap IK pre-filter)
            wrist = T[:3, 3] - T[:3, :3] @ robot.T_flange_tcp[:3, 3]
            if np.linalg.norm(wrist - np.array([0.0, 0.0, ur.d[0]])) > reach:
                st.no_ik += 1
                continue
            pending.append((k, o, spec, T))
    # Phase 2, most promising first (objects higher up are less buried; approaches closer to vertical leave
    # the gripper more room), fallback grasps after every standard one (they rank after them anyway, so they must
    # not take the places of standard ones under `limit`): the expensive checks, until `limit` grasps are feasible.
    pending.sort(key=lambda c: (is_fallback(inventory[c[1].obj_id], c[2]), -(c[3][2, 3] + 0.05 * -c[3][2, 2])))
    scenes: dict[int, Scene] = {}
    collided: list = []  # (object index, q, opening) of rejected grasps: what crowds the item, if nothing fits
    taken: list = []  # objects a pad would take in
    observed: dict[int, np.ndarray] = {}  # object index -> observed points (base frame) around it
    near: list = []  # (k, o, spec, T, misses) of rejected grasps (those that missed narrowly: second pass)

    def bites(T) -> np.ndarray:
        """The grasp pose at each bite (BITES), (3, 4, 4)."""
        return np.array([T @ trans(0.0, 0.0, -back) for back in BITES])

    # what every candidate's checks depend on besides the candidate itself (select_grasps' `memo`)
    context = None if memo is None else (
        scene.content_key(), tuple((o.obj_id, np.asarray(o.T_base_obj, float).tobytes()) for o in objects),
        np.asarray(q_current, float).tobytes(), None if q_rest is None else np.asarray(q_rest, float).tobytes(),
        float(settings.approach_distance), repr(settings.pad_give), id(robot), id(inventory))

    def fit(k, o, spec, T, misses: list | None = None, ik=None):
        """(q_grasp, q_pre, T at the bite taken, pad contacts, first colliding branch, first object taken in,
        reached); `misses` gets ("taken", T at the bite) and ("hit", q) of the first few rejections. `ik`: the
        closed-form IK branches at each bite (RobotModel.ik_all_batch over `bites(T)`), when already solved, or a
        function giving them (called only where the checks are not kept in `memo`)."""
        if k not in scenes:
            scenes[k] = scene.for_grasp(names[k])
        scenes[k].set_opening(spec.opening)  # the opening stays set for what asks the grasp scene next (accept)
        key = None
        if context is not None:
            key = (context, k, names[k], o.obj_id, np.asarray(o.T_base_obj, float).tobytes(), spec.name,
                   np.asarray(spec.T_obj_tcp, float).tobytes(), float(spec.opening), float(spec.width),
                   np.asarray(T, float).tobytes())
            kept = memo.get(key)
            if kept is not None:
                return _replay(k, kept, misses)
        found: list = []  # the rejections, as `misses` would get them from an empty list
        res = checks(k, o, spec, T, found, ik() if callable(ik) else ik)
        if key is not None:
            if len(memo) >= FIT_MEMO_SIZE:  # bounded: emptied before this answer is kept, not after
                memo.clear()
            # the object taken in by index (the next selection's objects are other ObjectPose instances)
            taken_at = None if res[5] is None else next(j for j, x in enumerate(objects) if x is res[5])
            # the misses without their neighbour lists (made again from this selection's objects on replay: the
            # memo keeps no perceived object alive)
            memo[key] = (res[:5] + (taken_at,) + res[6:], [(kind, x) for kind, x, _ in found])
        if misses is not None:
            misses.extend(found)
        return res

    def _replay(k, kept, misses):
        res, found = kept
        if misses is not None:
            others = [(objects[j], inventory[objects[j].obj_id]) for j in range(len(objects))
                      if j != k and objects[j].obj_id in inventory.models]
            misses.extend((kind, x, others if kind == "taken" else None) for kind, x in found)
        q_grasp, q_pre, Tg, brush, first_hit, taken_at, reached = res
        copy = (lambda a: None if a is None else np.array(a, float))
        return (copy(q_grasp), copy(q_pre), copy(Tg), brush, first_hit,
                None if taken_at is None else objects[taken_at], reached)

    def checks(k, o, spec, T, misses: list, ik: list | None):
        """fit's checks, where `memo` does not keep them (`misses`: an empty list, filled as fit describes)."""
        grasp_scene = scenes[k]
        others = [(objects[j], inventory[objects[j].obj_id]) for j in range(len(objects))
                  if j != k and objects[j].obj_id in inventory.models]
        first_hit = None  # the first IK branch whose gripper collided (what crowds the item)
        first_taken = None  # the first object a pad's closing sweep would take in
        reached = False
        # A Fin-Ray grasp still holds with a shallower bite: back off along the approach (up to 8 mm)
        # when the finger tips would touch what the object rests on. Every IK branch is tried, nearest to
        # the current configuration first (the nearest one's forearm often hits a basin wall where another
        # branch's does not); numerical IK covers wrist-singular poses, where the closed form gives none.
        # The multi-object test (another object where a pad sweeps while closing) is made at each bite too:
        # the pad tips of a grasp across an item lying on others (a mug on a plate stack) sweep into what it
        # lies on at the full bite and clear it a few millimetres shallower.
        Ts = bites(T)
        if ik is None:
            ik = robot.ik_all_batch(Ts, q_current)
        for back, Tb, branches in zip(BITES, Ts, ik):
            if back > 0.0 and not fingers_reach_backed_off(inventory[o.obj_id], spec.T_obj_tcp, back):
                continue  # backed off this far the fingers end short of the item's wall (planning/bite.py)
            taken_by = _taken_in(Tb, spec, gripper, others, scene, req)
            if taken_by is not None:
                first_taken = first_taken or taken_by
                if misses is not None and len(misses) < MAX_MISSES:
                    misses.append(("taken", Tb, others))
                continue
            if q_rest is not None:
                branches = list(robot.wrap_round_trip_rows(np.array(branches), q_current, q_rest)) if branches else []
            # numerical IK only where it may find something: not where the pose is clearly out of reach
            if not branches and not robot.surely_unreachable(Tb):
                num = robot.ik(Tb, q_current, max_seeds=6, max_iter=40)
                branches = [num.q] if num.q is not None else []
            if back == 0.0 and not branches:
                break  # unreachable: backing off 8 mm will not change that
            for qb in branches:
                reached = True
                give = None
                if not grasp_scene.valid(qb):
                    # the pads may brush a neighbour within their give (planning/pad_give.py)
                    give = pad_contacts(grasp_scene, qb, Tb, spec.opening, f"obj:{names[k]}",
                                        settings.approach_distance, settings.pad_give)
                    if give is None:
                        first_hit = first_hit or (k, qb, spec.opening)
                        if misses is not None and len(misses) < MAX_MISSES:
                            misses.append(("hit", qb, None))
                        continue
                q_pre = robot.ik(Tb @ trans(0.0, 0.0, -settings.approach_distance), qb, max_seeds=0).q
                if q_pre is None or not scene.valid(q_pre):
                    continue  # this branch's pre-grasp is unreachable or blocked: try the next branch
                return qb, q_pre, Tb, tuple(give or ()), first_hit, first_taken, reached
        return None, None, T, (), first_hit, first_taken, reached

    def narrow(k, spec, misses) -> bool:
        """Whether a rejected grasp missed narrowly: a pad sweep overlapping a neighbour by less than NEAR_MISS, or
        only the tool meeting a neighbour or the map (at some bite and IK branch)."""
        for kind, x, others in misses:
            if kind == "taken":
                if _taken_in(x, spec, gripper, others, scene, req, shrink=NEAR_MISS) is None:
                    return True
            else:
                scenes[k].set_opening(spec.opening)
                if scenes[k].only_tool_touches(x):  # _tool_only(colliding_pairs(x)), by two broad-phase checks
                    return True
        return False

    def pads_in_the_way(k, spec, misses) -> bool:
        """Whether a rejected grasp was rejected (at some bite and IK branch) only for its open pads: they met
        something, or their closing sweep took in a neighbour."""
        for kind, x, _others in misses:
            if kind == "taken":
                return True
            scenes[k].set_opening(spec.opening)
            if scenes[k].only_pads_touch(x):  # _pads_only(colliding_pairs(x)), by two broad-phase checks
                return True
        return False

    def accept(k, o, spec, T, q_grasp, q_pre, brush, made_from=None) -> bool:
        """Rank a collision-free grasp and keep it (False: its placement is unreachable); `made_from`: the grasp a
        swivelled one was made from (it ranks as that one)."""
        grasp_scene = scenes[k]
        T_pre = T @ trans(0.0, 0.0, -settings.approach_distance)
        if grasp_filter is not None and not grasp_filter(o, spec, T):
            st.no_placement += 1
            return False
        clearance = grasp_scene.min_distance(q_grasp, ("palm", "pad_a", "pad_b", "camera"), exclude=(f"obj:{names[k]}",))
        motion = float(np.max(np.abs(q_pre - q_current)))
        down = -T[2, 2]  # 1 = straight down
        score = min(clearance, 0.05) / 0.05 - 0.25 * motion / np.pi + 0.2 * down
        if is_fallback(inventory[o.obj_id], made_from or spec):
            score -= FALLBACK_PENALTY
        if brush:  # after every grasp whose pads keep clear of the neighbours
            score -= PAD_GIVE_PENALTY
            st.pad_contact += 1
        # The real surfaces (observed points of the item and of its neighbours) where a pad or the palm would be
        # at the grasp: the estimated pose is off there. Ranked last (below every grasp the points leave free).
        if k not in observed:
            observed[k] = _observed_near(o, objects)
        P = observed[k]
        hits = observed_in_tool((P - T[:3, 3]) @ T[:3, :3], spec.opening, gripper) if len(P) else 0
        if hits >= OBSERVED_HITS:
            score -= 10.0
            st.observed_in_tool += 1
        own = np.asarray(o.points, float).reshape(-1, 3)
        if len(own) >= WELL_OBSERVED and observed_in_grip((own - T[:3, 3]) @ T[:3, :3], spec.opening, gripper,
                                                          PAD_DEPTH) == 0:
            score -= 10.0
            st.empty_grip += 1
        out.append(Grasp(spec, o, T, q_grasp, q_pre, T_pre, float(score), float(clearance), pad_contacts=brush))
        st.feasible += 1
        return True

    # IK batched: the closed-form branches of the next IK_CHUNK candidates at every bite in one solve (~25x
    # cheaper per pose than one per call), solved as the checks reach them (most searches stop at `limit` long
    # before the end of `pending`)
    n_bites = len(BITES)
    solved: dict[int, list] = {}

    def ik_of(i: int) -> list:
        if i not in solved:
            # chunks start at multiples of IK_CHUNK whichever candidate asks first (the same batches, so the
            # same branches to the last bit, whether or not the candidates before it were kept in `memo`)
            start = i - i % IK_CHUNK
            chunk = pending[start:start + IK_CHUNK]
            sols = robot.ik_all_batch(np.concatenate([bites(T) for _, _, _, T in chunk]), q_current)
            for m in range(len(chunk)):
                solved[start + m] = sols[m * n_bites:(m + 1) * n_bites]
        return solved[i]

    for i, (k, o, spec, T) in enumerate(pending):
        if limit is not None and len(out) >= limit:
            break
        misses: list = []
        q_grasp, q_pre, Tg, brush, first_hit, first_taken, reached = fit(k, o, spec, T, misses, ik=lambda i=i: ik_of(i))
        if q_grasp is None and misses:
            near.append((k, o, spec, T, misses))
        if q_grasp is None and first_taken is not None:
            taken.append(first_taken)  # what crowds the item, if nothing fits
            if not reached:  # every bite takes in a neighbour (or is unreachable): a multi-object grasp
                st.multi_object += 1
                continue
        if q_grasp is None:
            if first_hit is not None and len(collided) < MAX_CROWD_CHECKS:
                collided.append(first_hit)
            if reached:
                st.in_collision += 1
            else:
                st.no_ik += 1
            continue
        accept(k, o, spec, Tg, q_grasp, q_pre, brush)
    # Second pass, only where no grasp fits as given: the grasps that missed narrowly (a pad's sweep grazing a
    # neighbour, or only the tool meeting one) swivelled a few degrees about their closing axis (SWIVELS). The
    # pads close on the same two contacts, the tool comes in from a slightly different direction: within what a
    # predefined grasp's placement already leaves to chance, so where the item's one or two grasps sit at the edge
    # of a check, a sub-millimetre change of its fitted pose no longer decides between some grasp and none.
    if not out:
        for k, o, spec, T, misses in near:
            if limit is not None and len(out) >= limit:
                break
            if not narrow(k, spec, misses):
                continue
            model = inventory[o.obj_id]
            for a in SWIVELS:
                T_obj_tcp = spec.T_obj_tcp @ rot_y(a)
                Ts = T @ rot_y(a)
                if Ts[2, 2] > settings.max_approach_up or not _swivel_fits(model, spec, T_obj_tcp):
                    continue
                swivelled = GraspSpec(tilted_name(spec.name, a), T_obj_tcp, spec.opening, spec.width)
                q_grasp, q_pre, Tg, brush, _, _, _ = fit(k, o, swivelled, Ts)
                if q_grasp is not None:
                    st.swivelled += 1
                    if accept(k, o, swivelled, Tg, q_grasp, q_pre, brush, made_from=spec):
                        break
    # Third pass, only where nothing fits even swivelled: the grasps whose open pads were all that met something
    # (a basin wall, a neighbour; nothing else of the arm or the tool) approached with the pads opened only
    # NARROW_SLACK wider than the item (narrowed_grasp): each pad comes down nearer the item, farther from what
    # is beside it. Less room for an error of the fitted pose, so only where the usual opening leaves none; the
    # next, narrower slack of NARROW_SLACKS only where the one before gave no grasp (the end of this function).
    slack = NARROW_SLACKS[narrow_level] if narrow_level < len(NARROW_SLACKS) else None
    if not out and slack is not None:
        for k, o, spec, T, misses in near:
            if limit is not None and len(out) >= limit:
                break
            if not pads_in_the_way(k, spec, misses):
                continue
            narrowed = narrowed_grasp(inventory[o.obj_id], spec, slack)
            if narrowed is None:
                continue
            q_grasp, q_pre, Tg, brush, _, _, _ = fit(k, o, narrowed, T)
            if q_grasp is not None:
                st.narrowed += 1
                accept(k, o, narrowed, Tg, q_grasp, q_pre, brush, made_from=spec)
    if out:
        out.sort(key=lambda g: -g.score)
        return out
    # Last pass, only where nothing fits even swivelled: a round item's grasps turned about its axis between their
    # copies (spun_grasps), every check run again. Its turn about the axis is unobservable, so which rim positions
    # its copies land on is chance; where a neighbour leaves a free window narrower than their spacing, it holds a
    # copy only for some turns. The failure reported stays that of the grasps as given.
    # Where the place filter tells cheaply that no spun grasp can reach a target (`grasp_filter.approachable`:
    # every release of every one would come from below), the spin selections could only fail: not run.
    round_items = [o for _, o in cands if getattr(inventory.models.get(o.obj_id), "is_rotationally_symmetric", False)
                   and not too_hidden(o, settings)]
    if not spin and round_items and _spins_may_place(round_items, inventory, grasp_filter):
        for frac in SPIN_STEPS:
            sub = GraspStats()
            res = select_grasps(robot, scene, inventory, objects, q_current, settings=settings, target=target,
                                grasp_filter=grasp_filter, stats=sub, limit=limit, avoid=avoid, q_rest=q_rest,
                                spin=frac, memo=memo, narrow_level=narrow_level)
            if not isinstance(res, PlanningFailure):
                st.spun += 1
                st.feasible += len(res)
                st.narrowed += sub.narrowed
                return res
    # Nothing fits with this slack, not even spun: the whole selection again with the next, narrower one (the
    # checks of the candidates already made are kept in `memo`). The failure reported stays this one's.
    if not spin and narrow_level + 1 < len(NARROW_SLACKS):
        sub = GraspStats()
        res = select_grasps(robot, scene, inventory, objects, q_current, settings=settings, target=target,
                            grasp_filter=grasp_filter, stats=sub, limit=limit, avoid=avoid, q_rest=q_rest,
                            memo=memo, narrow_level=narrow_level + 1)
        if not isinstance(res, PlanningFailure):
            st.feasible += len(res)
            st.narrowed += sub.narrowed
            st.spun += sub.spun
            return res
    st.crowded_by = _crowded_by(scenes, names, collided, taken, objects)
    details = st.__dict__.copy()
    if not any_model or st.considered == 0:
        return NoGraspableObject("no candidate object with grasps (occluded, unknown model or no grasps)", details)
    if st.no_placement > 0:
        return NoFeasiblePlacement(
            "collision-free grasps exist but none can also reach the requested placement "
            "(e.g. regrasp via the drop zone)", details)
    if st.in_collision + st.multi_object > 0:
        return NoCollisionFreeGrasp("every reachable grasp collides or takes in another object", details)
    if st.from_below == st.considered:
        return NoIK("every grasp of the object would approach from below (e.g. an upside-down bowl)", details)
    return NoIK("no grasp pose is reachable", details)
