"""What every task names: which objects it picks, in what order, where each goes, and when it is done.

A task is a pure function of perception results, the cell geometry and the executive's belief (what it has
placed, what is still pending: :class:`Holdings`): it never moves the robot and holds no state of the run. The
executive asks it for the next object (`remaining`) and its place targets (`targets(obj, belief)`), for the
record of a placement (`placed_record`, which the belief keeps), and whether the work is complete. Place targets
are :class:`kitchenbot.planning.types.PlaceTarget` (object pose at release); the planner turns them into motions.

Footprints on the target areas are discs/boxes in the base xy plane (what the rack, the stacking area or the
drop zone already holds, from the belief's placed records), because the scan only looks into the sink.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.resting import lying_on
from kitchenbot.planning.types import NoFreeSlot, PlaceTarget
from kitchenbot.transforms import make_T, rot_x, rot_y, rot_z
from kitchenbot.world.attitude import faces_down, is_level, is_upright
from kitchenbot.world.cell import AreaSpec, Cell
from kitchenbot.world.gripper import DROP_HEIGHT
from kitchenbot.world.inventory import Inventory, ObjectModel

CLEARANCE = 0.01  # m between neighbouring placed items
# m between an item released with a near-level side grasp and its neighbours: the open Fin-Ray pads reach ~31 mm
# beyond the item on both sides of the closing axis (plus the planner's margin), and they must open and back out
PAD_ROOM = 0.04


@dataclass
class Placed:
    """A verified placement (kept so later targets avoid it and the planner can collide against it)."""

    obj_id: int
    cls: str
    T_base_obj: np.ndarray
    lo: np.ndarray  # xy footprint box
    hi: np.ndarray
    top_z: float
    target: PlaceTarget
    instance_id: int = -1  # the id its ObjectPose carries as an obstacle (and as a pick target when staged)


def upright(model: ObjectModel, xy, support_z: float) -> np.ndarray:
    """Standing on its base (object z up) with its bottom at support_z."""
    return make_T(np.eye(3), (xy[0], xy[1], support_z + model.extents[2] / 2 + DROP_HEIGHT))


def inverted(model: ObjectModel, xy, support_z: float) -> np.ndarray:
    """Upside down (rim on the support)."""
    return make_T(rot_x(np.pi)[:3, :3], (xy[0], xy[1], support_z + model.extents[2] / 2 + DROP_HEIGHT))


def on_edge(model: ObjectModel, xy, support_z: float) -> np.ndarray:
    """A plate standing on its rim, its face normal along base x (between dishwasher tines)."""
    r = max(model.extents[0], model.extents[1]) / 2
    return make_T(rot_y(np.pi / 2)[:3, :3], (xy[0], xy[1], support_z + r + DROP_HEIGHT))


def as_is(R: np.ndarray):
    """A pose function keeping the object's current orientation R (e.g. a glass lying on its side), resting on the
    support: its lowest model point at support_z."""

    def pose(model: ObjectModel, xy, support_z: float) -> np.ndarray:
        # the height of a model point p in the base frame is (R p)_z = R[2, :] . p
        bottom = float(np.min(model.points @ R[2, :])) if len(model.points) else -model.extents[2] / 2
        return make_T(R, (xy[0], xy[1], support_z - bottom + DROP_HEIGHT))

    return pose


# the eight corners of a unit box centred on the origin, as signs (x slowest, z fastest)
_BOX_SIGNS = np.array([[sx, sy, sz] for sx in (-1.0, 1.0) for sy in (-1.0, 1.0) for sz in (-1.0, 1.0)])


def footprint(model: ObjectModel, T_base_obj: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """xy box and top height of the model at that pose (from its bounding-box corners)."""
    corners = _BOX_SIGNS * (model.extents / 2)
    P = corners @ T_base_obj[:3, :3].T + T_base_obj[:3, 3]
    return P[:, :2].min(0), P[:, :2].max(0), float(P[:, 2].max())


def _overlaps(lo, hi, placed: list[Placed], clearance: float | np.ndarray = CLEARANCE) -> bool:
    """Boxes closer than `clearance` (m; per axis when an xy array)?"""
    return any(np.all(lo < p.hi + clearance) and np.all(hi > p.lo - clearance) for p in placed)


class Holdings(Protocol):
    """What a task reads of the robot's belief (executive/belief.py): what it has put down, and the models it
    still has to move (from the latest perception). Tasks never change it."""

    placed: list[Placed]
    pending: list[ObjectModel]


@dataclass
class NoHoldings:
    """A belief as plain lists (nothing placed, nothing pending by default): for tasks used on their own."""

    placed: list = field(default_factory=list)
    pending: list = field(default_factory=list)


@dataclass
class Task:
    """Base class: subclasses set `name`, `description`, `wants()` and `targets()`. A task is a pure function of
    the perception results and the belief it is given: it holds no state of the run."""

    inventory: Inventory
    cell: Cell

    name = "task"
    description = ""
    success_criteria = ""
    # The executive's strategies for getting an item out, tried in this order (executive/strategies.py; the
    # names are its STRATEGIES). "stage_when_blocked" (stage an item for a regrasp also when the grasps that
    # reach its targets are blocked on their way out of the sink, or the full place plan finds no release for
    # them) is worth it where the targets admit few grasps (rack poses), not where the counter is the target.
    # "slide_top_of_nest" comes first: once a grip of a plate closed across two nested rims, the direct pick
    # would plan a pinch across the pair again.
    strategies = ("slide_top_of_nest", "direct_pick", "escape_then_pick", "pick_past_seen_through",
                  "stage_for_regrasp", "slide_off_stack", "slide_off_blocked", "slide_from_wall",
                  "pick_hidden_blocker", "blocker_first")

    # ---- what to pick ------------------------------------------------------------------------------------------
    def wants(self, obj: ObjectPose) -> bool:
        return True

    def in_sink(self, obj: ObjectPose) -> bool:
        return bool(self.cell.in_sink(obj.T_base_obj[:3, 3], margin=0.02)[0])

    def remaining(self, poses: list[ObjectPose]) -> list[ObjectPose]:
        """Objects still to do, in pick order: uncovered ones first (stacked/nested items come off the top), plates
        before other items (they need the most room at the target), then from the top down."""
        todo = [p for p in poses if self.in_sink(p) and self.wants(p)]
        return sorted(todo, key=lambda p: (self._covered(p, poses), p.cls != "plate", -p.T_base_obj[2, 3]))

    def _covered(self, p: ObjectPose, poses: list[ObjectPose]) -> bool:
        """Something rests on or over `p` (its centre within p's radius, higher up; or, by the meshes at their
        poses, it lies on p: planning.resting, what a pick names as blocking its lift): take that first. A glass
        leaning on a plate's rim has its centre beside the plate: by the first test alone the plate came first
        (plates before other items) and its pick failed with its lift blocked by the glass, one failed attempt."""
        r = max(self.inventory[p.obj_id].extents[:2]) / 2
        c = p.T_base_obj[:3, 3]
        if any(o is not p and o.T_base_obj[2, 3] > c[2] + 0.01 and np.linalg.norm(o.T_base_obj[:2, 3] - c[:2]) < r
               for o in poses):
            return True
        return bool(lying_on(p, [o for o in poses if o is not p and self.in_sink(o)], self.inventory))

    def pending_models(self, poses: list[ObjectPose]) -> list[ObjectModel]:
        """The models of what is still to do (the belief's `pending`: room is kept for them at the targets)."""
        return [m for _, m in self.pending_items(poses)]

    def pending_items(self, poses: list[ObjectPose]) -> list[tuple[ObjectPose, ObjectModel]]:
        """What is still to do, each with its model (the belief keeps room for those that can still come out:
        executive/belief.py, Belief.pending)."""
        return [(p, self.inventory[p.obj_id]) for p in self.remaining(poses)]

    # ---- where it goes --------------------------------------------------------------------------------------------
    def targets(self, obj: ObjectPose, belief: Holdings) -> list[PlaceTarget] | NoFreeSlot:
        """Candidate place targets for `obj`, best first (the executive plans them in order), given what the
        belief says is placed and still pending."""
        raise NotImplementedError

    def fallback_target(self, obj: ObjectPose, belief: Holdings) -> PlaceTarget | NoFreeSlot:
        """Where to put a held object down when giving up: the counter drop zone."""
        spots = _drop_zone_targets(self.inventory[obj.obj_id], self.cell.spec.drop_zone, list(belief.placed), 1)
        return spots[0] if spots else NoFreeSlot("drop zone is full")

    # ---- records ------------------------------------------------------------------------------------------------
    def placed_record(self, obj: ObjectPose, target: PlaceTarget, T_base_obj: np.ndarray,
                      instance_id: int = -1) -> Placed:
        """The record of `obj` resting at T_base_obj at `target` (footprint, top), for the belief to keep."""
        model = self.inventory[obj.obj_id]
        lo, hi, top = footprint(model, T_base_obj)
        if model.is_rotationally_symmetric and is_level(T_base_obj):
            # an upright or inverted round item covers its disc whatever yaw the planner turned it to (the box
            # of its turned bounding box is up to 41 % wider and would waste rack/counter room)
            r = max(model.extents[:2]) / 2
            lo, hi = T_base_obj[:2, 3] - r, T_base_obj[:2, 3] + r
        return Placed(obj.obj_id, obj.cls, np.array(T_base_obj), lo, hi, top, target, instance_id)

    def needs_regrasp(self, targets: list[PlaceTarget], obj: ObjectPose | None = None) -> bool:
        """Whether the object may need a different grasp than the one it offers where it lies: the targets turn it
        over (inverted / on edge), or (given `obj`) they turn it by more than 120 degrees from how it lies (a cup
        upside down in the sink wanted upright on a stack). The executive then stages it on the counter
        (`staging_targets`) and picks it again."""
        if any(not is_upright(t.T_base_obj) for t in targets):
            return True
        if obj is None:
            return False
        z = obj.T_base_obj[:3, 2]
        return any(float(t.T_base_obj[:3, 2] @ z) < -0.5 for t in targets)

    def staging_targets(self, obj: ObjectPose, belief: Holdings,
                        targets: list[PlaceTarget] | None = None) -> list[PlaceTarget] | NoFreeSlot:
        """Spots in the counter drop zone to set an object down and grasp it again, in poses from which `targets`
        may be reached with another grasp, the most likely first (the executive keeps those from which the next
        pick can reach them).

        Upright by default: an upright item wanted mouth-down (a rack) is turned over from there with a level side
        grasp. An item upside down wanted upright (a stack) is set down upside down, as a person flips a cup in two
        steps: it is carried there from above (a base grasp, no turn), then a level side grasp turns it over by
        turning 180 degrees about the approach axis. No grasp of it as it lies in the sink does that: a turn of
        180 degrees about a level axis reverses the approach's vertical component, so only a level approach stays
        from above, and a 20 cm tool cannot come in level below the counter top. The open pads of that level grasp
        reach ~31 mm beyond the item on both sides, so these spots keep PAD_ROOM from their neighbours.

        A round cup or glass may also be laid on its side (`lying_spots`): a quarter turn each way, both from
        above, which reaches places a level grasp does not (the back of the upper rack)."""
        model = self.inventory[obj.obj_id]
        zone = self.cell.spec.drop_zone
        lo = np.array(zone.origin_xy)
        hi = lo + np.array(zone.size_xy)
        flip = (targets is not None and len(targets) > 0 and faces_down(obj.T_base_obj)
                and all(is_upright(t.T_base_obj) for t in targets))
        if flip:
            spots = area_spots(model, lo, hi, zone.z, list(belief.placed), inverted, 2, centre_inside=True,
                               clearance=PAD_ROOM)
            out = [PlaceTarget(T, "stage", free_yaw=True, support="counter (upside down, to flip it)") for T in spots]
        else:
            out = _drop_zone_targets(model, zone, list(belief.placed), 2)
            for t in out:
                t.kind, t.support = "stage", "counter (regrasp)"
        if targets is not None:
            out += self.lying_spots(model, belief)
        return out or NoFreeSlot("drop zone has no free spot to stage a regrasp")

    def lying_spots(self, model: ObjectModel, belief: Holdings) -> list[PlaceTarget]:
        """A round cup or glass lying on its side in the drop zone (its mouth towards +y, then -x), PAD_ROOM from its
        neighbours; none for other items (a mug rolls onto its handle, a bowl or plate does not rest on its side)."""
        if model.cls not in ("cup", "glass") or not model.is_rotationally_symmetric:
            return []
        zone = self.cell.spec.drop_zone
        lo = np.array(zone.origin_xy)
        out = []
        for yaw in (np.pi / 2, np.pi):
            R = rot_z(yaw)[:3, :3] @ rot_y(np.pi / 2)[:3, :3]  # the object's axis along base x turned by yaw
            for T in area_spots(model, lo, lo + np.array(zone.size_xy), zone.z, list(belief.placed), as_is(R), 1,
                                centre_inside=True, clearance=PAD_ROOM):
                out.append(PlaceTarget(T, "stage", free_yaw=False, support="counter (on its side, to turn it)"))
        return out

    def accepts_as_it_lies(self, obj: ObjectPose) -> bool:
        """Whether an item found outside the sink (it fell there) is done where it lies. Most targets want a pose
        (a rack slot, a stack), so by default it is picked up again."""
        return False

    def complete(self, poses: list[ObjectPose]) -> bool:
        """Success criterion: nothing this task wants is left in the sink."""
        return not self.remaining(poses)

    def target_areas(self, cls: str) -> list[tuple[np.ndarray, np.ndarray]]:
        """xy boxes where an object of `cls` counts as delivered (used to audit simulated runs)."""
        z = self.cell.spec.drop_zone
        return [(np.array(z.origin_xy), np.array(z.origin_xy) + np.array(z.size_xy))]

    def at_target(self, cls: str, T_base_obj: np.ndarray, margin: float = 0.05) -> bool:
        p = T_base_obj[:2, 3]
        return any(np.all(p >= lo - margin) and np.all(p <= hi + margin) for lo, hi in self.target_areas(cls))

    def describe(self) -> dict:
        return {"name": self.name, "description": self.description, "success": self.success_criteria}


def nearest_the_robot(xy) -> float:
    """Sort key for spots: distance from the robot base (area corners far from it are often out of reach)."""
    return float(np.hypot(*xy))


def area_spots(model: ObjectModel, lo_xy, hi_xy, z: float, placed: list[Placed], pose=upright, limit: int = 3,
               preferred: list | None = None, step: float = 0.02, centre_inside: bool = False,
               clearance: float | np.ndarray = CLEARANCE, order=nearest_the_robot) -> list[np.ndarray]:
    """Free poses for `model` in the xy box [lo_xy, hi_xy] resting at height z: the `preferred` xy first
    (e.g. rack slots), then a `step` grid, each in `order` (a sort key of the xy; nearest the robot first by
    default). The footprint must stay inside the box (or only the centre when `centre_inside`, for items larger
    than the area) and `clearance` away from everything placed (per axis when an xy array)."""
    lo_xy, hi_xy = np.asarray(lo_xy, float), np.asarray(hi_xy, float)
    c = (lo_xy + hi_xy) / 2
    nx, ny = (np.ceil((hi_xy - lo_xy) / 2 / step) + 1).astype(int)
    # A grid centred on the area (so a centred spot exists for items as wide as the area).
    grid = [(c[0] + i * step, c[1] + j * step) for i in range(-nx, nx + 1) for j in range(-ny, ny + 1)]
    cands = sorted(list(preferred or []), key=order) + sorted(grid, key=order)
    out: list[np.ndarray] = []
    taken: list[Placed] = []  # the spots chosen so far, as placed items (each footprint computed once)
    for xy in cands:
        T = pose(model, xy, z)
        lo, hi, top = footprint(model, T)
        # Items larger than the area may overhang it evenly (e.g. a dinner plate on a small drop zone).
        over = np.maximum(0.0, ((hi - lo) - (hi_xy - lo_xy)) / 2) if centre_inside else 0.0
        if centre_inside == "any":
            over = (hi - lo) / 2
        m = np.where(over > 0, -over, CLEARANCE / 2) if centre_inside else CLEARANCE / 2
        inside = np.all(lo >= lo_xy + m - 1e-6) and np.all(hi <= hi_xy - m + 1e-6)
        if not inside or _overlaps(lo, hi, placed, clearance) or _overlaps(lo, hi, taken):
            continue
        out.append(T)
        taken.append(Placed(model.obj_id, model.cls, T, lo, hi, top, None))
        if len(out) >= limit:
            break
    return out


def on_top_of_same(model: ObjectModel, placed: list[Placed], offset: float, max_height: float = 0.4) -> np.ndarray | None:
    """The pose resting on the highest placed item of the same model (nested by `offset`), if any."""
    same = [p for p in placed if p.obj_id == model.obj_id]
    if not same:
        return None
    top = max(same, key=lambda p: p.T_base_obj[2, 3])
    T = top.T_base_obj.copy()
    T[2, 3] += offset + DROP_HEIGHT
    return T if T[2, 3] < max_height else None


def _on_a_pile(model: ObjectModel, placed: list[Placed], max_z: float = 0.35) -> np.ndarray | None:
    """Rest `model` on top of something already placed, as a person clearing a full counter would: nested into
    the same model when that is the top of a pile (plates, bowls, cups), or on a plate that tops a pile (any
    plate on plates; other items standing on a plate they fit on). The lowest such pose, or None."""
    from kitchenbot.tasks.cup_stacking import nest_offset_of

    best = None
    for base in placed:
        T = upright(model, base.T_base_obj[:2, 3], 0.0)
        lo, hi, _ = footprint(model, T)
        over = [p for p in placed if np.all(lo < p.hi) and np.all(hi > p.lo)]
        if not over:
            continue
        top = max(over, key=lambda p: p.top_z)
        if not is_level(top.T_base_obj) or not np.allclose(top.T_base_obj[:2, 3], base.T_base_obj[:2, 3]):
            continue  # only on an upright item centred where we stand it
        if top.obj_id == model.obj_id:
            z = top.T_base_obj[2, 3] + nest_offset_of(model) + DROP_HEIGHT
        elif top.cls == "plate" and (model.cls == "plate" or np.all(top.hi - top.lo >= hi - lo)):
            z = top.top_z + model.extents[2] / 2 + DROP_HEIGHT
        else:
            continue
        if z < max_z and (best is None or z < best[2, 3]):
            best = T.copy()
            best[2, 3] = z
    return best


def with_plate_room(model: ObjectModel, zone: AreaSpec, placed: list[Placed], pending) -> list[Placed]:
    """`placed` plus a reserved spot for the largest plate still in the sink, when `model` is not a plate and no
    plate is in the zone yet (plates cannot go on other items; other items can go on a plate)."""
    lo = np.array(zone.origin_xy)
    hi = lo + np.array(zone.size_xy)
    taken = list(placed)
    plates = [m for m in pending if m.cls == "plate"]
    if model.cls != "plate" and plates and not any(p.cls == "plate" for p in placed):
        big = max(plates, key=lambda m: max(m.extents[:2]))
        keep = area_spots(big, lo, hi, zone.z, placed, upright, 1, centre_inside=True)
        if keep:
            taken.append(Placed(big.obj_id, big.cls, keep[0], *footprint(big, keep[0]), None))
    return taken


def _drop_zone_targets(model: ObjectModel, zone: AreaSpec, placed: list[Placed], limit: int,
                       pending: list[ObjectModel] = ()) -> list[PlaceTarget]:
    """Free upright spots in an area (the centre inside it); when it is full, on a pile (see _on_a_pile).
    Room is kept for the largest plate still `pending` (plates cannot go on cups; cups can go on plates)."""
    lo = np.array(zone.origin_xy)
    hi = lo + np.array(zone.size_xy)
    taken = with_plate_room(model, zone, placed, pending)
    spots = area_spots(model, lo, hi, zone.z, taken, upright, limit, centre_inside=True)
    if not spots:  # overhanging the zone's edge (centre inside) beats blocking the plate's room
        spots = area_spots(model, lo, hi, zone.z, taken, upright, limit, centre_inside="any")
    if not spots and len(taken) > len(placed):  # the reservation leaves no room: a placement now wins
        spots = area_spots(model, lo, hi, zone.z, placed, upright, limit, centre_inside=True)
    out = [PlaceTarget(T, "drop", free_yaw=True, support="counter") for T in spots]
    if not out:
        T = _on_a_pile(model, placed)
        if T is not None:
            out.append(PlaceTarget(T, "drop", free_yaw=True, support="a pile in the drop zone"))
    return out
