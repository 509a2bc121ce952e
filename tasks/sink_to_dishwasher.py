"""sink-to-dishwasher: plates upright (on edge) in the lower rack, cups/glasses/bowls/mugs inverted in the upper
(bowls in the lower one first; the others there when the upper one is full).

Targets: the cell's rack slots (world.cell.Slot) of the matching rack kind, skipping slots whose footprint
would overlap an item already placed or leave the rack. Plates stand on their rim with the face normal along
base x (the lower rack's narrow x pitch); vessels go rim down. Success: nothing left in the sink and each
placement verified at its slot.
"""

from __future__ import annotations

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget
from kitchenbot.tasks.base import CLEARANCE, PAD_ROOM, Holdings, Placed, Task, area_spots, footprint, inverted, on_edge
from kitchenbot.world.attitude import faces_down, faces_up, is_level, is_lying

VESSELS = ("cup", "glass", "bowl", "mug")
RACK_WIRE = 0.006  # m, the racks' side wires (world.cell)
MORE_IN_KEPT_ROOM = 2  # lower-rack spots offered inside the room kept for plates, after the others


def from_the_back(xy) -> tuple[float, float]:
    """Sort key for upper-rack spots: largest x first (away from the side the arm reaches level), then the
    smallest y (the rack's far end from the robot)."""
    return (-round(float(xy[0]), 4), round(float(xy[1]), 4))


def from_the_front(xy) -> tuple[float, float]:
    """Sort key for upper-rack spots a level tool must reach: smallest x first, then the largest y (nearest the
    robot)."""
    return (round(float(xy[0]), 4), -round(float(xy[1]), 4))


def either_way(model) -> bool | None:
    """Whether a vessel's rack target may also be turned half a turn about the vertical (PlaceTarget.flip_ok): for
    an item that is not round (a mug: its handle), whose footprint box is the same either way round (footprints
    are the model's box about its origin). A lying mug is carried by grasps across its body, and which of them
    reach a spot depends on which way its handle points there: at the back of the upper rack, where mouth-down
    items go first, a mug lying with its handle level had none with the handle one way and 15-28 of its 33 with
    it the other (tests/tasks/test_mug_either_way.py); with a fixed handle direction it stayed in the sink
    (``no_feasible_placement``) once the near part was full. None (the planner decides) for round items."""
    return None if model.is_rotationally_symmetric else True


