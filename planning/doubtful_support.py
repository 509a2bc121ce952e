"""Lifting an item off a support whose perceived pose is poorly supported by what the camera saw of it.

A separating lift (Planner._separating_lift) moves the held item first along the direction that parts it from the
*perceived poses* of what it rests in, then up. Where such a support was seen only in small part, its fitted pose
may be centimetres off while still explaining every one of its points (an upside-down bowl nested under another,
7 % of it seen, fitted 6.6 cm away lying on its side): the leg that parts the held item from that pose drives it
sideways across the real support. Such a pose may not choose the lift's direction:

- `pose_doubtful`: a support seen in less than DOUBTFUL_SEEN of what a fully visible item shows, or whose pose
  explains its own points worse than DOUBTFUL_VERIFIED (perception/verify.py), is doubtful.
- `own_axis_directions`: the directions that lift the held item off whatever it rests on without knowing where that
  is: along its own axis (upward, as it was stacked) and in a cone about it, then straight up.
- `approaches_points`: the lift is checked against what the camera did see of the doubtful support, its own points:
  no point may come nearer the swept held item than it was at the grasp (less POINT_APPROACH_TOL) while within
  POINT_REACH of it (a touch of the seen surface, not a pass near it: a bowl lifted out of a bowl slides past the
  lower wall's seen points within millimetres on every clean lift).
- POSE_ERROR / NARROWING_TOL: a doubtful support's fitted pose is still checked against the held item on every lift
  (Planner._may_meet_doubtful_again), allowing for its error: a gap to it that narrows again after parting while
  within POSE_ERROR of the start's counts as a contact that may come back (in the world the two touch at the start;
  the support's wall may be that much nearer than its fit says).
"""

from __future__ import annotations

import coal
import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.collision import coal_transform

# share of a fully visible item's visible fraction (settings.visible_fraction_unoccluded) below which a support's
# fitted pose is not trusted to choose a direction: under a third of what can be seen, a bowl's fit is free to
# turn and slide along the part it saw
DOUBTFUL_SEEN = 1 / 3
# ObjectPose.verification below which a pose leaves its own points unexplained
DOUBTFUL_VERIFIED = 0.9
# degrees: the cone about the held item's own axis in which it is lifted off a doubtful support
OWN_AXIS_CONES = (10.0, 20.0)
OWN_AXIS_AZIMUTHS = 8
# m: how much nearer than at the grasp a seen point of the doubtful support may come (depth noise, sampling)
POINT_APPROACH_TOL = 0.0005
# m: how near the swept held item a seen point must be to count as touched (approaches_points). With the collision
# margin (1 cm) every lift of a bowl out of a bowl it is tilted in was refused: the held bowl's outer wall passes the
# lower bowl's seen rim within 2 to 3 mm on the clean lifts as on the colliding ones.
POINT_REACH = 0.001
# m: how far a doubtful support's surface may be from where its fitted pose puts it, near the held item: a bowl seen
# 11 %, fitted 1.8 mm and 3 degrees off, was 1.6 mm nearer the held bowl's wall than the fit said where the two met
# again in the world
POSE_ERROR = 0.003
# m: a narrowing of the gap to a doubtful support that counts (the overlap of two meshes, measured along a lift,
# wobbles by up to 0.07 mm where nothing moves nearer; the narrowing where the lift above met the bowl again: 0.44 mm)
NARROWING_TOL = 0.0001
# m: a support's seen point within this of the held item's fitted surface at the grasp is, as far as the camera can
# tell, on the held item (segmentation hands a nested item's points near the rim it rests in to either one; depth
# noise and the fit are about a millimetre): not checked, it moves with the item. A support the lift would drive
# into is seen as a patch, and its points farther off than this are approached too.
POINT_ON_HELD = 0.0015
# most points of a support checked (nearest the held item first)
MAX_POINTS = 400
# m: the held item's travel between the poses at which the points are checked
POINT_CHECK_STEP = 0.002


def pose_doubtful(o: ObjectPose, visible_unoccluded: float) -> bool:
    """Whether `o`'s fitted pose is too poorly supported by what was seen of it to choose a lift's direction."""
    seen = float(o.visible_fraction) / max(float(visible_unoccluded), 1e-9)
    return seen < DOUBTFUL_SEEN or float(o.verification) < DOUBTFUL_VERIFIED


