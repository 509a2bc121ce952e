"""Plates nested under a found plate, counted one nest level at a time.

Copies of one plate nested in each other lie one nest pitch apart along their axis (a side plate on a side plate
~5-7 mm). The top plate hides all of each lower plate but a thin band of its rim's outer edge, a few millimetres
under the rim above: at the splitting tolerance (0.8 voxel) the top plate's pose explains that band, so nothing is
left over to fit, and a nest of four was perceived as one or two plates (the lower plates' rims under 3 % visible).

So after the poses of a scan are final, each plate pose is asked whether a copy of its model lies one nest level
under it: the pose shifted down its axis (the way that points down) by 0.9-1.75 of the model's nest pitch, in
0.5 mm steps (a settled nest sits a little looser than the model's pitch, never tighter). A level is supported by
map points on no pose's surface (NEST_TOL: the plates above, the items around) that lie on the copy's surface at
the sensor's precision (NEST_TOL, facing the same way) in its rim's outer band (RIM_SHARE of its radius or more):
the band beside the plate above. The shift with the most such points is refitted on them (ICP with the axis held:
a lower plate settles up to a centimetre or so off-centre) and kept where

- it has at least NEST_MIN_POINTS of its own points, spread at least NEST_MIN_ARC around the axis (a rim band, not
  a lump of something else touching the plate),
- it puts no model surface where the depth sees through it (the Scorer's free space at most NEST_MAX_FREE: a
  single plate has nothing under it, and the copy's rim would stand in the air the cameras see through),
- and none of its model inside known solid matter (a plate on the floor has no plate under it).

A level kept becomes a pose (its own points taken from the plate above) and is itself asked for the level under
it; a level that a pose of the same model found before in the nest has on its surface (half its points within
SAME_PLATE_TOL) is that plate, and the chain stops there (that pose is asked for its own level).
A plate standing on its edge (axis within NEST_MIN_UP of horizontal) has no "under". Base frame, metres.
"""

from __future__ import annotations

import logging

import numpy as np

from kitchenbot.perception.register import Hypothesis, Scorer, icp_to_model, on_surface
from kitchenbot.perception.verify import Verification
from kitchenbot.transforms import inv

log = logging.getLogger(__name__)

#: which classes are counted level by level (bowls and cups are not tried: a nested bowl or cup shows more of
#: itself and is found by the stacking hypotheses of the pose search)
NEST_CLASSES = ("plate",)
#: a point within this of the copy's surface (facing the same way) supports it; it must also be farther than this
#: from every pose found (m; the sensor's precision, as the fine check's 3 mm)
NEST_TOL = 0.0025
#: shifts tried, in the model's nest pitch, and the step between them (m)
NEST_SHIFTS = (0.9, 1.75)
NEST_STEP = 0.0005
#: a supporting point lies this share of the model's radius or more from the copy's axis: a lower plate of a nest
#: shows the outer band of its rim, nothing else (points across a plate a little off its fit are not a level)
RIM_SHARE = 0.85
#: how much wider and longer than where a level's rim band can be the candidate ring is (m): the refit's 1.5 cm
#: across, its 7.5 mm reach, the 6 mm neighbourhood of a point's normal
RING_MARGIN = 0.03
#: fewest supporting points of a level, and how far round the axis they must reach (rad)
NEST_MIN_POINTS = 20
NEST_MIN_ARC = np.radians(45.0)
#: the most free space (share of the copy's judged visible surface the depth sees through) a level may claim
NEST_MAX_FREE = 0.1
#: share of the copy's model points inside known solid matter that rules it out
NEST_MAX_SOLID = 0.01
#: |axis . up| under this: the plate stands on its edge, no level under it is looked for
NEST_MIN_UP = 0.3
#: most levels under one plate
NEST_MAX_LEVELS = 6
#: a level whose points lie within this of a pose of its model found before is that plate (m)
SAME_PLATE_TOL = 0.003
#: bins of the arc test (rad)
ARC_BIN = np.radians(15.0)


