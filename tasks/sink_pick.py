"""sink-pick: take every object out of the sink and set it down in the counter drop zone.

Targets, the way a person clears a sink onto the counter:
- plates go onto a pile of plates already in the zone (same model first, a smaller plate onto a bigger one next),
  a new pile only when there is none yet (or the piles are too high); bowls and cups nest into a pile of their
  own model the same way; glasses and mugs stand on the counter side by side (they do not nest safely);
- a pile's height is tracked from what was placed on it (each item rests its nesting height above the one
  below, or on the top of a different plate);
- free spots on the counter are searched on a 2 cm grid, 1 cm apart from what is there, and room is kept for the
  first plate / bowl / cup pile while such items are still in the sink (a cup must not take the only spot a
  dinner plate fits in); of the free spots offered (a few more than asked, each in its own part of the zone),
  those leaving room for the most items still to come go first;
- only when the counter is full does a glass or mug stand on top of a plate pile, and only once no plate is
  left to come (it would block the pile);
- items that do not lie upright in the sink may also be set down the way they lie.

Success: no object left in the sink (confirmed by consecutive scans) and each placement verified (gone from the
sink, seen at its spot).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.placement import nesting_height
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget
from kitchenbot.tasks.base import (
    CLEARANCE,
    _overlaps,
    Holdings,
    Placed,
    Task,
    area_spots,
    as_is,
    footprint,
    upright,
)
from kitchenbot.world.attitude import faces_down, is_upright
from kitchenbot.world.gripper import DROP_HEIGHT
from kitchenbot.world.inventory import ObjectModel

PILE_CLASSES = ("plate", "bowl", "cup")  # items a person piles up on the counter
PILE_MAX_TOP = 0.20  # m above the counter: a pile higher gets unstable, and the tool must still reach over it
SPARE_SPOTS = 3  # counter spots offered beyond those asked for (farther ones, when the nearest are out of reach)
LOOKAHEAD_ITEMS = 8  # items still to come whose room a counter spot is chosen to keep (the largest ones)
PILE_CLEARANCE = 0.015  # m above a pile where the item is let go: its pose in the gripper is as good as perception
# from the zone's far corner (tests/tasks/test_sink_pick_drop_zone.py)


def levelled(R: np.ndarray, round_: bool = False) -> np.ndarray:
    """R turned by the smallest rotation that makes the item's axis vertical the way it faces (up or down): its
    yaw is kept as far as it can be. A `round_` item (rotationally symmetric) loses its turn about its axis, which
    changes nothing but keeps its footprint box the disc's square."""
    z = R[:, 2]
    goal = np.array([0.0, 0.0, 1.0 if z[2] >= 0 else -1.0])
    if round_:
        return np.diag([1.0, np.sign(goal[2]), goal[2]])
    axis = np.cross(z, goal)
    s, c = float(np.linalg.norm(axis)), float(z @ goal)
    if s < 1e-9:
        return np.array(R, float)
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix() @ R


_FLOOR_RADIUS: dict[int, float] = {}


def floor_radius(model: ObjectModel, rise: float = 0.003, step: float = 0.005) -> float:
    """Radius (m) of the flat floor of a dish: out to where its top surface rises more than `rise` above the
    middle (a plate's rim), from the mesh's highest vertex per `step`-wide ring. Cached per model id."""
    if model.obj_id not in _FLOOR_RADIUS:
        V = np.asarray(model.mesh.vertices)
        r = np.hypot(V[:, 0], V[:, 1])
        floor = float(V[r < step, 2].max()) if np.any(r < step) else float(V[:, 2].min())
        rad = float(r.max())
        for r0 in np.arange(0.0, rad, step):
            ring = (r >= r0) & (r < r0 + step)
            if np.any(ring) and float(V[ring, 2].max()) > floor + rise:
                rad = float(r0)
                break
        _FLOOR_RADIUS[model.obj_id] = rad
    return _FLOOR_RADIUS[model.obj_id]


