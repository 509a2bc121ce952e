"""Is the placed object where it should be? A depth check from one view, independent of perception.

The model's surface points at the target pose are projected into the view; where they are the nearest thing
to the camera (a small z-buffer), the measured depth should agree. With the object there most pixels agree;
with it missing the camera sees what lies behind (rack floor, counter) and few agree. Fewer than
`min_pixels` projected pixels (target out of view) gives no decision. Pixels where something is nearer than
predicted (an occluder, the cup it nests in) count neither way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kitchenbot.perception.types import View
from kitchenbot.transforms import inv
from kitchenbot.world.inventory import ObjectModel


@dataclass
class Presence:
    pixels: int  # projected model pixels that are evidence (depth agrees, or is seen behind the object)
    agree: float  # fraction of them that agree within `tol`
    decided: bool
    present: bool
    dz: float = 0.0  # m: the vertical offset from the target that explains the depth best (how far it settled)

    def as_dict(self) -> dict:
        return {"pixels": self.pixels, "agree": round(self.agree, 3), "decided": self.decided, "present": self.present,
                "dz": round(self.dz, 4)}


def target_presence(view: View, model: ObjectModel, T_base_obj: np.ndarray, tol: float = 0.012,
                    min_pixels: int = 40, threshold: float = 0.5, stride: int = 4,
                    dz_range: tuple[float, float] = (-0.035, 0.01), dz_step: float = 0.005,
                    dz_tie: float = 0.93) -> Presence:
    """Best agreement over vertical offsets in `dz_range` (released objects drop and settle a little). Not
    deeper: 5 cm below a cup set on a stack lies the cup under it, which agrees as well as the cup itself would
    (seen as present while it had fallen off the stack: later transfers ran into it).

    The depth often cannot tell offsets a centimetre apart (a plate on edge seen from above: its rim agrees at
    -1 and -2 cm alike). The settled pose becomes the record later motions plan around, and one recorded too low
    lets the gripper come down onto its top edge (a side plate on edge in the rack, 1 cm higher than recorded:
    the palm of the next placement hit it). So `dz` is the highest offset whose agreement is within `dz_tie` of
    the best: recorded no lower than the depth shows it can be."""
    rows: list[Presence] = []
    for dz in np.arange(dz_range[0], dz_range[1] + 1e-9, dz_step):
        T = np.array(T_base_obj, float)
        T[2, 3] += dz
        p = _presence_at(view, model, T, tol, min_pixels, threshold, stride)
        p.dz = float(dz)
        rows.append(p)
    # most agreeing pixels, not the highest fraction: lowering the model turns pixels into "occluded", which
    # would flatter the fraction
    score = [(p.decided, p.agree * p.pixels) for p in rows]
    best = rows[max(range(len(rows)), key=lambda k: score[k])]
    if best.decided:
        top = best.agree * best.pixels
        best.dz = max(p.dz for p in rows if p.decided and p.agree * p.pixels >= dz_tie * top)
    return best


def depth_agreement(view: View, model: ObjectModel, T_base_obj: np.ndarray, tol: float = 0.012,
                    stride: int = 2) -> Presence:
    """How well the item at T_base_obj explains the view's depth, at this pose only (no settling offsets): two
    poses of one item compared on the same view."""
    return _presence_at(view, model, T_base_obj, tol, 40, 0.5, stride)


def _presence_at(view: View, model: ObjectModel, T_base_obj: np.ndarray, tol: float, min_pixels: int,
                 threshold: float, stride: int) -> Presence:
    T_cam_obj = inv(view.T_base_cam) @ T_base_obj
    P = model.points @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3]
    P = P[P[:, 2] > 0.05]
    h, w = view.depth.shape
    if not len(P):
        return Presence(0, 0.0, False, False)
    uv = P @ view.K.T
    u = (uv[:, 0] / uv[:, 2] / stride).astype(int)
    v = (uv[:, 1] / uv[:, 2] / stride).astype(int)
    hs, ws = h // stride, w // stride
    ok = (u >= 0) & (u < ws) & (v >= 0) & (v < hs)
    u, v, z = u[ok], v[ok], P[ok, 2]
    zbuf = np.full((hs, ws), np.inf)
    np.minimum.at(zbuf, (v, u), z)
    ys, xs = np.nonzero(np.isfinite(zbuf))
    meas = view.depth[ys * stride + stride // 2, xs * stride + stride // 2]
    good = np.isfinite(meas) & (meas > 0)
    n = int(good.sum())
    if n < min_pixels:
        return Presence(n, 0.0, False, False)
    diff = meas[good] - zbuf[ys[good], xs[good]]
    agree = int(np.sum(np.abs(diff) < tol))
    through = int(np.sum(diff >= tol))  # seen behind where the object should be: evidence it is absent
    # nearer than predicted = something in front (an occluder, the cup it is nested in): no evidence either way
    n = agree + through
    if n < min_pixels:
        return Presence(n, 0.0, False, False)
    frac = agree / n
    return Presence(n, frac, True, frac >= threshold)


# What a placement's check decides (`where_it_went`)
PLACED = "placed"  # at its target: seen there, or gone from the sink where no view can tell
KEPT = "kept"  # let go at its target, no view can tell, and the sink still shows its class: an obstacle there
UNSEEN = "unseen"  # not seen where it was recorded at its target: an obstacle there, looked for around it
NOT_TAKEN = "not_taken"  # still in the sink, not seen at its target, and nothing says it was carried away


def where_it_went(carried: bool, still_in_sink: bool, presence: Presence | None) -> str:
    """Weigh what is known about where a released item went:

    - `carried`: the gripper held it from the lift to its release at the target (polled at every motion poll; a
      slip on the way is a drop, not a release);
    - `still_in_sink`: the sink still shows as many items of its class where it was picked as before the pick;
    - `presence`: the target's view (None: no view; `decided` false: it cannot tell).

    Seen at its target, it is there. Otherwise an item carried to its target and let go there is not in the sink,
    whatever the sink shows where it was picked: an item of its class seen there is another one (it lay under the
    picked one, seen with it as one item before the pick, or revealed by it), and the item stays recorded at its
    target as an obstacle: one view not showing it where it was recorded (a plate on edge seen from above, leaning
    against a tine) is weaker evidence than the hand that put it there, and a record dropped sends the next item
    into the one standing there. Only an item that nothing says was carried away (a put-down whose hold was not
    polled) and that the sink still shows is "not taken"."""
    seen = presence is not None and presence.decided
    if seen and presence.present:
        return PLACED
    if still_in_sink and not seen:
        return KEPT
    if still_in_sink and not carried:
        return NOT_TAKEN
    return UNSEEN if seen else PLACED
