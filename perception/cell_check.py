"""Is the configured cell the one the camera sees? Render the cell's boxes into each view and compare depths.

Where the cell says there is a surface, the camera must see that surface or something in front of it (an item
in the sink). Seeing *through* it, measured depth clearly behind the predicted surface, means the cell is
not there: a basin 10 cm off, another sink, a table where a sink was described. The fraction of such
pixels, over the pixels where both depths are known, decides; a few are expected from depth noise at edges
and from scan pose errors, which the tolerance (3 cm) and the threshold absorb.

A basin covered over is the other misfit: a table or a board where the cell has an open sink. The camera then
sees nothing *behind* the cell, but over most of the basin's floor it sees one level surface well above it
(items in a sink are level only in patches: a dinner plate covers under a third of a basin, a stack's plates lie
at several heights). Over half of the floor's pixels seen on one level (2 cm) at least 3 cm above the floor:
the cell is not there either. One level is not always enough: boxes of two heights and plates on a table
split what is seen over the floor between several levels, none of them the most. So the basin is also covered
where its own surfaces (floor and walls, deeper than 6 cm under the rim) are hardly seen where the cell puts
them: in a sink they are seen around and between the items, over a board not at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from kitchenbot.world.cell import Cell
from kitchenbot.world.raycast import pinhole_rays
from kitchenbot.perception.types import View
from kitchenbot.transforms import inv


# Over this share of the basin floor's pixels seen on one level above it, the basin is covered (a table over it).
MAX_COVERED = 0.6
# Under this share of the basin's floor and wall pixels (deeper than 2 tol under the rim) seen on those surfaces,
# the basin is covered: over a board 0 on development tables; in sinks 0.43-0.87 (3 distractors), 0.18-0.28 with
# 20 items in the sink.
MIN_BASIN_SEEN = 0.05


@dataclass
class CellCheck:
    fits: bool
    behind: float  # share of compared pixels seen behind the cell's surface (the cell is not there)
    agree: float  # share seen on the cell's surface (within `tol`)
    compared: int  # pixels with both a measured and a predicted depth
    message: str = ""
    covered: float = 0.0  # share of the basin floor's pixels seen on one level well above it (a table over it)
    max_covered: float = MAX_COVERED  # the share over which the basin counts as covered
    basin_seen: float = 1.0  # share of the basin's floor and wall pixels seen on those surfaces (within `tol`)

    @property
    def is_covered(self) -> bool:
        """The basin is covered (a table or a board over the sink): the cell does not fit, whatever the views'
        registration onto it."""
        return self.covered > self.max_covered or self.basin_seen < MIN_BASIN_SEEN


_SCENES: dict = {}  # the last cell's RaycastingScene (building it is cheap, but not free per scan)


def _scene(cell: Cell) -> o3d.t.geometry.RaycastingScene:
    key = cell.spec.model_dump_json()
    if key not in _SCENES:
        _SCENES.clear()
        scene = o3d.t.geometry.RaycastingScene()
        for b in cell.boxes:
            m = o3d.geometry.TriangleMesh.create_box(*np.maximum(b.size, 1e-4))
            m.translate(b.lower)
            scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
        _SCENES[key] = scene
    return _SCENES[key]


def _level_share(z: np.ndarray, n_floor: int, band: float = 0.02) -> tuple[float, float]:
    """(share of the pixels that see down to the fullest `band`-wide level of heights `z` (those on it, those
    below it, the `n_floor - len(z)` on the floor) that lie on it, that level's centre). Items standing on a
    table hide it from the pixels they cover: those are not counted."""
    if len(z) == 0 or n_floor == 0:
        return 0.0, float("nan")
    zs = np.sort(z)
    hi = np.searchsorted(zs, zs + band, side="right")  # points in [z, z + band] for each z
    k = int(np.argmax(hi - np.arange(len(zs))))
    reach = hi[k] + (n_floor - len(z))  # on the level or below it
    return float((hi[k] - k) / reach), float(zs[k] + band / 2)


def check_cell(views: list[View], cell: Cell, stride: int = 8, tol: float = 0.03, max_behind: float = 0.04,
               min_compared: int = 300, max_covered: float = MAX_COVERED) -> CellCheck:
    """Compare each view's depth (every `stride`-th pixel) with the cell rendered from its pose. The cell fits
    when at most `max_behind` of the compared pixels are seen more than `tol` behind its surfaces, and at most
    `max_covered` of the basin floor's pixels are seen on one level more than `tol` above the floor."""
    scene = _scene(cell)
    floor_ids = [k for k, b in enumerate(cell.boxes) if b.name == "sink_floor"]
    basin_ids = [k for k, b in enumerate(cell.boxes) if b.name.startswith("sink_")]
    basin_n = basin_on = 0
    rim = max((float(b.lower[2] + b.size[2]) for b in cell.boxes if b.name.startswith("sink_wall")), default=0.0)
    behind = agree = compared = 0
    floor_n, floor_z = 0, []
    for v in views:
        h, w = v.depth.shape
        K = np.array(v.K, float)
        K[:2] /= stride  # the same camera at 1/stride resolution (pixel centres scaled with it)
        K[:2, 2] = (np.array(v.K)[:2, 2] + 0.5) / stride - 0.5
        hs, ws = (h + stride - 1) // stride, (w + stride - 1) // stride
        rays = pinhole_rays(K, inv(v.T_base_cam), ws, hs)
        hit = scene.cast_rays(rays)
        pred, gid = hit["t_hit"].numpy(), hit["geometry_ids"].numpy()
        d = np.asarray(v.depth, np.float32)
        # The measured depth at the centre of each stride x stride block.
        rows = np.clip(np.round((np.arange(hs) + 0.5) * stride - 0.5).astype(int), 0, h - 1)
        cols = np.clip(np.round((np.arange(ws) + 0.5) * stride - 0.5).astype(int), 0, w - 1)
        meas = d[np.ix_(rows, cols)]
        with np.errstate(invalid="ignore"):
            both = np.isfinite(pred) & np.isfinite(meas) & (meas > 1e-4)
            behind += int(np.sum(both & (meas > pred + tol)))
            agree += int(np.sum(both & (np.abs(meas - pred) <= tol)))
        compared += int(both.sum())
        # Only the basin's surfaces deeper than 2 tol under its rim: a board over it is within tol of the walls'
        # top (seen "on" them), never of what lies deeper.
        r = rays.numpy()
        with np.errstate(invalid="ignore"):
            deep = r[..., 2] + r[..., 5] * pred < rim - 2 * tol
        on_basin = both & np.isin(gid, basin_ids) & deep
        basin_n += int(on_basin.sum())
        basin_on += int(np.sum(on_basin & (np.abs(meas - pred) <= tol)))
        on_floor = both & np.isin(gid, floor_ids)
        floor_n += int(on_floor.sum())
        above = on_floor & (meas < pred - tol)
        if above.any():
            floor_z.append(r[above][:, 2] + r[above][:, 5] * meas[above])  # base-frame height of what is seen there
    if compared < min_compared:
        return CellCheck(False, 0.0, 0.0, compared,
                         f"the configured cell is hardly in view ({compared} pixels to compare): not used")
    b, a = behind / compared, agree / compared
    covered, level = _level_share(np.concatenate(floor_z) if floor_z else np.zeros(0), floor_n)
    # Too few basin pixels in view (a scan elsewhere): no evidence either way.
    seen = basin_on / basin_n if basin_n >= min_compared else 1.0
    fits = b <= max_behind and covered <= max_covered and seen >= MIN_BASIN_SEEN
    msg = ""
    if b > max_behind:
        msg = (f"the configured cell does not fit the scan: {100 * b:.1f} % of the depth lies behind its surfaces "
               f"(at most {100 * max_behind:.0f} % expected); using surfaces found in the data")
    elif covered <= max_covered and not fits:
        msg = (f"the configured cell does not fit the scan: its basin's floor and walls are seen on their surfaces "
               f"at only {100 * seen:.0f} % of their pixels (a table or a board over the sink?); using surfaces found "
               f"in the data")
    elif not fits:
        msg = (f"the configured cell does not fit the scan: {100 * covered:.0f} % of its basin floor is seen on one "
               f"level at z = {level:.3f} m (a table or a board over the sink?); using surfaces found in the data")
    return CellCheck(fits, b, a, compared, msg, covered, max_covered, seen)
