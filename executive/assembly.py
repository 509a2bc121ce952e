"""Cell assembly: turn a validated CellConfig into connected devices, the inventory and the cell geometry.

`assemble(config)` is the only place that picks implementations: fake drivers over a simulated kitchen
(a SimWorld from `config.sim`), or the real UR / Dynamixel / OAK-D drivers, or the replay camera.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kitchenbot.drivers.arm import Arm
from kitchenbot.drivers.camera import Camera
from kitchenbot.drivers.gripper import Gripper
from kitchenbot.drivers.ur_kinematics import ur_model
from kitchenbot.executive.config import CellConfig
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory


@dataclass
class RobotCell:
    config: CellConfig
    arm: Arm
    gripper: Gripper
    camera: Camera
    inventory: Inventory
    cell: Cell
    T_flange_cam: np.ndarray
    world: object | None = None  # the SimWorld when any driver is simulated
    connected: bool = field(default=False)

    def connect(self) -> None:
        for dev in (self.arm, self.gripper, self.camera):
            dev.connect()
        self.connected = True

    def disconnect(self) -> None:
        for dev in (self.camera, self.gripper, self.arm):
            try:
                dev.disconnect()
            except Exception:  # noqa: BLE001 - disconnect everything we can
                pass
        self.connected = False


def load_inventory(config: CellConfig) -> Inventory:
    inv_cfg = config.inventory
    if inv_cfg.models_dir == "builtin":
        return Inventory.builtin()
    grasps = config.resolve_path(inv_cfg.grasps_file) if inv_cfg.grasps_file else None
    return Inventory.load(config.resolve_path(inv_cfg.models_dir), grasps, inv_cfg.classes)


def make_sim_world(config: CellConfig, seed: int | None = None, inventory: Inventory | None = None):
    """A random sink scene in the configured cell, with the configured robot, tool and camera mount."""
    from kitchenbot.fakes.scenes import SceneOptions, generate_scene

    sim = config.sim
    world = generate_scene(
        sim.seed if seed is None else seed,
        inventory or load_inventory(config),
        cell_spec=config.cell,
        options=SceneOptions(min_objects=sim.min_objects, max_objects=sim.max_objects, style=sim.style),
        world_kwargs={
            "robot": ur_model(config.robot.model),
            "T_flange_tcp": config.robot.tool.T_flange_tcp.matrix(),
            "T_flange_cam": config.T_flange_cam(),
        },
    )
    world.faults.slip_probability = sim.slip_probability
    world.set_joints(np.asarray(config.robot.home, float))
    return world


def assemble(config: CellConfig, seed: int | None = None, world=None) -> RobotCell:
    """Build (but do not connect) the devices the config names."""
    inventory = world.inventory if world is not None else load_inventory(config)
    limits = config.safety_limits()
    model = ur_model(config.robot.model)
    d = config.drivers
    needs_world = "fake" in (d.arm.kind, d.gripper.kind, d.camera.kind)
    if needs_world and world is None:
        world = make_sim_world(config, seed, inventory)

    if d.arm.kind == "fake":
        from kitchenbot.fakes.arm import FakeArm

        arm: Arm = FakeArm(world, limits, model=model)
    else:
        from kitchenbot.drivers.ur_rtde_arm import URArm

        arm = URArm(model, limits, d.arm.host, frequency=d.arm.frequency, receive_timeout=d.arm.receive_timeout,
                    connect_timeout=d.arm.connect_timeout, upper_range_registers=d.arm.upper_range_registers,
                    payload_kg=config.robot.tool.payload_kg, cog=config.robot.tool.cog)

    if d.gripper.kind == "fake":
        from kitchenbot.fakes.gripper import FakeGripper

        gripper: Gripper = FakeGripper(world)
    else:
        from kitchenbot.drivers.dynamixel_gripper import DynamixelGripper

        gripper = DynamixelGripper(d.gripper.port, d.gripper.baudrate, d.gripper.servo_id,
                                   closed_ticks=d.gripper.closed_ticks, open_ticks=d.gripper.open_ticks,
                                   max_opening=d.gripper.max_opening, current_limit_ma=d.gripper.current_limit_ma,
                                   min_packet_timeout_ms=d.gripper.min_packet_timeout_ms)

    if d.camera.kind == "fake":
        from kitchenbot.fakes.camera import FakeCamera

        camera: Camera = FakeCamera(world, d.camera.width, d.camera.height,
                                    pose_noise_m=config.sim.scan_pose_noise_m,
                                    pose_noise_deg=config.sim.scan_pose_noise_deg)
    elif d.camera.kind == "oakd":
        from kitchenbot.drivers.oakd_camera import OakDCamera

        camera = OakDCamera(width=d.camera.width, height=d.camera.height, fps=d.camera.fps,
                            device_id=d.camera.device_id)
    else:
        from kitchenbot.drivers.replay_camera import ReplayCamera

        camera = ReplayCamera(config.resolve_path(d.camera.directory))

    return RobotCell(config, arm, gripper, camera, inventory, Cell(config.cell), config.T_flange_cam(), world)
