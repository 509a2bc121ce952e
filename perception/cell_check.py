"""Is the configured cell the one the camera sees? Render the cell's boxes into each view and compare depths.

Where the cell says there is a surface, the camera must see that surface or something in front of it (an item
in the sink). Seeing *through* it, measured depth clearly behind the predicted surface, means the cell is
not there: a basin 10 cm off, another sink, a table where a sink was described. The fraction of such
pixels, over the pixels where both depths are known, decides; a few are expected from depth noise at edges
and from scan pose errors, which the tolerance (3 cm) and the threshold absorb.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from kitchenbot.world.cell import Cell
from kitchenbot.world.raycast import pinhole_rays
from kitchenbot.perception.types import View
from kitchenbot.transforms import inv


@dataclass
class CellCheck:
    fits: bool
    behind: float  # share of compared pixels seen behind the cell's surface (the cell is not there)
    agree: float  # share seen on the cell's surface (within `tol`)
    compared: int  # pixels with both a measured and a predicted depth
    message: str = ""


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


def check_cell(views: list[View], cell: Cell, stride: int = 8, tol: float = 0.03, max_behind: float = 0.04,
               min_compared: int = 300) -> CellCheck:
    """Compare each view's depth (every `stride`-th pixel) with the cell rendered from its pose. The cell fits
    when at most `max_behind` of the compared pixels are seen more than `tol` behind its surfaces."""
    scene = _scene(cell)
    behind = agree = compared = 0
    for v in views:
        h, w = v.depth.shape
        K = np.array(v.K, float)
        K[:2] /= stride  # the same camera at 1/stride resolution (pixel centres scaled with it)
        K[:2, 2] = (np.array(v.K)[:2, 2] + 0.5) / stride - 0.5
        hs, ws = (h + stride - 1) // stride, (w + stride - 1) // stride
        pred = scene.cast_rays(pinhole_rays(K, inv(v.T_base_cam), ws, hs))["t_hit"].numpy()
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
    if compared < min_compared:
        return CellCheck(False, 0.0, 0.0, compared,
                         f"the configured cell is hardly in view ({compared} pixels to compare): not used")
    b, a = behind / compared, agree / compared
    fits = b <= max_behind
    msg = "" if fits else (f"the configured cell does not fit the scan: {100 * b:.1f} % of the depth lies behind "
                           f"its surfaces (at most {100 * max_behind:.0f} % expected); using surfaces found in the data")
    return CellCheck(fits, b, a, compared, msg)