def _piles(placed: list[Placed], tol: float = 0.03) -> list[list[Placed]]:
    """Placed items grouped into piles (bottom first): items centred within `tol` of each other (a pile is built
    centred on its bottom item; a neighbour whose footprint merely overlaps is not part of it)."""
    piles: list[list[Placed]] = []
    for p in sorted(placed, key=lambda p: p.T_base_obj[2, 3]):
        for pile in piles:
            if np.linalg.norm(p.T_base_obj[:2, 3] - pile[0].T_base_obj[:2, 3]) <= tol:
                pile.append(p)
                break
        else:
            piles.append([p])
    return piles


def pile_pose(model: ObjectModel, pile: list[Placed]) -> np.ndarray | None:
    """`model` upright on top of `pile` (centred on its top item): nested by its nesting height into the same
    model, else resting on the top item's top. None when the top item is not upright or the pile is too high."""
    top = pile[-1]
    if not is_upright(top.T_base_obj):
        return None
    T = upright(model, top.T_base_obj[:2, 3], 0.0)
    if top.obj_id == model.obj_id:
        T[2, 3] = top.T_base_obj[2, 3] + nesting_height(model) + DROP_HEIGHT
    else:
        T[2, 3] = top.top_z + model.extents[2] / 2 + DROP_HEIGHT
    if T[2, 3] + model.extents[2] / 2 > PILE_MAX_TOP:
        return None
    return T


