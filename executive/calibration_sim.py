"""The simulated calibration cell for `kitchenbot calibrate --sim`: the configured cell with fake drivers, a
ChArUco board lying on the counter (stacking area), a camera mount that differs from the configured one by a
few millimetres and degrees (the hidden truth the routine must find), and the arm moved to a pose that sees
the board, as an operator would jog it before starting.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from kitchenbot.calibration.board import CharucoSpec, render_board
from kitchenbot.calibration.routine import ik_flange, look_at
from kitchenbot.executive.config import CellConfig, DriversConfig
from kitchenbot.transforms import inv, make_T, rot_z, trans

BOARD_PX_PER_M = 4000.0  # texture resolution: ~4x the camera's pixels on the board at 0.4 m
BOARD_MARGIN_PX = 40  # white border around the squares (1 cm)


@dataclass
class CalibrationSim:
    world: object  # fakes.world.SimWorld
    arm: object  # fakes.arm.FakeArm (connected)
    camera: object  # fakes.camera.FakeCamera (connected)
    T_base_board: np.ndarray  # truth
    T_flange_cam_nominal: np.ndarray  # what the config says


def board_on_plane(spec: CharucoSpec, ppm: float = BOARD_PX_PER_M, margin_px: int = BOARD_MARGIN_PX):
    """(rgb image, width m, height m, T_plane_board) for a SimWorld textured plane showing the board.

    SimWorld planes are centred, z = normal, image x along +x and image rows along -y; the board frame has its
    origin at the squares' top-left corner, x along columns, y along rows, z into the board (= -normal).
    """
    img = render_board(spec, ppm, margin_px)
    h_px, w_px = img.shape
    w, h = w_px / ppm, h_px / ppm
    T_plane_board = make_T(np.diag([1.0, -1.0, -1.0]), [-w / 2 + margin_px / ppm, h / 2 - margin_px / ppm, 0.0])
    return np.repeat(img[:, :, None], 3, axis=2), w, h, T_plane_board


def make_calibration_sim(cfg: CellConfig, spec: CharucoSpec, seed: int = 0, mount_error_mm: float = 4.0,
                         mount_error_deg: float = 1.5) -> CalibrationSim:
    from kitchenbot.executive.assembly import assemble

    cfg = cfg.model_copy(deep=True)
    cfg.drivers = DriversConfig()  # --sim: fake arm, gripper and camera whatever the file says
    cell = assemble(cfg, seed=seed)
    world = cell.world
    rng = np.random.default_rng(seed + 1000)
    nominal = cfg.T_flange_cam()  # the config's mount (its calibration file, if any)
    # The hidden truth: the mount as built differs from the drawing.
    dR = Rotation.from_rotvec(rng.normal(size=3) / np.sqrt(3) * np.deg2rad(mount_error_deg)).as_matrix()
    dt = rng.normal(size=3) / np.sqrt(3) * mount_error_mm / 1000.0
    world.T_flange_cam = nominal @ make_T(dR, dt)

    # The board on the counter's stacking area (free of dishes), 2 mm above the top, turned a little.
    area = cfg.cell.stacking_area
    centre = np.array([area.origin_xy[0] + area.size_xy[0] / 2, area.origin_xy[1] + area.size_xy[1] / 2,
                       area.z + 0.002])
    img, w, h, T_plane_board = board_on_plane(spec)
    T_base_plane = trans(*centre) @ rot_z(float(rng.uniform(-0.4, 0.4)))
    world.add_textured_plane("charuco", T_base_plane, w, h, img)
    T_base_board = T_base_plane @ T_plane_board

    # Start pose: the camera ~0.42 m above the board centre, slightly tilted (a fronto-parallel first view is
    # the worst conditioned for PnP), reached from home with a joint move like an operator's jog.
    bw, bh = spec.size_m
    c = (T_base_board @ np.array([bw / 2, bh / 2, 0.0, 1.0]))[:3]
    eye = c + np.array([-0.10, 0.0, 0.40])
    T_base_cam0 = look_at(eye, c, roll=float(rng.uniform(-0.3, 0.3)))
    seed_q = np.asarray(cfg.robot.home, float).copy()
    seed_q[0] = np.arctan2(c[1], c[0]) + np.pi
    seed_q[0] = (seed_q[0] + np.pi) % (2 * np.pi) - np.pi if abs(seed_q[0]) > 2 * np.pi else seed_q[0]
    limits = cfg.safety_limits()
    q0 = ik_flange(cell.arm.model, T_base_cam0 @ inv(nominal), seed_q, limits.joint_lower, limits.joint_upper)
    if q0 is None:
        raise ValueError("calibration sim: no IK solution for a start pose above the board (check robot.home)")
    cell.arm.connect()
    cell.camera.connect()
    cell.arm.move_joints(q0, speed=1.0, accel=2.0)
    return CalibrationSim(world, cell.arm, cell.camera, T_base_board, nominal)
