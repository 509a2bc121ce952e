"""The lift's fallbacks, in the order plan_pick tries them, as one generator (`lift_fallbacks`): straight up;
along the item's own axis when it rests tilted (as it was stacked); tilted away from the basin walls when it
is near one; and, once all of those ran into perceived items, tilted away from the items they ran into. Where
those run into them too, a lift in two legs (`sidesteps`): out from under them nearly level, then straight up.

Each direction comes with `along`: whether it is straight up or along the item's axis (those lifts may keep
the fingers' and the held item's start contacts for a few centimetres; see Planner.plan_pick).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from kitchenbot.planning.grasps import object_name


def tilted_axis(T_base_obj: np.ndarray | None) -> np.ndarray | None:
    """The item's axis (upward, unit) when it rests tilted by 5 to 60 degrees, else None."""
    if T_base_obj is None:
        return None
    axis = np.asarray(T_base_obj, float)[:3, 2]
    axis = axis * np.sign(axis[2]) if abs(axis[2]) > 1e-9 else axis
    if np.cos(np.radians(60)) <= axis[2] <= np.cos(np.radians(5)):
        return axis / np.linalg.norm(axis)
    return None


def base_directions(sink_lo_hi, p: np.ndarray, T_base_obj: np.ndarray | None = None, *,
                    away_from_walls: bool = True) -> list[np.ndarray]:
    """Unit lift directions from a grasp at `p` (base frame): up; along the object's axis when it rests tilted
    (5 to 60 degrees; the upward one of +-z); then (`away_from_walls`) tilted towards the sink's middle."""
    lo, hi = sink_lo_hi
    to_mid = (np.asarray(lo, float) + np.asarray(hi, float))[:2] / 2 - np.asarray(p, float)[:2]
    out = [np.array([0.0, 0.0, 1.0])]
    axis = tilted_axis(T_base_obj)
    if axis is not None:
        out.append(axis)
    if not away_from_walls or np.linalg.norm(to_mid) < 1e-6:
        return out
    a0 = float(np.arctan2(to_mid[1], to_mid[0]))
    for tilt, da in ((30.0, 0.0), (30.0, 60.0), (30.0, -60.0), (50.0, 0.0)):
        t, a = np.radians(tilt), a0 + np.radians(da)
        out.append(np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)]))
    return out


def between_up_and_axis(axis: np.ndarray, fractions=(1 / 3, 2 / 3)) -> list[np.ndarray]:
    """Unit directions between straight up and a tilted item's `axis` (at these fractions of its tilt, in its
    vertical plane): an item resting tilted in a nest whose straight-up lift sweeps its side into the rim below,
    and whose lift along its own axis runs into what it leans towards, comes out in between."""
    axis = np.asarray(axis, float)
    tilt = float(np.arccos(np.clip(axis[2], -1.0, 1.0)))
    h = axis[:2] / max(float(np.linalg.norm(axis[:2])), 1e-9)
    out = []
    for f in fractions:
        t = f * tilt
        out.append(np.array([np.sin(t) * h[0], np.sin(t) * h[1], np.cos(t)]))
    return out


def _away_angle(centre: np.ndarray, objects, names: set[str], unknown=()) -> float | None:
    """Heading (rad, base frame) away from the named perceived objects' centres and from the centroid of
    `unknown` (base-frame points: map voxels no perceived object explains that the lifts ran into; they count as
    one more object), or None."""
    away = np.zeros(2)
    centres = [np.asarray(o.T_base_obj, float)[:2, 3] for k, o in enumerate(objects) if object_name(o, k) in names]
    unknown = np.asarray(unknown, float).reshape(-1, 3)
    if len(unknown):
        centres.append(unknown[:, :2].mean(axis=0))
    for c in centres:
        v = centre[:2] - c
        if np.linalg.norm(v) > 1e-3:
            away += v / np.linalg.norm(v)
    if np.linalg.norm(away) < 1e-6:
        return None
    return float(np.arctan2(away[1], away[0]))


