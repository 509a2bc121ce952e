"""Whether a grasp backed off along its approach (a shallower bite, planning.grasps.BITES) still holds its item.

The grasp filter backs a grasp off by up to 8 mm when the finger tips would touch what the item rests on: a
Fin-Ray grasp still holds with a shallower bite. Not on a short wall: a bowl's foot ring stands 10 mm proud and its
pinch reaches 7 mm over it (TCP 3 mm short of the ring's end, the physical finger tips 10 mm past the TCP), so 8 mm
back the fingers end 1 mm short of the ring and close on air (`grasp_missed`; every foot pinch of a bowl nested
upside down over another was backed off so, and each missed). A bite is kept only where the fingers still reach
onto the item: a line across the closing axis MIN_REACH inside the physical finger tips, through the pads' middle
or 5 mm to either side across their width, crosses the item's mesh (as the simulated pads feel it, fakes.gripper).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.transforms import trans
from kitchenbot.world.gripper import FINGERS
from kitchenbot.world.inventory import ObjectModel

MIN_REACH = 0.002  # m: how far onto the item the finger tips must reach at a backed-off bite
ACROSS_PAD = (-0.005, 0.0, 0.005)  # m: where across the pads' width (TCP x) the lines run
HALF_LINE = 0.06  # m: the lines start this far either side of the TCP, outside any item a grasp closes on

_scenes: dict[int, tuple] = {}  # id(model) -> (model, its ray scene)


def _scene(model: ObjectModel) -> o3d.t.geometry.RaycastingScene:
    hit = _scenes.get(id(model))
    if hit is None or hit[0] is not model:
        if len(_scenes) > 64:
            _scenes.clear()
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(model.mesh))
        hit = _scenes[id(model)] = (model, scene)
    return hit[1]


def fingers_reach(model: ObjectModel, T_obj_tcp: np.ndarray) -> bool:
    """Whether the fingers of a grasp at `T_obj_tcp` (the TCP in the item's frame) reach MIN_REACH onto the item:
    some line across the closing axis (TCP y) at that depth, through the pads (ACROSS_PAD), crosses its mesh."""
    T = np.asarray(T_obj_tcp, float)
    x, y, z, p = T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3]
    centres = np.array([p + z * (FINGERS.tip_z - MIN_REACH) + x * dx for dx in ACROSS_PAD])
    n = len(centres)
    rays = np.vstack([np.hstack([centres - y * HALF_LINE, np.broadcast_to(y, (n, 3))]),
                      np.hstack([centres + y * HALF_LINE, np.broadcast_to(-y, (n, 3))])]).astype(np.float32)
    t = _scene(model).cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    return bool(np.any(np.isfinite(t[:n]) & np.isfinite(t[n:]) & (t[:n] + t[n:] < 2 * HALF_LINE)))


_backed: dict[tuple, tuple[ObjectModel, bool]] = {}  # (id(model), T_obj_tcp bytes, back) -> (model, answer)


def fingers_reach_backed_off(model: ObjectModel, T_obj_tcp: np.ndarray, back: float) -> bool:
    """:func:`fingers_reach` for the grasp `T_obj_tcp` (the TCP in the item's frame) backed off `back` metres along
    its approach (TCP -z). It depends on the item's model and the grasp alone, not on where the item lies, so it is
    kept: grasp selection asks it for every candidate at every shallower bite, the same grasps again each plan."""
    T = np.asarray(T_obj_tcp, float)
    key = (id(model), T.tobytes(), float(back))
    hit = _backed.get(key)
    if hit is None or hit[0] is not model:
        if len(_backed) > 20000:
            _backed.clear()
        hit = _backed[key] = (model, fingers_reach(model, T @ trans(0.0, 0.0, -float(back))))
    return hit[1]
