"""A minimal kinematic arm and a board-only pinhole camera for routine tests that must not depend on the
simulated cell (fakes): the arm jumps to its target, the camera warps the rendered board through the true
(hidden) mount."""

from __future__ import annotations

import numpy as np

from kitchenbot.calibration.board import CharucoSpec, render_board, warp_board
from kitchenbot.drivers.arm import Arm, ArmState, SafetyState
from kitchenbot.drivers.camera import Camera, Frame
from kitchenbot.drivers.ur_kinematics import fk_flange
from kitchenbot.transforms import inv

K = np.array([[520.0, 0.0, 320.0], [0.0, 520.0, 240.0], [0.0, 0.0, 1.0]])
PPM, MARGIN = 4000.0, 12


class JumpArm(Arm):
    def __init__(self, model, limits, q0):
        super().__init__(model, limits)
        self.q = np.array(q0, float)
        self.moves = 0

    def connect(self): ...
    def disconnect(self): ...

    @property
    def is_connected(self):
        return True

    def joint_positions(self):
        return self.q.copy()

    def state(self):
        return ArmState(self.q.copy(), np.zeros(6), self.tcp_pose(), SafetyState.NORMAL, False, 0.0)

    def safety_state(self):
        return SafetyState.NORMAL

    def is_moving(self):
        return False

    def wait(self, timeout=None): ...
    def stop(self, decel=3.0): ...

    def _move_joints(self, q, speed, accel, asynchronous):
        self.q = np.array(q, float)
        self.moves += 1

    def _move_linear(self, T, speed, accel, asynchronous):
        raise NotImplementedError

    def _execute_trajectory(self, times, q, asynchronous, guarded=False):
        raise NotImplementedError

    def _unlock_protective_stop(self): ...


class BoardCamera(Camera):
    def __init__(self, arm: JumpArm, T_flange_cam: np.ndarray, T_base_board: np.ndarray, spec: CharucoSpec):
        self.arm, self.X, self.T_base_board, self.spec = arm, T_flange_cam, T_base_board, spec
        self.image = render_board(spec, PPM, MARGIN)

    def connect(self): ...
    def disconnect(self): ...

    @property
    def is_connected(self):
        return True

    def intrinsics(self):
        return K.copy()

    def capture(self, timeout=2.0):
        T_cam_board = inv(fk_flange(self.arm.model, self.arm.q) @ self.X) @ self.T_base_board
        g = warp_board(self.image, PPM, MARGIN, K, T_cam_board, (640, 480), supersample=2)
        return Frame(np.repeat(g[:, :, None], 3, axis=2), np.zeros((480, 640), np.float32), K.copy(), 0.0)