def directions_away(centre: np.ndarray, objects, names: set[str], have: list[np.ndarray],
                    tilts=(30.0, 45.0), turns=(0.0, 40.0, -40.0), unknown=()) -> list[np.ndarray]:
    """Unit lift directions tilted away (horizontally) from the named perceived objects' centres (and the
    `unknown` points', see _away_angle), not within 10 degrees of one in `have`."""
    a0 = _away_angle(centre, objects, names, unknown)
    if a0 is None:
        return []
    out: list[np.ndarray] = []
    for tilt in tilts:
        for da in turns:
            t, a = np.radians(tilt), a0 + np.radians(da)
            d = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])
            if all(float(d @ h) < np.cos(np.radians(10.0)) for h in [*have, *out]):
                out.append(d)
    return out


# A lift of this item that a protective stop cut short (the executive let the item go where it was taken and
# remembers the direction the tool moved in at the stop): the lifts within this angle (rad) of it are the same
# lift, and are not planned again; instead, these tilts (degrees from straight up) at AROUND_TURNS headings.
STOPPED_LIFT_ANGLE = np.radians(10.0)
AROUND_TILTS = (25.0, 45.0)
AROUND_TURNS = 8


def repeats_stopped(d: np.ndarray, stopped) -> bool:
    """Whether moving along `d` (a unit direction, or any offset) repeats one of the `stopped` lift directions
    (unit, base frame): within STOPPED_LIFT_ANGLE of it."""
    d = np.asarray(d, float)
    n = float(np.linalg.norm(d))
    if n < 1e-9:
        return False
    return any(float(d @ np.asarray(s, float)) / n >= np.cos(STOPPED_LIFT_ANGLE) for s in stopped)


def directions_around(p: np.ndarray, sink_lo_hi, have: list[np.ndarray]) -> list[np.ndarray]:
    """Unit lift directions tilted by AROUND_TILTS at AROUND_TURNS headings, the first heading towards the sink's
    middle, not within 10 degrees of one in `have`: the lifts tried where the item's usual one stopped (nothing
    says which side what it met is on)."""
    lo, hi = sink_lo_hi
    to_mid = (np.asarray(lo, float) + np.asarray(hi, float))[:2] / 2 - np.asarray(p, float)[:2]
    a0 = float(np.arctan2(to_mid[1], to_mid[0])) if np.linalg.norm(to_mid) > 1e-6 else 0.0
    out: list[np.ndarray] = []
    for tilt in AROUND_TILTS:
        for k in range(AROUND_TURNS):  # alternating either side of the heading to the middle: 0, +1, -1, +2, ...
            turn = (k + 1) // 2 * (1 if k % 2 else -1) * 2 * np.pi / AROUND_TURNS
            t, a = np.radians(tilt), a0 + turn
            d = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])
            if all(float(d @ h) < np.cos(np.radians(10.0)) for h in [*have, *out]):
                out.append(d)
    return out


def lift_fallbacks(sink_lo_hi, T_base_obj: np.ndarray, objects, ran_into: set[str], *,
                   near_wall: bool, ran_into_unknown: set | None = None,
                   stopped: tuple = ()) -> Iterator[tuple[np.ndarray, bool]]:
    """(direction, along) for the lift of the item at T_base_obj, in the order to try them. `ran_into` is the
    caller's set of perceived objects the lifts tried so far ran into: read when the base directions are used up
    (a cup under the rim of a glass leaning over it slips out from under it, tilted away from the glass).
    `ran_into_unknown`: the caller's set of map voxels (base-frame points) no perceived object explains that those
    lifts ran into (an item perception did not recognise, leaning on this one): read likewise, they count as one
    more item to tilt away from. `stopped`: directions (unit, base frame) of lifts of this item a protective stop
    cut short: no direction within STOPPED_LIFT_ANGLE of one is given, and after the others come
    directions_around the item."""
    centre = np.asarray(T_base_obj, float)[:3, 3]
    base = base_directions(sink_lo_hi, centre, T_base_obj, away_from_walls=near_wall)
    tilted = tilted_axis(T_base_obj) is not None

    def ok(d):
        return not repeats_stopped(d, stopped)

    for k, d in enumerate(base):
        if ok(d):
            yield d, k == 0 or (k == 1 and tilted)
        if k == 1 and tilted:
            for d_between in between_up_and_axis(d):
                if ok(d_between):
                    yield d_between, True
    unknown = sorted(ran_into_unknown or ())
    away: list[np.ndarray] = []
    if ran_into or unknown:
        away = directions_away(centre, objects, ran_into, base, unknown=unknown)
        for d in away:
            if ok(d):
                yield d, False
    if len(stopped):
        for d in directions_around(centre, sink_lo_hi, [*base, *away]):
            if ok(d):
                yield d, False


