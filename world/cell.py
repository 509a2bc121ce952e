"""The kitchen cell's fixed geometry: counter, sink basin, dishwasher racks, stacking area, drop zone.

This is prior knowledge, like the inventory: perception removes these surfaces before segmenting, planning
collides against them and places into the rack slots, and the simulator renders them. One parametric
description (pydantic, from the cell config) expands into axis-aligned boxes in the ``base`` frame.

Layout (base frame: robot base on the counter top, z up, x towards the sink):
counter top at z=0; sink basin in front of the robot; dishwasher with its racks pulled out to the right
(-y; lower rack for plates, upper rack for cups/glasses/bowls); stacking area and drop zone on the left (+y).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

Vec3 = tuple[float, float, float]
Vec2 = tuple[float, float]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SinkSpec(_Strict):
    centre_xy: Vec2 = (0.50, 0.0)
    inner_size_xy: Vec2 = Field((0.50, 0.40), description="inside of the basin, metres")
    depth: float = Field(0.20, gt=0.05, lt=0.5)
    wall: float = Field(0.012, gt=0.0, lt=0.05)
    style: Literal["stainless", "ceramic"] = "stainless"


class RackSpec(_Strict):
    """A pulled-out dishwasher rack: a wire floor with low sides, slots on a grid."""

    origin_xy: Vec2  # min corner
    size_xy: Vec2
    floor_z: float
    side_height: float = 0.08
    slot_pitch: Vec2 = (0.10, 0.10)  # metres between slots along x and y
    kind: Literal["plates", "cups"] = "plates"


class DishwasherSpec(_Strict):
    # Racks pulled out to the robot's right. The lower rack holds one row of upright plates (10 slots at
    # 45 mm); the upper rack a 3 x 3 grid for cups, glasses, mugs and bowls (inverted). Every slot is within
    # the UR5e's reach with the tool pointing down (checked by tests/planning).
    lower: RackSpec = RackSpec(origin_xy=(-0.15, -0.74), size_xy=(0.50, 0.34), floor_z=-0.28,
                               slot_pitch=(0.045, 0.30), kind="plates")
    upper: RackSpec = RackSpec(origin_xy=(0.38, -0.74), size_xy=(0.34, 0.40), floor_z=-0.12,
                               slot_pitch=(0.095, 0.095), kind="cups")


class AreaSpec(_Strict):
    origin_xy: Vec2
    size_xy: Vec2
    z: float = 0.0


class CellSpec(_Strict):
    counter_extent_xy: tuple[Vec2, Vec2] = ((-0.35, -0.30), (0.95, 0.90))  # min, max (x, y)
    counter_thickness: float = 0.04
    sink: SinkSpec = SinkSpec()
    dishwasher: DishwasherSpec = DishwasherSpec()
    stacking_area: AreaSpec = AreaSpec(origin_xy=(0.30, 0.35), size_xy=(0.30, 0.30))
    # The counter beside the robot where sink-pick sets items down (and other tasks stage or give up items):
    # room for a plate pile, a bowl pile and a row of cups/glasses/mugs, as a person clearing a 10-item sink
    # would use. Every spot is reachable with the tool pointing down (checked by tests/executive/test_tasks.py);
    # it ends 4 cm before the stacking area (x >= 0.30) and 0.40 m from the base (the arm's column).
    drop_zone: AreaSpec = AreaSpec(origin_xy=(-0.30, 0.40), size_xy=(0.56, 0.38))
    wall_x: float = Field(1.00, description="back wall (splashback) plane x, metres")


@dataclass(frozen=True)
class Box:
    """Axis-aligned box in the base frame."""

    name: str
    kind: str  # counter | sink | rack | wall | cabinet
    lower: np.ndarray
    upper: np.ndarray
    colour: tuple[float, float, float]

    @property
    def centre(self) -> np.ndarray:
        return (self.lower + self.upper) / 2

    @property
    def size(self) -> np.ndarray:
        return self.upper - self.lower


@dataclass(frozen=True)
class Slot:
    """A place in a dishwasher rack. T_base_slot: z up; objects are placed with their base on the rack floor."""

    name: str
    rack: str  # lower | upper
    kind: str  # plates | cups
    T_base_slot: np.ndarray


STYLE_COLOURS = {
    "stainless": {"sink": (0.72, 0.74, 0.76), "counter": (0.35, 0.30, 0.26)},
    "ceramic": {"sink": (0.93, 0.93, 0.90), "counter": (0.55, 0.55, 0.58)},
}


def _box(name, kind, lo, hi, colour) -> Box:
    return Box(name, kind, np.asarray(lo, float), np.asarray(hi, float), colour)


class Cell:
    """The expanded cell: boxes, the sink interior, rack slots, the stacking area and drop zone."""

    def __init__(self, spec: CellSpec | None = None):
        self.spec = spec or CellSpec()
        self.boxes: list[Box] = self._build_boxes()
        self.slots: list[Slot] = self._build_slots()

    # ---- regions -------------------------------------------------------------------------------------
    @property
    def sink_interior(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) corners of the empty space inside the basin, up to the counter top."""
        s = self.spec.sink
        c, h = np.array(s.centre_xy), np.array(s.inner_size_xy) / 2
        return np.array([*(c - h), -s.depth]), np.array([*(c + h), 0.0])

    def in_sink(self, p: np.ndarray, margin: float = 0.0) -> np.ndarray:
        lo, hi = self.sink_interior
        p = np.atleast_2d(p)
        return np.all((p >= lo - margin) & (p <= hi + np.array([margin, margin, 0.3])), axis=1)

    # ---- construction --------------------------------------------------------------------------------
    def _build_boxes(self) -> list[Box]:
        sp = self.spec
        col = STYLE_COLOURS[sp.sink.style]
        boxes: list[Box] = []
        (x0, y0), (x1, y1) = sp.counter_extent_xy
        t = sp.counter_thickness
        s = sp.sink
        c, h, w = np.array(s.centre_xy), np.array(s.inner_size_xy) / 2, s.wall
        sx0, sy0 = c - h - w
        sx1, sy1 = c + h + w
        # Counter top with a cut-out for the sink (four slabs around the hole).
        ctr = col["counter"]
        boxes += [
            _box("counter_back", "counter", (x0, y0, -t), (sx0, y1, 0), ctr),
            _box("counter_front", "counter", (sx1, y0, -t), (x1, y1, 0), ctr),
            _box("counter_right", "counter", (sx0, y0, -t), (sx1, sy0, 0), ctr),
            _box("counter_left", "counter", (sx0, sy1, -t), (sx1, y1, 0), ctr),
        ]
        # Sink basin: floor and four walls.
        sc = col["sink"]
        zf = -s.depth
        boxes += [
            _box("sink_floor", "sink", (sx0, sy0, zf - w), (sx1, sy1, zf), sc),
            _box("sink_wall_back", "sink", (sx0, sy0, zf), (sx0 + w, sy1, 0), sc),
            _box("sink_wall_front", "sink", (sx1 - w, sy0, zf), (sx1, sy1, 0), sc),
            _box("sink_wall_right", "sink", (sx0, sy0, zf), (sx1, sy0 + w, 0), sc),
            _box("sink_wall_left", "sink", (sx0, sy1 - w, zf), (sx1, sy1, 0), sc),
        ]
        # Splashback wall behind the counter.
        boxes.append(_box("wall", "wall", (sp.wall_x, y0, -0.9), (sp.wall_x + 0.05, y1, 0.9), (0.88, 0.87, 0.83)))
        # Dishwasher racks.
        rack_col = (0.55, 0.58, 0.62)
        for rname, r in (("lower", sp.dishwasher.lower), ("upper", sp.dishwasher.upper)):
            (rx, ry), (rw, rd), z = r.origin_xy, r.size_xy, r.floor_z
            wire = 0.006
            boxes += [
                _box(f"rack_{rname}_floor", "rack", (rx, ry, z - wire), (rx + rw, ry + rd, z), rack_col),
                _box(f"rack_{rname}_side_a", "rack", (rx, ry, z), (rx + wire, ry + rd, z + r.side_height), rack_col),
                _box(f"rack_{rname}_side_b", "rack", (rx + rw - wire, ry, z), (rx + rw, ry + rd, z + r.side_height), rack_col),
                _box(f"rack_{rname}_side_c", "rack", (rx, ry, z), (rx + rw, ry + wire, z + r.side_height), rack_col),
                _box(f"rack_{rname}_side_d", "rack", (rx, ry + rd - wire, z), (rx + rw, ry + rd, z + r.side_height), rack_col),
            ]
        return boxes

    def _build_slots(self) -> list[Slot]:
        slots: list[Slot] = []
        for rname, r in (("lower", self.spec.dishwasher.lower), ("upper", self.spec.dishwasher.upper)):
            (rx, ry), (rw, rd) = r.origin_xy, r.size_xy
            px, py = r.slot_pitch
            nx = max(1, int((rw - 0.04) // px))
            ny = max(1, int((rd - 0.04) // py))
            xs = rx + (rw - (nx - 1) * px) / 2 + px * np.arange(nx)
            ys = ry + (rd - (ny - 1) * py) / 2 + py * np.arange(ny)
            for i, x in enumerate(xs):
                for j, y in enumerate(ys):
                    T = np.eye(4)
                    T[:3, 3] = (x, y, r.floor_z)
                    slots.append(Slot(f"{rname}_{i}_{j}", rname, r.kind, T))
        return slots