def add_nest_levels(perceiver, m, views, kept: list[list], next_iid: int) -> int:
    """Append to `kept` ([hyp, iid, own] per pose) a pose per nest level the data supports under each plate pose,
    taking its own points from the pose above; `next_iid`: the first instance id no instance of the scan has (a
    level is an instance of its own); returns how many were added."""
    up = perceiver._up()
    if up is None:
        up = np.array([0.0, 0.0, 1.0])
    vox = perceiver.settings.voxel_size
    inside = perceiver._inside_solid(perceiver._up())
    added = 0
    todo = [(k, 0) for k in kept if perceiver.inventory[k[0].obj_id].cls in NEST_CLASSES]
    while todo:
        above, depth = todo.pop(0)
        hyp = above[0]
        model = perceiver.inventory[hyp.obj_id]
        if model.nest_pitch <= 0:
            continue
        level = _level_under(perceiver, m, views, kept, hyp, up, inside, vox)
        if level is None:
            continue
        new_hyp, pts = level
        above[2] = np.setdiff1d(above[2], pts)
        entry = [new_hyp, next_iid, pts]
        next_iid += 1
        kept.append(entry)
        added += 1
        if depth + 1 < NEST_MAX_LEVELS:
            todo.insert(0, (entry, depth + 1))
    return added


def _level_under(perceiver, m, views, kept, hyp: Hypothesis, up: np.ndarray, inside, vox: float):
    model = perceiver.inventory[hyp.obj_id]
    entry = perceiver.database[hyp.obj_id]
    T = hyp.T_base_obj
    axis = T[:3, 2]
    if abs(axis @ up) < NEST_MIN_UP:
        return None
    down = -axis if axis @ up > 0 else axis
    # candidate points: map points within the model's reach of the pose, on no pose's surface, in the ring round
    # its axis where a level's rim band can lie (RING_MARGIN wider and longer: the refit's reach across, its
    # tolerance, and the neighbours that set each point's normal)
    reach = entry.reach + 2 * model.nest_pitch * NEST_SHIFTS[1]
    idx = np.nonzero(((m.points - T[:3, 3]) ** 2).sum(axis=1) <= reach ** 2)[0]
    r_model = float(np.linalg.norm(model.points[:, :2], axis=1).max())
    r_rim = RIM_SHARE * r_model
    q = (m.points[idx] - T[:3, 3]) @ T[:3, :3]
    rad = np.linalg.norm(q[:, :2], axis=1)
    idx = idx[(rad >= r_rim - RING_MARGIN) & (rad <= r_model + RING_MARGIN) &
              (np.abs(q[:, 2]) <= float(np.abs(model.points[:, 2]).max()) + NEST_SHIFTS[1] * model.nest_pitch + RING_MARGIN)]
    if len(idx) < NEST_MIN_POINTS:
        return None
    P = m.points[idx]
    free = np.ones(len(idx), bool)
    for k in kept:
        free &= ~on_surface(P, None, perceiver.database[k[0].obj_id], k[0].T_base_obj, NEST_TOL)
    idx, P = idx[free], P[free]
    rim = np.nonzero(_on_rim(P, T, r_rim))[0]  # a shift along the axis keeps each point's distance from it
    if len(idx) < NEST_MIN_POINTS or len(rim) < NEST_MIN_POINTS // 2:
        return None
    N = perceiver._map_normals(m, idx)
    best = None
    for s in np.arange(NEST_SHIFTS[0] * model.nest_pitch, NEST_SHIFTS[1] * model.nest_pitch + 1e-9, NEST_STEP):
        C = T.copy()
        C[:3, 3] += s * down
        on = np.zeros(len(P), bool)
        on[rim] = on_surface(P[rim], N[rim], entry, C, NEST_TOL)
        if best is None or on.sum() > best[1].sum():
            best = (C, on)
    C, on = best
    log.debug("nest level under %s: best shift %.1f mm, %d points", hyp.obj_id,
              1000 * ((C[:3, 3] - T[:3, 3]) @ down), on.sum())
    if on.sum() < NEST_MIN_POINTS // 2:
        return None
    # Refit on its own points, the axis held (a lower plate settles up to a centimetre off-centre: a copy on the
    # axis of the one above then meets its rim band on one side only).
    near = on_surface(P, N, entry, C, 3 * NEST_TOL) & _on_rim(P, C, r_rim - 2 * NEST_TOL)
    T_obj_base = icp_to_model(P[near], entry, inv(C), (3 * NEST_TOL, 2 * NEST_TOL, NEST_TOL), iters=10,
                              upright=True, qn=N[near], symmetric=model.is_rotationally_symmetric)
    C2 = inv(T_obj_base)
    on2 = on_surface(P, N, entry, C2, NEST_TOL) & _on_rim(P, C2, r_rim)
    if on2.sum() >= on.sum() and _between(C2, T, down, model.nest_pitch):
        C, on = C2, on2
    log.debug("nest level refitted: %d points, arc %.0f deg", on.sum(), np.degrees(_arc(P[on], C)))
    if on.sum() < NEST_MIN_POINTS or _arc(P[on], C) < NEST_MIN_ARC:
        return None
    own = idx[on]
    if any(k[0].obj_id == hyp.obj_id and k[0] is not hyp and _same_plate(perceiver, m, k[0], C, own)
           for k in kept):
        return None
    scorer = Scorer(entry, m.points[own], views, vox, inside_solid=None, depths=perceiver._depths)
    score, or_q, or_m, fs, vis = scorer(C)
    log.debug("nest level scored: free space %.3f, seen %.3f", fs, or_m)
    if fs > NEST_MAX_FREE:
        return None
    if inside is not None:
        mp = entry.dense_points @ C[:3, :3].T + C[:3, 3]
        log.debug("nest level inside solid %.3f", inside(mp).mean())
        if inside(mp).mean() > NEST_MAX_SOLID:
            return None
    ver = Verification(seen=or_m, explained=1.0, free_space=fs, normals=1.0)
    return Hypothesis(hyp.obj_id, C, score, or_q, or_m, fs, vis, "nest-level", ver), own


