"""The Fin-Ray gripper's geometry, in the TCP frame (z = approach, out of the gripper into the object; y = the
closing axis between the two pads; x = y x z), metres. One description for every layer:

- ``MAX_OPENING`` and ``PAD_DEPTH``: what the fingers can do (the driver's calibrated ``max_opening`` may be
  smaller on a given gripper; the config says so);
- ``FINGERS``: the physical palm and fingers (the simulator's contact model, fakes/collision.py);
- ``PAD_ENVELOPE``: the pads as the planner and grasp synthesis check them, a little larger than the fingers
  (planning/collision.py ``GripperGeometry``, planning/grasp_synthesis.py), so the planner stays the more
  conservative of the two.
- ``DROP_HEIGHT``: how far above its resting pose the gripper lets an item go (it settles by that much).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_OPENING = 0.10  # m, Fin-Ray pads fully open
PAD_DEPTH = 0.035  # m, how far the pads reach back from the finger tips along the approach axis
DROP_HEIGHT = 0.01  # m above the resting pose at release (place targets are release poses)


@dataclass(frozen=True)
class FingerGeometry:
    """The physical palm and fingers: boxes in the TCP frame. The fingers end `tip_z` past the TCP; the pads are
    their inner faces over the last PAD_DEPTH."""

    palm_half_xy: tuple[float, float] = (0.035, 0.065)
    palm_z: tuple[float, float] = (-0.20, -0.11)  # the flange sits at -0.20 with the default tool
    finger_half_x: float = 0.0125
    finger_thickness: float = 0.012
    finger_z0: float = -0.11
    tip_z: float = 0.010

    @property
    def pad_z(self) -> tuple[float, float]:
        return (self.tip_z - PAD_DEPTH, self.tip_z)

    def boxes(self, opening: float) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """(name, lower, upper) of the palm and the two fingers, TCP frame, at a pad distance `opening`."""
        hx, hy = self.palm_half_xy
        o = max(0.0, float(opening)) / 2
        t, fx = self.finger_thickness, self.finger_half_x
        return [
            ("palm", np.array([-hx, -hy, self.palm_z[0]]), np.array([hx, hy, self.palm_z[1]])),
            ("finger_pos", np.array([-fx, o, self.finger_z0]), np.array([fx, o + t, self.tip_z])),
            ("finger_neg", np.array([-fx, -o - t, self.finger_z0]), np.array([fx, -o, self.tip_z])),
        ]


@dataclass(frozen=True)
class PadEnvelope:
    """The pad boxes the planner collides and grasp synthesis checks: 26 mm wide (x), 16 mm thick (y, outwards
    from the pad face at +-opening/2), from the pad roots (the palm's bottom) 70 mm behind the TCP to the tips
    12 mm past it (2 mm past the physical tips)."""

    width: float = 0.026  # along x
    thickness: float = 0.016  # along y
    root: float = -0.07  # z of the pad roots in the TCP frame
    tip: float = 0.012


FINGERS = FingerGeometry()
PAD_ENVELOPE = PadEnvelope()