# The first leg of a sideways-then-up lift: (m level, m up). An item under something that overhangs it (a plate's
# rim leaning over a cup, a bowl tilted over a glass) runs into it on every line that rises at once, even tilted
# 45 degrees; moved out from under it nearly level first, it then goes straight up past it.
SIDESTEPS = ((0.04, 0.01), (0.07, 0.015))


def sidesteps(centre: np.ndarray, objects, ran_into: set[str], turns=(0.0, 45.0, -45.0), unknown=()) -> list[np.ndarray]:
    """First legs (base-frame offsets, m) of sideways-then-up lifts away from the perceived objects the other
    lifts ran into (and the `unknown` map voxels they ran into, see _away_angle; straight away from them, and
    turned by `turns` degrees), shortest first; [] when none."""
    a0 = _away_angle(centre, objects, ran_into, unknown)
    if a0 is None:
        return []
    out = []
    for level, up in SIDESTEPS:
        for da in turns:
            a = a0 + np.radians(da)
            out.append(np.array([level * np.cos(a), level * np.sin(a), up]))
    return out


# A lift that first opens the held item's start contacts (separating_leg): the least rise (sine of the elevation) of
# the directions tried, the step (m) each is scored at, and the leg lengths (m) tried for "clear", shortest first.
SEPARATE_MIN_RISE = np.sin(np.radians(20.0))
SEPARATE_STEP = 0.006
SEPARATE_LEGS = (0.01, 0.02, 0.03)


def _directions(min_rise: float, n_az: int = 12, elevations=(90.0, 70.0, 50.0, 35.0, 20.0)) -> list[np.ndarray]:
    out = []
    for el in elevations:
        e = np.radians(el)
        if np.sin(e) < min_rise - 1e-9:
            continue
        for k in range(1 if el >= 90.0 else n_az):
            a = 2 * np.pi * k / n_az
            out.append(np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]))
    return out


def separating_legs(gap, others: list, clear: float) -> list[np.ndarray]:
    """First legs (base-frame offsets, m) of lifts that open the held item's start contacts at once, best first:
    along each rising direction in which a short move (SEPARATE_STEP) takes the item away from all those it
    touches (`others`, opaque to this function; `gap(offset, other)` -> the item's distance to `other` moved by
    `offset`, 0 or less where they touch), ranked by that distance, each as far as the first of SEPARATE_LEGS
    after which it is `clear` of all of them (the longest where none is); [] where no direction parts them.
    A nested item (a bowl tilted in another) lifted straight up slides along the surface it rests on: in the
    world the two part and meet again by a fraction of a millimetre, finer than the fitted poses tell; moved
    along the contact's normal first, they part at once. Sampled directions, not the contact's normal from the
    meshes: mesh-mesh contact normals of overlapping fitted poses are per triangle pair and scatter. All the
    parting directions, not only the best: the best may run into something else (a bowl nobody perceived under
    the one the item nests in, seen only as map points), and the caller checks each leg against everything."""
    if not others:
        return []
    scored = []
    for k, d in enumerate(_directions(SEPARATE_MIN_RISE)):
        s = min(gap(SEPARATE_STEP * d, o) for o in others)
        if s > 1e-6:
            scored.append((-s, k, d))
    out = []
    for _, _, d in sorted(scored, key=lambda r: r[:2]):
        for length in SEPARATE_LEGS:
            if min(gap(length * d, o) for o in others) >= clear:
                break
        out.append(length * d)
    return out