def _between(C: np.ndarray, T: np.ndarray, down: np.ndarray, pitch: float) -> bool:
    """Whether the refitted copy stays a level under the pose above: its shift along the axis within the shifts
    searched, across it under 1.5 cm (stacks land off-centre)."""
    d = C[:3, 3] - T[:3, 3]
    along = d @ down
    across = np.linalg.norm(d - along * down)
    return NEST_SHIFTS[0] * pitch <= along <= NEST_SHIFTS[1] * pitch and across <= 0.015


def _same_plate(perceiver, m, other: Hypothesis, C: np.ndarray, own: np.ndarray) -> bool:
    """Whether a pose of the same model found before is the plate of this level: in the nest (within 1.5 nest
    pitches along the axis, 2 cm across), with half or more of the level's points on its surface (3 mm, either
    side: a lower plate's pose fitted a few millimetres off along its axis still has its rim band there)."""
    model = perceiver.inventory[other.obj_id]
    d = other.T_base_obj[:3, 3] - C[:3, 3]
    along = d @ C[:3, 2]
    if abs(along) > 1.5 * model.nest_pitch or np.linalg.norm(d - along * C[:3, 2]) > 0.02:
        return False
    if abs(along) < 0.5 * model.nest_pitch:
        return True
    on = on_surface(m.points[own], None, perceiver.database[other.obj_id], other.T_base_obj, SAME_PLATE_TOL)
    return bool(on.mean() >= 0.5)


def _on_rim(P: np.ndarray, C: np.ndarray, r_rim: float) -> np.ndarray:
    """Which points lie at least `r_rim` from the posed copy's axis (its rim's outer band)."""
    q = (P - C[:3, 3]) @ C[:3, :3]
    return np.linalg.norm(q[:, :2], axis=1) >= r_rim


def _arc(P: np.ndarray, C: np.ndarray) -> float:
    """How far round the copy's axis its points reach (rad): the occupied ARC_BIN bins' total."""
    q = (P - C[:3, 3]) @ C[:3, :3]
    a = np.arctan2(q[:, 1], q[:, 0])
    bins = np.unique(np.floor((a + np.pi) / ARC_BIN).astype(int))
    return len(bins) * ARC_BIN
