"""Where an item that left the gripper may have come to rest, judged by the item as it was held, not by the tool point.

A plate held by its rim lies mostly beside the tool: the tool 5 mm outside the basin with the plate over it, the
drop was judged "outside the sink" by the tool point and only looked for on the counter; it lay in the sink, the
scans found and placed it, and the run still ended with it "not seen again" (nothing awaited it there). So the
held item's footprint (its model points as held, in x-y) decides: where part of it was over the basin, a scan must
see it back in the sink (Belief.await_in_sink); where its centre, or a part of it beyond FOOTPRINT_MARGIN, was
outside the basin, the counter is looked at too, straight down at its centre (RecoveryActions._search_drop_site).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FOOTPRINT_MARGIN = 0.02  # m: a part of the footprint beyond the basin's edge by less than this tips into the basin


@dataclass(frozen=True)
class DropFootprint:
    centre: np.ndarray  # (3,) x-y of the held item's centre, z of the tool point (where to look from above)
    over_basin: bool  # part of it (or, by the tool point alone, the tool) was over the basin's interior
    beyond_basin: bool  # its centre, or a part of it by more than FOOTPRINT_MARGIN, was outside the basin


def drop_footprint(site: np.ndarray, held: np.ndarray | None, sink_lo_hi) -> DropFootprint:
    """Judge where an item fell: `site` is the tool point when it left the gripper, `held` the item's model points
    (base frame) as it was held then (None: not known; the tool point alone decides, as a point)."""
    lo, hi = (np.asarray(v, float)[:2] for v in sink_lo_hi)
    site = np.asarray(site, float)
    if held is None or not len(held):
        inside = bool(np.all(site[:2] >= lo) and np.all(site[:2] <= hi))
        return DropFootprint(site.copy(), inside, not inside)
    xy = np.asarray(held, float).reshape(-1, 3)[:, :2]
    c = 0.5 * (xy.min(axis=0) + xy.max(axis=0))  # the centre of its footprint's box
    over = np.all((xy >= lo) & (xy <= hi), axis=1)
    far_out = ~np.all((xy >= lo - FOOTPRINT_MARGIN) & (xy <= hi + FOOTPRINT_MARGIN), axis=1)
    centre_out = not (np.all(c >= lo) and np.all(c <= hi))
    return DropFootprint(np.array([c[0], c[1], site[2]]), bool(over.any()), bool(centre_out or far_out.any()))
