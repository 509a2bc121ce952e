"""The cell configuration: one YAML file, validated by pydantic.

Which drivers (fake or real, addresses and ports), the robot model and its limits, the tool, the calibration
file, the inventory, the perception backends and planning settings, and the cell geometry. Every field has a
default that runs the simulation (``config/sim.yaml`` ships with the project and documents them).

A bad value raises :class:`ConfigError` naming the file, the field path and what was expected.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from kitchenbot.drivers.safety import SafetyLimits, Workspace
from kitchenbot.drivers.ur_kinematics import UR_MODELS, ur_model
from kitchenbot.perception.settings import PerceptionSettings
from kitchenbot.planning.settings import PlanningSettings
from kitchenbot.transforms import from_xyz_rpy
from kitchenbot.world.cell import CellSpec

PACKAGE_DIR = Path(__file__).resolve().parent.parent
DEFAULT_CONFIG = PACKAGE_DIR / "config" / "sim.yaml"


class ConfigError(ValueError):
    """A configuration file could not be read or a value is invalid."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Pose(_Strict):
    """A pose as translation (m) + roll-pitch-yaw (rad)."""

    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def matrix(self) -> np.ndarray:
        return from_xyz_rpy(self.xyz, self.rpy)


Six = Annotated[list[float], Field(min_length=6, max_length=6)]


class LimitsConfig(_Strict):
    """Narrows the data-sheet limits. Unset joint limits take the robot model's."""

    joint_lower: Six | None = None
    joint_upper: Six | None = None
    max_joint_speed: float = Field(1.5, gt=0, le=6.3, description="rad/s, any joint")
    max_joint_accel: float = Field(3.0, gt=0, le=40.0, description="rad/s^2, any joint")
    max_tcp_speed: float = Field(0.5, gt=0, le=1.0, description="m/s (UR e-Series max 1 m/s)")
    workspace_lower: tuple[float, float, float] = (-0.40, -0.95, -0.35)
    workspace_upper: tuple[float, float, float] = (0.98, 0.95, 0.90)


class ToolConfig(_Strict):
    T_flange_tcp: Pose = Pose(xyz=(0.0, 0.0, 0.20))
    payload_kg: float = Field(0.9, ge=0.0, le=20.0)
    cog: tuple[float, float, float] = (0.0, 0.0, 0.06)


class RobotConfig(_Strict):
    model: str = "ur5e"
    limits: LimitsConfig = LimitsConfig()
    tool: ToolConfig = ToolConfig()
    home: Six = Field(default_factory=lambda: [3.1416, -1.9, 1.9, -1.57, -1.57, 0.0])

    @field_validator("model")
    @classmethod
    def _known_model(cls, v: str) -> str:
        if v.lower() not in UR_MODELS:
            raise ValueError(f"expected one of {sorted(UR_MODELS)}")
        return v.lower()


class FakeArmConfig(_Strict):
    kind: Literal["fake"] = "fake"


class URArmConfig(_Strict):
    kind: Literal["ur_rtde"] = "ur_rtde"
    host: str = "192.168.1.10"
    frequency: float = Field(500.0, gt=0, le=500)
    receive_timeout: float = Field(0.1, gt=0, description="RTDE data older than this (seconds) = stalled")
    connect_timeout: float = Field(2.0, gt=0, le=30, description="seconds for each connection step to answer")
    upper_range_registers: bool = Field(
        False, description="use RTDE input registers 24-47 (when a fieldbus adapter holds 0-23)")


class FakeGripperConfig(_Strict):
    kind: Literal["fake"] = "fake"


class DynamixelGripperConfig(_Strict):
    kind: Literal["dynamixel"] = "dynamixel"
    port: str = "/dev/ttyUSB0"
    baudrate: int = Field(57600, gt=0)
    servo_id: int = Field(1, ge=0, le=252)
    current_limit_ma: float = Field(600.0, gt=0, le=3200.0)
    closed_ticks: int = Field(2048, description="servo position where the finger pads touch (linear calibration)")
    open_ticks: int = Field(3072, description="servo position where the pads are max_opening apart")
    max_opening: float = Field(0.085, gt=0, le=0.3, description="m between the pads at open_ticks")
    min_packet_timeout_ms: float = Field(0.0, ge=0, le=2000, description="floor on the status-packet timeout "
                                         "(0: the SDK's ~34 ms); raise it for a slow USB hub or an emulator")


class FakeCameraConfig(_Strict):
    kind: Literal["fake"] = "fake"
    width: int = Field(640, ge=64, le=4096)
    height: int = Field(480, ge=48, le=4096)


class OakDCameraConfig(_Strict):
    kind: Literal["oakd"] = "oakd"
    width: int = Field(640, ge=64, le=4096)
    height: int = Field(480, ge=48, le=4096)
    fps: float = Field(15.0, gt=0, le=60)
    device_id: str | None = None


class ReplayCameraConfig(_Strict):
    kind: Literal["replay"] = "replay"
    directory: str


class DriversConfig(_Strict):
    arm: FakeArmConfig | URArmConfig = Field(FakeArmConfig(), discriminator="kind")
    gripper: FakeGripperConfig | DynamixelGripperConfig = Field(FakeGripperConfig(), discriminator="kind")
    camera: FakeCameraConfig | OakDCameraConfig | ReplayCameraConfig = Field(FakeCameraConfig(), discriminator="kind")