def own_axis_directions(T_base_held: np.ndarray) -> list[np.ndarray]:
    """Unit lift directions (base frame) that need no support's pose: the held item's own axis (the upward one of
    +-z), then rings of OWN_AXIS_CONES about it (those rising at least 45 degrees), then straight up where it is
    not already among them."""
    axis = np.asarray(T_base_held, float)[:3, 2]
    if abs(axis[2]) < 1e-9:
        return [np.array([0.0, 0.0, 1.0])]
    axis = axis * np.sign(axis[2])
    axis = axis / np.linalg.norm(axis)
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    out = [axis] if axis[2] >= np.sin(np.radians(45.0)) else []
    for cone in OWN_AXIS_CONES:
        c, s = np.cos(np.radians(cone)), np.sin(np.radians(cone))
        for k in range(OWN_AXIS_AZIMUTHS):
            a = 2 * np.pi * k / OWN_AXIS_AZIMUTHS
            d = c * axis + s * (np.cos(a) * e1 + np.sin(a) * e2)
            if d[2] >= np.sin(np.radians(45.0)):
                out.append(d / np.linalg.norm(d))
    up = np.array([0.0, 0.0, 1.0])
    if all(float(d @ up) < np.cos(np.radians(2.0)) for d in out):
        out.append(up)
    return out


def _point_distances(held_bvh, T_base_held: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance (m) of each base-frame point to the held item's mesh at T_base_held (0 where inside it)."""
    T_h = coal_transform(T_base_held)
    sphere = coal.Sphere(1e-5)
    out = np.empty(len(points))
    T_p = np.eye(4)
    for k, p in enumerate(points):
        T_p[:3, 3] = p
        out[k] = max(0.0, coal.distance(held_bvh, T_h, sphere, coal_transform(T_p), coal.DistanceRequest(),
                                        coal.DistanceResult()))
    return out


def _thinned(T_path: list[np.ndarray]) -> list[np.ndarray]:
    """The poses of `T_path` at which the item has moved POINT_CHECK_STEP or more (by its origin) since the last one
    kept, the first and the last always."""
    out = [np.asarray(T_path[0], float)]
    for T in T_path[1:-1]:
        if np.linalg.norm(np.asarray(T, float)[:3, 3] - out[-1][:3, 3]) >= POINT_CHECK_STEP:
            out.append(np.asarray(T, float))
    out.append(np.asarray(T_path[-1], float))
    return out


def approaches_points(held_bvh, T_path: list[np.ndarray], points: np.ndarray, near: float) -> bool:
    """Whether the held item, moved through the base-frame poses `T_path` (the first: at the grasp), brings one of
    a support's seen `points` nearer to it than it was at the grasp (by more than POINT_APPROACH_TOL) while that
    point is within `near` (the collision margin) of it. Points within POINT_ON_HELD of the item at the grasp are
    its own surface and not checked. Only points within `near` plus the path's travel of the item at the grasp can
    come within `near`; of those at most MAX_POINTS, the nearest."""
    P = np.asarray(points, float).reshape(-1, 3)
    if not len(P) or len(T_path) < 2:
        return False
    T_path = _thinned(T_path)
    c = np.array([np.asarray(T, float)[:3, 3] for T in T_path])
    travel = float(np.max(np.linalg.norm(c - c[0], axis=1)))
    P = P[np.argsort(np.linalg.norm(P - c[0], axis=1))[:4 * MAX_POINTS]]  # the nearest the item's centre
    d0 = _point_distances(held_bvh, T_path[0], P)
    off_held = d0 > POINT_ON_HELD  # those nearer are on the held item as far as the camera can tell
    P, d0 = P[off_held], d0[off_held]
    nearest = np.argsort(d0)[:MAX_POINTS]
    nearest = nearest[d0[nearest] <= near + travel]
    if not len(nearest):
        return False
    P, d0 = P[nearest], d0[nearest]
    limit = np.minimum(d0 - POINT_APPROACH_TOL, near)
    for T in T_path[1:]:
        if np.any(_point_distances(held_bvh, T, P) < limit):
            return True
    return False