class SinkToDishwasher(Task):
    name = "sink-to-dishwasher"
    description = ("plates upright in the lower rack; cups, glasses, bowls and mugs inverted in the upper rack "
                   "(bowls first in the lower one; others there when the upper one is full)")
    success_criteria = "sink empty; every plate verified in a lower-rack slot, every vessel in a rack slot"
    # rack poses admit few grasps: a blocked or unplaceable one is staged too (see Task.strategies)
    # (and an item with no room in the racks that blocks one with room is set aside on the counter)
    strategies = ("slide_top_of_nest", "direct_pick", "escape_then_pick", "pick_past_seen_through",
                  "stage_for_regrasp", "stage_when_blocked", "slide_off_stack", "slide_off_blocked", "slide_from_wall",
                  "pick_hidden_blocker", "set_aside_blocker", "blocker_first")

    def wants(self, obj: ObjectPose) -> bool:
        return obj.cls == "plate" or obj.cls in VESSELS

    def target_areas(self, cls: str) -> list[tuple[np.ndarray, np.ndarray]]:
        dw = self.cell.spec.dishwasher
        specs = [dw.lower] if cls == "plate" else [dw.upper, dw.lower]  # vessels: the lower rack when the upper is full
        return [(np.array(s.origin_xy), np.array(s.origin_xy) + np.array(s.size_xy)) for s in specs]

    def targets(self, obj: ObjectPose, belief: Holdings) -> list[PlaceTarget] | NoFreeSlot:
        if obj.cls == "bowl":
            # As people load bowls: in the lower rack, the upper one (16 cm a bowl, the room of two or three
            # cups) only if the lower one is full. A bowl not mouth-down stands on its rim between the tines,
            # facing the spray arm like a plate, carried by a rim pinch (it has no level side grasp to turn it
            # over: 16 cm, its foot ring faces down). A mouth-down bowl, carried from above by a foot-ring pinch,
            # goes in mouth-down as it lies (turned on its rim with that pinch it is released 5 cm up, over the
            # rails, and in a test at three spots the pads' retreat then hit it). Two mouth-down bowls in the
            # upper rack leave no room for a mug and a cup.
            if not faces_down(obj.T_base_obj):
                lower = self._bowl_in_lower_rack(obj, belief, on_edge, "on its rim")
            else:
                lower = self._bowl_in_lower_rack(obj, belief, inverted, "mouth-down")
            upper = self._targets(obj, belief, "upper")
            out = lower + (upper if isinstance(upper, list) else [])
            return out or NoFreeSlot("no free slot for a bowl in the lower or upper rack")
        if obj.cls == "plate":
            return self._targets(obj, belief, "lower")
        upper = self._targets(obj, belief, "upper")
        if not isinstance(upper, NoFreeSlot) and not faces_up(obj.T_base_obj):
            return upper
        # The upper rack is full (it takes about seven cups, glasses and mugs with the room a level grasp needs;
        # e.g. six cups, two glasses and a mug), or the item stands upright and its free spots may all lie
        # beyond the near part a level grasp reaches (a staged mug): mouth-down in the lower rack, after
        # the upper rack's spots, as people load a full dishwasher, from its far end, with room kept for the
        # plates still in the sink.
        lower = self._bowl_in_lower_rack(obj, belief, inverted, "mouth-down, the upper rack full")
        out = (upper if isinstance(upper, list) else []) + lower
        return out or NoFreeSlot(f"no free slot for a {obj.cls} in the upper or lower rack")

    def staging_targets(self, obj: ObjectPose, belief: Holdings,
                        targets: list[PlaceTarget] | None = None) -> list[PlaceTarget] | NoFreeSlot:
        """A round cup or glass is staged lying on its side first: from there a grasp from above turns it mouth-down
        anywhere in the upper rack, where from upright only a level side grasp does, which reaches the rack's near
        part only (staged upright when that part was full, they stayed on the counter); that
        part stays free for what must be turned over upright (a mug, which rolls onto its handle on its side)."""
        out = super().staging_targets(obj, belief, targets)
        if isinstance(out, NoFreeSlot):
            return out
        return sorted(out, key=lambda t: not is_lying(t.T_base_obj))  # lying first, stable

    def _bowl_in_lower_rack(self, obj: ObjectPose, belief: Holdings, pose, how: str) -> list[PlaceTarget]:
        """A bowl (or a vessel the full upper rack has no room for) in the lower rack, `pose` on_edge (on its rim,
        its axis along x, as a plate) or inverted, from the rack's far end in x (plates are loaded from the end
        nearest the robot), with room kept for the plates still in the sink (one plate thickness each, from the end
        nearest the robot).

        The room kept is where the plates would go first; it can hold the only spots the item reaches (an upright
        bowl in the sink is carried by a rim pinch that reaches the rack's middle, not its far end, where the bowls
        before it went). So spots inside that room are offered too, after the others (the planner tries targets in
        order), where every pending plate still has a spot beside them (`_plates_still_fit`): the plates then go
        elsewhere in the rack, the room kept for them is the same in number."""
        model = self.inventory[obj.obj_id]
        placed = list(belief.placed)
        plates = [m for m in belief.pending if m.cls == "plate"]
        kept: list[Placed] = []
        big = None
        if plates:  # where the plates will go (the spots _plate_spots gives them, the largest plate in each)
            big = max(plates, key=lambda m: max(m.extents[:2]))
            kept = [Placed(big.obj_id, big.cls, T, *footprint(big, T), None)
                    for T in self._plate_spots(big, placed, len(plates))]
        poses = self._lower_rack_spots(model, placed + kept, pose)
        if kept:
            inside = [T for T in self._lower_rack_spots(model, placed, pose)
                      if not any(np.allclose(T, P) for P in poses)]
            poses += [T for T in inside if self._plates_still_fit(big, len(plates), placed, model, T)][:MORE_IN_KEPT_ROOM]
        free_yaw = pose is inverted and model.is_rotationally_symmetric  # a mug keeps its handle along x
        return [PlaceTarget(T, "slot", slot=f"lower@{T[0, 3]:.3f},{T[1, 3]:.3f}", free_yaw=free_yaw,
                            support=f"rack_lower ({how})", flip_ok=either_way(model)) for T in poses]

    def _plates_still_fit(self, plate, n: int, placed: list[Placed], model, T: np.ndarray) -> bool:
        """Do `n` plates (each as large as `plate`) still find lower-rack spots with `model` placed at T?"""
        there = Placed(model.obj_id, model.cls, T, *footprint(model, T), None)
        return len(self._plate_spots(plate, placed + [there], n)) >= n

    def _lower_rack_spots(self, model, taken: list[Placed], pose, limit: int = 3) -> list[np.ndarray]:
        """Free lower-rack poses for `model` (`pose` on_edge or inverted) beside what is `taken`, from the far end."""
        spec = self.cell.spec.dishwasher.lower
        lo = np.array(spec.origin_xy)
        hi = lo + np.array(spec.size_xy)
        y = (lo[1] + hi[1]) / 2
        # Flush beside what is in the rack (or kept for plates), CLEARANCE + 1 mm from it, then every 5 mm from
        # the far end: on the 15 mm grid alone a second bowl missed the room left between the first one and the
        # plates by 2 mm.
        r = max(model.extents[:2]) / 2 if pose is inverted else model.extents[2] / 2  # half its length along x
        in_rack = [p for p in taken if lo[0] <= (p.lo[0] + p.hi[0]) / 2 <= hi[0] and lo[1] <= (p.lo[1] + p.hi[1]) / 2 <= hi[1]]
        xs = [p.lo[0] - CLEARANCE - 0.001 - r for p in in_rack] + [p.hi[0] + CLEARANCE + 0.001 + r for p in in_rack]
        xs += list(np.arange(hi[0] - 0.01, lo[0], -0.005))
        if pose is inverted:
            return self._mouth_down_in_lower_rack(model, lo, hi, spec.floor_z, taken, xs, limit)
        # On its rim (its axis along x, as a plate): on the centre line, facing the spray arm.
        pref = [(float(x), float(y)) for x in xs]

        def far_end_first(xy):  # the largest x first, on the rack's centre line first
            return (-round(float(xy[0]), 4), abs(float(xy[1]) - y))

        return area_spots(model, lo, hi, spec.floor_z, taken, pose, limit, pref, step=0.015, order=far_end_first)

    def _mouth_down_in_lower_rack(self, model, lo, hi, floor_z: float, taken: list[Placed], xs,
                                  limit: int = 3) -> list[np.ndarray]:
        """A mouth-down bowl in the lower rack: a 16 cm disc, against one side of the 34 cm rack (the far one
        first), then beside the next bowl against the other side, staggered in x by what their round rims need
        (CLEARANCE between the discs, not between their boxes), from the rack's far end in x: two bowls to a
        column, as people load bowls. On the rack's centre line each bowl took a whole column and a third bowl
        found neither rack free (three bowls, the upper rack full of glasses and mugs). area_spots
        keeps boxes apart, which leaves no room for two 16 cm bowls across this rack, hence the disc test here."""
        r = max(model.extents[:2]) / 2
        edge = RACK_WIRE + 0.002 + r  # the rim 2 mm inside the rack's side wire
        ys = [lo[1] + edge, hi[1] - edge]
        xs = sorted({round(float(x), 4) for x in xs if lo[0] + edge - 1e-9 <= x <= hi[0] - edge + 1e-9}, reverse=True)
        out: list[np.ndarray] = []
        for x in xs:
            for y in ys:
                T = inverted(model, (x, y), floor_z)
                if all(self._apart(model, T, p) for p in taken) and all(
                        np.hypot(*(T[:2, 3] - o[:2, 3])) >= 2 * r + CLEARANCE - 1e-9 for o in out):
                    out.append(T)
                    if len(out) >= limit:
                        return out
        return out

    def _apart(self, model, T: np.ndarray, p: Placed) -> bool:
        """Is `model` at T (upright or mouth-down) CLEARANCE from the placed item `p`: between two round items
        standing or lying mouth-down, the distance of their discs; otherwise their xy boxes."""
        other = self.inventory.models.get(p.obj_id)
        if (model.is_rotationally_symmetric and other is not None and other.is_rotationally_symmetric
                and is_level(p.T_base_obj) and is_level(T)):
            d = np.hypot(*(T[:2, 3] - p.T_base_obj[:2, 3]))
            return d >= max(model.extents[:2]) / 2 + max(other.extents[:2]) / 2 + CLEARANCE - 1e-9
        lo, hi, _ = footprint(model, T)
        return not (np.all(lo < p.hi + CLEARANCE) and np.all(hi > p.lo - CLEARANCE))

    def _plate_spots(self, model, placed: list[Placed], limit: int) -> list[np.ndarray]:
        """Plates on edge in the lower rack (they span it in y): each slot's x on the rack's centre line first,
        nearest the robot first."""
        spec = self.cell.spec.dishwasher.lower
        lo = np.array(spec.origin_xy)
        hi = lo + np.array(spec.size_xy)
        slots = [s.T_base_slot[:2, 3] for s in self.cell.slots if s.rack == "lower"]
        xs = sorted({round(float(xy[0]), 4) for xy in slots})
        preferred = [(x, (lo[1] + hi[1]) / 2) for x in xs] + slots
        return area_spots(model, lo, hi, spec.floor_z, placed, on_edge, limit, preferred, step=0.015)

    def _targets(self, obj: ObjectPose, belief: Holdings, rack: str) -> list[PlaceTarget] | NoFreeSlot:
        model = self.inventory[obj.obj_id]
        spec = self.cell.spec.dishwasher.lower if rack == "lower" else self.cell.spec.dishwasher.upper
        lo = np.array(spec.origin_xy)
        hi = lo + np.array(spec.size_xy)
        slots = [s.T_base_slot[:2, 3] for s in self.cell.slots if s.rack == rack]
        if obj.cls == "plate":
            poses = self._plate_spots(model, list(belief.placed), 3)
        else:
            # On a fine grid (the nominal slots leave gaps a bowl needs). An item not already mouth-down is turned
            # over with a near-level side grasp (after a regrasp on the counter): it is released and backed out of
            # with open pads ~31 mm beyond it on both sides of the closing axis, so it goes where its neighbours
            # leave that room, as a person loading a rack leaves room for the hand. The arm reaches the upper rack
            # level only coming in along +x..+30 degrees (a scan of release poses over the rack), so the pads open
            # along ~y: PAD_ROOM in y, 1 cm in x. An item already mouth-down is carried from above (a base grasp):
            # 1 cm is enough.
            mouth_down = faces_down(obj.T_base_obj)
            room = CLEARANCE if mouth_down else np.array([CLEARANCE, PAD_ROOM])
            if faces_up(obj.T_base_obj):
                # Upright (in the sink or staged on the counter): only a level side grasp turns it over, and a
                # level tool reaches only the rack's near part in x (centres up to ~0.53 m, a scan of release
                # poses): the smallest x first, then nearest the robot in y. Six of them: the three nearest the
                # robot were often beyond that x where the near part still had room (a staged cup).
                poses = area_spots(model, lo, hi, spec.floor_z, list(belief.placed), inverted, 6, clearance=room,
                                   order=from_the_front)
            else:
                # Mouth-down or lying: carried from above, which reaches the whole rack. Loaded from the back, as a
                # person loads a rack (largest x first, then the far end in y): the near part, the only one a level
                # grasp reaches, stays free for the upright items still to come, and no placed item stands between
                # the arm and a later spot. Six spots (the back column and the next), then the three nearest the
                # robot in case none at the back can be reached with the item's grasps.
                back = area_spots(model, lo, hi, spec.floor_z, list(belief.placed), inverted, 6, clearance=room,
                                  order=from_the_back)
                near = area_spots(model, lo, hi, spec.floor_z, list(belief.placed), inverted, 3, clearance=room)
                poses = back + [T for T in near if not any(np.allclose(T, B) for B in back)]
        names = {tuple(np.round(xy, 4)): s.name for xy, s in
                 zip(slots, [s for s in self.cell.slots if s.rack == rack])}
        # Plates on edge keep their face normal along x (tines); mugs have a handle: no free yaw for either, but a
        # mug's handle may point either way along x (either_way).
        free_yaw = obj.cls not in ("plate", "mug")
        flip = None if obj.cls == "plate" else either_way(model)
        out = [PlaceTarget(T, "slot", slot=names.get(tuple(np.round(T[:2, 3], 4)), f"{rack}@{T[0, 3]:.3f},{T[1, 3]:.3f}"),
                           free_yaw=free_yaw, support=f"rack_{rack}", flip_ok=flip) for T in poses]
        return out or NoFreeSlot(f"{rack} rack has no free slot for a {obj.cls}")