class CalibrationConfig(_Strict):
    file: str | None = Field(None, description="hand-eye YAML from `kitchenbot calibrate`; overrides T_flange_cam")
    T_flange_cam: Pose = Pose(xyz=(0.0, -0.07, 0.04), rpy=(0.0, 0.0, 0.0))


class InventoryConfig(_Strict):
    models_dir: str = Field("builtin", description="'builtin' or a BOP models/ folder")
    grasps_file: str | None = Field(None, description="grasps JSON for a BOP models/ folder (optional: grasps are "
                                                      "synthesised from the meshes)")
    classes: dict[int, Literal["plate", "bowl", "cup", "mug", "glass"]] = Field(
        default_factory=dict, description="obj_id -> class, where the class from the mesh's shape is not right")


class SimConfig(_Strict):
    seed: int = 0
    style: Literal["stainless", "ceramic", "random"] = "random"
    min_objects: int = Field(3, ge=0, le=30)
    max_objects: int = Field(10, ge=0, le=30)
    slip_probability: float = Field(0.0, ge=0.0, le=1.0, description="chance an object slips in transport")
    scan_pose_noise_m: float = Field(0.0, ge=0.0, le=0.05)
    scan_pose_noise_deg: float = Field(0.0, ge=0.0, le=5.0)

    @model_validator(mode="after")
    def _range(self) -> "SimConfig":
        if self.min_objects > self.max_objects:
            raise ValueError("min_objects must be <= max_objects")
        return self


class CellConfig(_Strict):
    robot: RobotConfig = RobotConfig()
    drivers: DriversConfig = DriversConfig()
    calibration: CalibrationConfig = CalibrationConfig()
    inventory: InventoryConfig = InventoryConfig()
    perception: PerceptionSettings = PerceptionSettings()
    planning: PlanningSettings = PlanningSettings()
    cell: CellSpec = CellSpec()
    sim: SimConfig = SimConfig()
    scan_waypoints: list[Six] = Field(
        default_factory=lambda: [
            [2.598, -2.638, 2.552, -1.873, -1.347, 0.425],
            [3.541, -1.723, 2.133, -1.959, -2.105, -0.054],
            [2.198, -1.734, 2.006, -1.53, -1.13, 0.142],
        ],
        description="joint configurations (rad) the arm visits to scan the sink",
    )
    source: str | None = Field(None, exclude=True, description="file this config came from")

    # ---- derived objects -------------------------------------------------------------------------------
    def safety_limits(self) -> SafetyLimits:
        m = ur_model(self.robot.model)
        lim = self.robot.limits
        lo = np.array(lim.joint_lower if lim.joint_lower is not None else m.joint_lower, float)
        hi = np.array(lim.joint_upper if lim.joint_upper is not None else m.joint_upper, float)
        return SafetyLimits(
            joint_lower=np.maximum(lo, m.joint_lower),
            joint_upper=np.minimum(hi, m.joint_upper),
            max_joint_speed=np.minimum(np.array(m.max_joint_speed), lim.max_joint_speed),
            max_joint_accel=np.full(6, lim.max_joint_accel),
            max_tcp_speed=lim.max_tcp_speed,
            workspace=Workspace(np.array(lim.workspace_lower, float), np.array(lim.workspace_upper, float)),
            T_flange_tcp=self.robot.tool.T_flange_tcp.matrix(),
        )

    def T_flange_cam(self) -> np.ndarray:
        """The hand-eye transform: from `calibration.file` (a `kitchenbot calibrate` YAML, path relative to
        this config) when set, else `calibration.T_flange_cam`."""
        if self.calibration.file:
            from kitchenbot.calibration.files import load_hand_eye

            return load_hand_eye(self.resolve_path(self.calibration.file), "T_flange_cam")
        return self.calibration.T_flange_cam.matrix()

    def resolve_path(self, p: str) -> Path:
        """Paths in a config file are relative to that file."""
        path = Path(p).expanduser()
        if not path.is_absolute() and self.source:
            path = Path(self.source).parent / path
        return path


def _format_error(source: str, err: ValidationError) -> str:
    lines = [f"{source}: invalid configuration"]
    for e in err.errors():
        loc = ".".join(str(x) for x in e["loc"]) or "(top level)"
        got = e.get("input")
        got_s = "" if isinstance(got, dict) else f" (got {got!r})"
        lines.append(f"  {loc}: {e['msg']}{got_s}")
    return "\n".join(lines)


def load_config(path: str | Path | None = None) -> CellConfig:
    """Read and validate a cell config; None gives the shipped simulation config."""
    path = Path(path) if path is not None else DEFAULT_CONFIG
    try:
        text = path.read_text()
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the config file ({e.strerror})") from None
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML: {e}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of sections at the top level, got {type(data).__name__}")
    try:
        cfg = CellConfig.model_validate(data)
    except ValidationError as e:
        raise ConfigError(_format_error(str(path), e)) from None
    cfg.source = str(path.resolve())
    return cfg
