"""Grasps whose pads brush a neighbour: the compliant contact allowance of the Fin-Ray pads, bounded.

In a pile an item often has no grasp whose pads keep clear of the item beside it: the planner's pad envelope
(world.gripper.PAD_ENVELOPE, 16 mm thick) is 4 mm thicker outwards than the physical finger (FINGERS, 12 mm), and a
neighbour standing against the target reaches into that outer part. Such a grasp is rejected by the strict check,
and where every grasp of the item is, the item is never picked (a pile where two items each block the other's
grasps ends with both left in the sink).

A pad may touch a neighbour (a perceived object other than the target; never a cell surface, the map's voxels,
the palm, the camera or the arm) when the neighbour reaches no deeper than ``give`` into the pad's outer face over
the whole grasp-in: the pad box less its outer ``give``, swept from the pre-grasp to the grasp along the approach,
is clear of the neighbour's mesh (no margin). With ``give`` = envelope thickness - finger thickness - 1 mm (3 mm)
the physical finger stays 1 mm clear of the neighbour where the poses are right; where the neighbour is a few
millimetres nearer than perceived, the finger's compliance pushes it aside.

Why hand-written: coal gives the box-mesh overlap test; which contacts a soft finger tolerates is this gripper's
rule, not a library's.
"""

from __future__ import annotations

import coal
import numpy as np

from kitchenbot.planning.collision import PADS, Scene, coal_transform
from kitchenbot.transforms import make_T
from kitchenbot.world.gripper import FINGERS, PAD_ENVELOPE

# m a neighbour may reach into a pad envelope's outer face (see the module docstring)
PAD_GIVE = round(PAD_ENVELOPE.thickness - FINGERS.finger_thickness - 0.001, 4)


def core_sweeps(opening: float, approach: float, give: float, gripper) -> list[tuple[coal.Box, np.ndarray]]:
    """Each pad less its outer `give` (TCP frame), swept `approach` metres back along the approach axis."""
    t = gripper.pad_thickness - give
    z0, z1 = gripper.pad_root - approach, gripper.pad_tip
    box = coal.Box(gripper.pad_width, max(t, 1e-4), z1 - z0)
    y = opening / 2 + t / 2
    return [(box, make_T(t=(0.0, s * y, (z0 + z1) / 2))) for s in (1.0, -1.0)]


def pad_contacts(grasp_scene: Scene, q: np.ndarray, T_base_tcp: np.ndarray, opening: float, target: str,
                 approach: float, give: float = PAD_GIVE) -> list[tuple[str, str]] | None:
    """The (pad, neighbour) pairs to allow for this grasp, or None when it is not one the pads' give admits.

    `grasp_scene`: the target's grasp scene (Scene.for_grasp), pads at `opening`, in which `q` (the grasp) is
    not valid; `target`: its ``obj:<name>``. Admitted when every colliding pair at `q` is a pad with another
    perceived object, the scene allowing those pairs is valid at `q`, and each such neighbour stays out of the
    pads' swept cores (core_sweeps)."""
    if give <= 0.0:
        return None
    pairs = grasp_scene.colliding_pairs(q)
    if not pairs:
        return None
    neighbours: set[str] = set()
    for a, b in pairs:
        pad, other = (a, b) if a in PADS else (b, a)
        if pad not in PADS or not other.startswith("obj:") or other == target:
            return None
        neighbours.add(other)
    allowed = [(pad, n) for n in neighbours for pad in PADS]
    if not grasp_scene.allowing_keep_zone(allowed).valid(q):
        return None
    gripper = grasp_scene.world.gripper
    cores = [(box, coal_transform(np.asarray(T_base_tcp, float) @ T))
             for box, T in core_sweeps(opening, approach, give, gripper)]
    req = coal.CollisionRequest()
    for n in neighbours:
        gid = grasp_scene.names.index(n)
        go = grasp_scene.gm.geometryObjects[gid]
        T_n = coal.Transform3s(go.placement.rotation, go.placement.translation)  # env objects hang off the base
        if any(coal.collide(box, Tb, go.geometry, T_n, req, coal.CollisionResult()) for box, Tb in cores):
            return None
    return allowed