class SinkPick(Task):
    name = "sink-pick"
    description = "pick each object out of the sink and set it down in the counter drop zone"
    success_criteria = "sink empty; every object verified in the drop zone"

    def placed_record(self, obj: ObjectPose, target: PlaceTarget, T_base_obj: np.ndarray,
                      instance_id: int = -1) -> Placed:
        """As Task.placed_record, at its resting height; an upright round item's footprint is its disc's square
        whatever yaw the planner turned it to (the bounding box of a turned plate is up to 41 % wider)."""
        T_base_obj = np.array(T_base_obj, float)
        if abs(T_base_obj[2, 3] - float(target.T_base_obj[2, 3])) < 1e-6:
            # not measured (the executive had no view of it): it came to rest DROP_HEIGHT below the release
            # target; a pile's height is built on this, so the drop height must not pile up with it
            T_base_obj[2, 3] -= DROP_HEIGHT
        p = super().placed_record(obj, target, T_base_obj, instance_id)
        model = self.inventory[obj.obj_id]
        if model.is_rotationally_symmetric and is_upright(T_base_obj):
            r = max(model.extents[:2]) / 2
            p.lo, p.hi = T_base_obj[:2, 3] - r, T_base_obj[:2, 3] + r
        return p

    def accepts_as_it_lies(self, obj: ObjectPose) -> bool:
        """The drop zone takes items as they lie: one that fell into it is done."""
        return self.at_target(obj.cls, obj.T_base_obj)

    def _zone(self) -> tuple[np.ndarray, np.ndarray, float]:
        z = self.cell.spec.drop_zone
        lo = np.array(z.origin_xy, float)
        return lo, lo + np.array(z.size_xy, float), float(z.z)

    def _in_zone(self, p: Placed) -> bool:
        lo, hi, _ = self._zone()
        c = p.T_base_obj[:2, 3]
        return bool(np.all(c >= lo - 0.05) and np.all(c <= hi + 0.05))

    def _pile_targets(self, model: ObjectModel, kinds, belief: Holdings) -> list[np.ndarray]:
        """Poses on the piles whose top item passes `kinds(top) -> rank` (lower first; None: not this pile)."""
        zone_items = [p for p in belief.placed if self._in_zone(p)]
        out = []
        for pile in _piles(zone_items):
            rank = kinds(pile[-1])
            if rank is None or self._carries(pile[-1], zone_items):
                continue
            T = pile_pose(model, pile)
            if T is None:
                continue
            lo, hi, _ = footprint(model, T)
            pile_lo, pile_hi = np.min([p.lo for p in pile], 0), np.max([p.hi for p in pile], 0)
            others = [p for p in zone_items if not any(p is q for q in pile)]
            # an item no wider than the pile below covers nothing the pile does not already (a neighbour set down
            # turned, its box grazing the pile's, does not close the pile to the next plate of its size)
            wider = not (np.all(lo >= pile_lo - 1e-3) and np.all(hi <= pile_hi + 1e-3))
            if wider and any(np.all(lo < p.hi) and np.all(hi > p.lo) for p in others):
                continue  # a bigger item on a smaller pile would overhang its neighbours
            out.append((rank, T[2, 3], T))
        return [T for _, _, T in sorted(out, key=lambda r: (r[0], r[1]))]

    @staticmethod
    def _carries(top: Placed, zone_items: list[Placed]) -> list[Placed]:
        """The items standing on `top` off its centre (not part of its pile: see `_plate_top_spots`): over it, their
        bottom above its bottom. A taller item standing on the counter beside a one-plate pile, its box grazing the
        plate's, has its centre higher too but does not close the pile."""
        def bottom(p: Placed) -> float:  # the footprint box is centred on the pose: bottom = 2 z - top
            return 2.0 * float(p.T_base_obj[2, 3]) - p.top_z

        return [p for p in zone_items if p is not top and bottom(p) > bottom(top) + 1e-3
                and p.T_base_obj[2, 3] > top.T_base_obj[2, 3] + 1e-3
                and bool(np.all(p.lo < top.hi) and np.all(p.hi > top.lo))]

    def _plate_top_spots(self, model: ObjectModel, belief: Holdings, limit: int) -> list[np.ndarray]:
        """Upright poses standing on the flat floor of a plate that tops a pile, as a person puts glasses and
        mugs onto a stack of plates when the counter is full: inside the floor's disc (`floor_radius`) and
        CLEARANCE from what already stands there, off the centre first (two glasses side by side on a dinner
        plate; one in the middle would take the whole floor); an item wider than the floor in the middle, on
        an empty plate only. The lowest pile first."""
        zone_items = [p for p in belief.placed if self._in_zone(p)]
        r_item = float(np.hypot(*model.extents[:2])) / 2 if not model.is_rotationally_symmetric \
            else max(model.extents[:2]) / 2
        out = []
        for pile in _piles(zone_items):
            top = pile[-1]
            if top.cls != "plate" or not is_upright(top.T_base_obj):
                continue
            room = floor_radius(self.inventory[top.obj_id]) - r_item
            on_it = self._carries(top, zone_items)
            c = top.T_base_obj[:2, 3]
            cands = [c + room * np.array([np.cos(a), np.sin(a)]) for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
            # off the centre only where two fit side by side (glasses on a dinner plate); else in the middle,
            # standing on the rim if need be (a mug on a side plate), as one item centred on a pile always was
            for xy in [*cands, c] if room >= r_item + CLEARANCE / 2 else [c]:
                T = upright(model, xy, 0.0)
                T[2, 3] = top.top_z + model.extents[2] / 2 + DROP_HEIGHT
                if T[2, 3] + model.extents[2] / 2 > PILE_MAX_TOP:
                    break
                # the item's disc (a mug: the circle around its box) keeps CLEARANCE from those already there
                if any(np.linalg.norm(xy - q.T_base_obj[:2, 3]) < r_item + max(q.hi - q.lo) / 2 + CLEARANCE
                       for q in on_it):
                    continue
                out.append(T)
                on_it = on_it + [Placed(model.obj_id, model.cls, T, *footprint(model, T), None)]
                break  # one per plate here: the next call sees this one placed
        return sorted(out, key=lambda T: T[2, 3])[:limit]

    def _same_way_piles(self, model: ObjectModel, R: np.ndarray, belief: Holdings) -> list[np.ndarray]:
        """Poses nested onto piles topped by the same model lying the way R does (its axis within ~10 degrees):
        two copies turned alike nest by the same height as upright ones (the pair is only turned as a whole)."""
        if model.cls not in PILE_CLASSES:
            return []
        out = []
        for pile in _piles([p for p in belief.placed if self._in_zone(p)]):
            top = pile[-1]
            if top.obj_id != model.obj_id or float(top.T_base_obj[:3, 2] @ R[:, 2]) < 0.98:
                continue
            T = top.T_base_obj.copy()
            T[2, 3] += nesting_height(model) + DROP_HEIGHT
            if footprint(model, T)[2] <= PILE_MAX_TOP:
                out.append(T)
        return sorted(out, key=lambda T: T[2, 3])

    def _reserved(self, model: ObjectModel, belief: Holdings) -> tuple[list[Placed], list[Placed]]:
        """Placeholders (growth, new): around each pile, the footprint of the largest item of its class still to
        come; for each pile class with items still to come but no pile yet (and that `model` cannot start),
        a spot for its largest item."""
        lo, hi, z = self._zone()
        zone_items = [p for p in belief.placed if self._in_zone(p)]
        taken = list(zone_items)
        extra: list[Placed] = []
        growth: list[Placed] = []
        for cls in PILE_CLASSES:
            pend = [m for m in belief.pending if m.cls == cls]
            if not pend:
                continue
            big = max(pend, key=lambda m: max(m.extents[:2]))
            piles = [pile for pile in _piles(zone_items) if pile[-1].cls == cls]
            if piles:
                # the pile will take the largest item of its class still to come (a dinner plate onto a side
                # plate): keep its footprint around the pile free
                T = upright(big, piles[0][-1].T_base_obj[:2, 3], z)
                ph = Placed(big.obj_id, big.cls, T, *footprint(big, T), None)
                taken.append(ph)
                growth.append(ph)
                continue
            if cls == model.cls:
                continue
            # where that pile will start (`_floor`'s lattice: plates in a corner): a spot reserved in the
            # zone's middle would leave the rest in pieces too small for the next pile
            spot = area_spots(big, lo, hi, z, taken, upright, 1, preferred=self._lattice(big, lo, hi),
                              centre_inside=True)
            if spot:
                ph = Placed(big.obj_id, big.cls, spot[0], *footprint(big, spot[0]), None)
                taken.append(ph)
                extra.append(ph)
        return growth, extra

    def _floor(self, model: ObjectModel, belief: Holdings, limit: int, pose=upright,
               centre_inside=True, spare: int = SPARE_SPOTS) -> list[np.ndarray]:
        """Free counter spots for `model` (`limit` plus `spare` farther ones, each in its own part of the zone),
        those leaving the most room for what is still to come first (`_leaving_room`)."""
        lo, hi, z = self._zone()
        zone_items = [p for p in belief.placed if self._in_zone(p)]
        # a new pile is started with room for the largest item of its class still to come (a dinner plate
        # onto a side plate's pile must not overhang the neighbours)
        probe = model
        if model.cls in PILE_CLASSES and pose is upright:
            probe = max([model, *(m for m in belief.pending if m.cls == model.cls)], key=lambda m: max(m.extents[:2]))
        pref = self._lattice(probe, lo, hi, None if pose is upright else pose)
        growth, new = self._reserved(model, belief)
        spots: list[np.ndarray] = []
        # the reservations leave no room: first a new pile's spot, then a pile's growth gives way to a placement now
        for keep in (growth + new, growth, []):
            # more candidates than asked for, each in its own part of the zone: ranked by the room they leave
            spots = area_spots(probe, lo, hi, z, zone_items + keep, pose, limit + spare, preferred=pref,
                               centre_inside=centre_inside)
            if spots:
                break
        if len(spots) > 1:
            spots = self._leaving_room(probe, spots, zone_items + keep, belief)
        if probe is not model:
            spots = [upright(model, T[:2, 3], z) for T in spots]
        return spots

    def _floor_needs(self, model: ObjectModel, belief: Holdings) -> list[ObjectModel]:
        """The items still to come (besides `model`, the one being placed) that will need a spot of their own on
        the counter, largest first: each glass or mug (they do not pile), and the first item of each pile model
        with no pile in the zone yet (one plate pile takes every plate: plates go on plates)."""
        pending = list(belief.pending)
        for k, m in enumerate(pending):
            if m is model or m.obj_id == model.obj_id:
                del pending[k]  # the item being placed
                break
        tops = {pile[-1].obj_id for pile in _piles([p for p in belief.placed if self._in_zone(p)])}
        top_cls = {self.inventory[i].cls for i in tops if i in self.inventory.models}
        needs: dict = {}
        singles = []
        for m in pending:
            if m.cls == "plate":
                if "plate" in top_cls or model.cls == "plate":
                    continue
                if "plate" not in needs or max(m.extents[:2]) > max(needs["plate"].extents[:2]):
                    needs["plate"] = m
            elif m.cls in PILE_CLASSES:
                if m.obj_id not in tops and m.obj_id != model.obj_id:
                    needs.setdefault(m.obj_id, m)
            else:
                singles.append(m)
        out = list(needs.values()) + singles
        return sorted(out, key=lambda m: -float(np.prod(m.extents[:2])))[:LOOKAHEAD_ITEMS]

    def _leaving_room(self, model: ObjectModel, spots: list[np.ndarray], taken: list[Placed],
                      belief: Holdings) -> list[np.ndarray]:
        """`spots` ranked by how many of the items still to come that need counter room of their own
        (`_floor_needs`, largest first) still fit, each at the first free spot of its edge-to-edge lattice or the 2 cm grid, once
        `model` stands there; ties keep the given order (nearest the robot). Taking the nearest free spot
        regardless scattered items over the zone: the space between them fitted no later plate or bowl pile
        (tests/tasks/test_drop_zone_room.py)."""
        needs = self._floor_needs(model, belief)
        if not needs:
            return spots
        lo, hi, z = self._zone()
        # where each still-to-come item may stand: its edge-to-edge lattice, then a 2 cm grid (as `area_spots`),
        # as upright boxes centred there (vectorised: a spot search per item per candidate)
        step = 0.02
        c = (lo + hi) / 2
        n = (np.ceil((hi - lo) / 2 / step) + 1).astype(int)
        grid = np.array([(c[0] + i * step, c[1] + j * step) for i in range(-n[0], n[0] + 1)
                         for j in range(-n[1], n[1] + 1)])
        grid = grid[np.argsort(np.hypot(grid[:, 0], grid[:, 1]), kind="stable")]
        where = {}
        for m in needs:
            lat = np.array(self._lattice(m, lo, hi), float).reshape(-1, 2)
            lat = lat[np.argsort(np.hypot(lat[:, 0], lat[:, 1]), kind="stable")]
            P = np.vstack([lat, grid])
            half = np.asarray(m.extents[:2], float) / 2
            ok = np.all(P - half >= lo + CLEARANCE / 2 - 1e-6, axis=1) & np.all(P + half <= hi - CLEARANCE / 2 + 1e-6, axis=1)
            where[id(m)] = (P[ok] - half, P[ok] + half)

        def fits(T) -> int:
            f_lo, f_hi, _ = footprint(model, T)
            occ_lo = np.array([p.lo for p in taken] + [f_lo]).reshape(-1, 2) - CLEARANCE
            occ_hi = np.array([p.hi for p in taken] + [f_hi]).reshape(-1, 2) + CLEARANCE
            count = 0
            for m in needs:
                b_lo, b_hi = where[id(m)]
                if not len(b_lo):
                    continue
                hit = np.all(b_lo[:, None, :] < occ_hi[None], axis=2) & np.all(b_hi[:, None, :] > occ_lo[None], axis=2)
                free = np.flatnonzero(~hit.any(axis=1))
                if len(free):
                    count += 1
                    occ_lo = np.vstack([occ_lo, b_lo[free[0]] - CLEARANCE])
                    occ_hi = np.vstack([occ_hi, b_hi[free[0]] + CLEARANCE])
            return count

        score = [fits(T) for T in spots]
        order = sorted(range(len(spots)), key=lambda k: -score[k])
        return [spots[k] for k in order]

    @staticmethod
    def _lattice(model: ObjectModel, lo: np.ndarray, hi: np.ndarray, pose=None) -> list[tuple[float, float]]:
        """Spots packed edge to edge from the zone's sides (a pile in a corner leaves the rest of the zone in one
        piece; cups in rows waste no room), tried before the 2 cm grid. Upright by default; given a `pose`
        function (an item set down the way it lay), from the half-widths of its footprint in that pose, so an
        item set down turned also goes to the zone's sides instead of its middle, where it would split the free
        room in two."""
        if pose is None:
            r = np.full(2, max(model.extents[:2]) / 2 + CLEARANCE / 2)
        else:
            f_lo, f_hi, _ = footprint(model, pose(model, (0.0, 0.0), 0.0))
            r = np.maximum(-f_lo, f_hi) + CLEARANCE / 2
        if model.cls == "plate" and pose is None:  # plate piles in the corners
            xs, ys = [lo[0] + r[0], hi[0] - r[0]], [lo[1] + r[1], hi[1] - r[1]]
        else:
            pitch = 2 * r + 1e-3
            xs = [*np.arange(lo[0] + r[0], hi[0] - r[0] + 1e-9, pitch[0]),
                  *np.arange(hi[0] - r[0], lo[0] + r[0] - 1e-9, -pitch[0])]
            ys = [*np.arange(lo[1] + r[1], hi[1] - r[1] + 1e-9, pitch[1]),
                  *np.arange(hi[1] - r[1], lo[1] + r[1] - 1e-9, -pitch[1])]
        return [(float(x), float(y)) for x in xs for y in ys]

    def targets(self, obj: ObjectPose, belief: Holdings) -> list[PlaceTarget] | NoFreeSlot:
        model = self.inventory[obj.obj_id]
        out: list[PlaceTarget] = []

        def add(Ts, support):
            onto = "pile" in support  # onto another item: released a little above it (see PlaceTarget.clearance)
            out.extend(PlaceTarget(T, "drop", free_yaw=True, support=support, clearance=PILE_CLEARANCE if onto else 0.0)
                       for T in Ts)

        if model.cls == "plate":
            size = max(model.extents[:2])

            def plate_rank(top):
                if top.cls != "plate":
                    return None
                if top.obj_id == model.obj_id:
                    return 0
                return 1 if max(self.inventory[top.obj_id].extents[:2]) >= size else 3

            add(self._pile_targets(model, lambda top: p if (p := plate_rank(top)) in (0, 1) else None, belief)[:2],
                "a plate pile")
            if not out:
                add(self._floor(model, belief, 2), "counter")
            if not out:  # a bigger plate on a smaller one's pile still rests flat on its rim
                add(self._pile_targets(model, plate_rank, belief)[:2], "a plate pile")
        elif model.cls in ("bowl", "cup"):
            add(self._pile_targets(model, lambda top: 0 if top.obj_id == model.obj_id else None, belief)[:2],
                f"a {model.cls} pile")
            if not out:
                add(self._floor(model, belief, 3), "counter")
        else:
            add(self._floor(model, belief, 3), "counter")
        if not out:
            # the counter is full: overhang the zone's edge (centre inside), then stand on a plate pile once
            # no plate is left to come
            add(self._floor(model, belief, 2, centre_inside="any"), "counter (overhanging)")
        if not out and not any(m.cls == "plate" for m in belief.pending if m is not model):
            add(self._plate_top_spots(model, belief, 2), "a plate pile")
        R = obj.T_base_obj[:3, :3]
        if faces_down(obj.T_base_obj):
            # Mouth down in the sink (a bowl tipped over, tilted on the items below): set down level and mouth
            # down, the tool turning with it by the tilt. Inverted copies nest as well as upright ones, so it goes
            # onto a pile of its model lying so first, and its level footprint is smaller than the tilted one.
            Rl = levelled(R, model.is_rotationally_symmetric)
            for T in self._same_way_piles(model, Rl, belief)[:1]:
                out.append(PlaceTarget(T, "drop", free_yaw=True, support=f"a {model.cls} pile (upside down)",
                                       clearance=PILE_CLEARANCE))
            for T in self._floor(model, belief, 2, as_is(Rl), spare=0):
                out.append(PlaceTarget(T, "drop", free_yaw=True, support="counter (upside down)"))
        if not is_upright(obj.T_base_obj):
            # Not upright in the sink (a glass on its side): no grasp may reach "upright", so also offer the
            # drop zone as it lies now (set down the way it is held): nested onto a pile of the same model
            # lying the same way (upside-down bowls onto an upside-down bowl), else a free spot.
            for T in self._same_way_piles(model, R, belief)[:1]:
                out.append(PlaceTarget(T, "drop", free_yaw=False, support=f"a {model.cls} pile (as it lay)",
                                       clearance=PILE_CLEARANCE))
            for T in self._floor(model, belief, 2, as_is(R), centre_inside="any", spare=0):
                out.append(PlaceTarget(T, "drop", free_yaw=False, support="counter (as it lay)"))
        return out or NoFreeSlot(f"drop zone has no free spot for a {obj.cls}")
