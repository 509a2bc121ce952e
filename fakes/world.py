"""SimWorld: the single source of truth of the simulated kitchen cell.

It holds the cell geometry, the objects and their poses, which object the gripper holds, the true camera
mount, the arm's true joint state, a simulated clock and the fault switches. Fake drivers act on it
(fakes/arm.py, fakes/gripper.py, fakes/camera.py); the renderer (fakes/render.py) draws it.
Nothing here is physics: objects stay where they are put, a held object follows the TCP, a released one is
put down where it is (dropped straight down onto whatever is below).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from kitchenbot.drivers.ur_kinematics import URModel, fk_flange, ur_model
from kitchenbot.transforms import inv
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory, ObjectModel


class SimClock:
    """Simulated seconds. Drivers advance it when something takes time (a motion, a capture)."""

    def __init__(self, t0: float = 0.0):
        self._t = float(t0)

    def now(self) -> float:
        return self._t

    def advance(self, dt: float) -> float:
        if dt < 0:
            raise ValueError(f"SimClock.advance: dt must be >= 0, got {dt}")
        self._t += float(dt)
        return self._t


@dataclass
class Faults:
    """Fault switches the drivers consult. Set by tests or the fault-injection hooks of later issues.

    One-shot counters are decremented when the fault fires; probabilities draw from the world's RNG.
    """

    camera_drop: int = 0  # next N captures time out
    camera_nan_depth: int = 0  # next N captures have NaN/zero depth over the image
    arm_disconnect: bool = False  # the arm link is down until reconnected
    arm_disconnect_after: float | None = None  # drop the link this many seconds into the next motion
    protective_stop: int = 0  # next N motions end in a protective stop halfway
    gripper_overload: int = 0  # next N grasps end in an overload hardware error
    slip_probability: float = 0.0  # chance a held object slips out during a transport motion
    missed_detection: int = 0  # perception hook: next N scans miss an object (used by the executive)


@dataclass
class SimObject:
    uid: int  # unique in the world, >= 1; the instance label in renders
    model: ObjectModel
    T_base_obj: np.ndarray


@dataclass
class TexturedPlane:
    """A flat textured rectangle (e.g. a calibration board). Plane frame: z = normal, image x along +x,
    image y along -y... the image's top-left corner is at (-w/2, +h/2)."""

    name: str
    T_base_plane: np.ndarray
    width: float
    height: float
    image: np.ndarray  # (H, W, 3) uint8


@dataclass
class Fixture:
    """Fixed geometry beyond the cell's boxes (a faucet, a drain, rounded basin corners, a draining rack):
    a triangle mesh in the base frame that is rendered, collided with and rested on like the cell."""

    name: str
    kind: str  # faucet | drain | fillet | rack | ...
    mesh: o3d.geometry.TriangleMesh  # base frame, metres
    colour: tuple[float, float, float]
    shiny: float = 0.1


@dataclass
class SimWorld:
    cell: Cell
    inventory: Inventory
    robot: URModel = field(default_factory=lambda: ur_model("ur5e"))
    T_flange_tcp: np.ndarray = field(default_factory=lambda: np.eye(4))
    T_flange_cam: np.ndarray = field(default_factory=lambda: np.eye(4))  # the truth; calibration must find it
    q: np.ndarray = field(default_factory=lambda: np.array([0.0, -1.9, 1.9, -1.57, -1.57, 0.0]))
    clock: SimClock = field(default_factory=SimClock)
    faults: Faults = field(default_factory=Faults)
    seed: int = 0
    objects: dict[int, SimObject] = field(default_factory=dict)
    planes: dict[str, TexturedPlane] = field(default_factory=dict)
    fixtures: dict[str, Fixture] = field(default_factory=dict)
    held_uid: int | None = None
    T_tcp_held: np.ndarray | None = None
    slip_in_motions: int | None = None  # the held object slips in the motion this many motions from now
    gripper_opening: float = 0.10  # m between the finger pads; FakeGripper keeps it current (collision model)
    version: int = 0  # bumped on every geometric change (render/collision caches key on it)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self._uids = itertools.count(1)

    # ---- objects -------------------------------------------------------------------------------------
    def add_object(self, model: ObjectModel, T_base_obj: np.ndarray) -> int:
        uid = next(self._uids)
        self.objects[uid] = SimObject(uid, model, np.array(T_base_obj, float))
        self.version += 1
        return uid

    def remove_object(self, uid: int) -> None:
        self.objects.pop(uid)
        if self.held_uid == uid:
            self.held_uid, self.T_tcp_held = None, None
        self.version += 1

    def set_pose(self, uid: int, T_base_obj: np.ndarray) -> None:
        self.objects[uid].T_base_obj = np.array(T_base_obj, float)
        self.version += 1

    def add_textured_plane(self, name: str, T_base_plane: np.ndarray, width_m: float, height_m: float,
                           rgb_image: np.ndarray) -> None:
        img = np.asarray(rgb_image)
        if img.ndim == 2:
            img = np.repeat(img[:, :, None], 3, axis=2)
        if img.dtype != np.uint8 or img.shape[2] != 3:
            raise ValueError(f"add_textured_plane {name!r}: expected an (H, W, 3) or (H, W) uint8 image")
        self.planes[name] = TexturedPlane(name, np.array(T_base_plane, float), float(width_m), float(height_m), img)
        self.version += 1

    def add_fixture(self, fixture: Fixture) -> None:
        if len(fixture.mesh.triangles) == 0:
            raise ValueError(f"add_fixture {fixture.name!r}: the mesh has no triangles")
        self.fixtures[fixture.name] = fixture
        self.version += 1

    # ---- the arm's truth -------------------------------------------------------------------------------
    def set_joints(self, q: np.ndarray) -> None:
        self.q = np.array(q, float)
        if self.held_uid is not None:
            self.objects[self.held_uid].T_base_obj = self.T_base_tcp() @ self.T_tcp_held
        self.version += 1

    def T_base_flange(self) -> np.ndarray:
        return fk_flange(self.robot, self.q)

    def T_base_tcp(self) -> np.ndarray:
        return self.T_base_flange() @ self.T_flange_tcp

    def T_base_cam(self) -> np.ndarray:
        return self.T_base_flange() @ self.T_flange_cam

    # ---- grasping -----------------------------------------------------------------------------------------
    def attach(self, uid: int, slip: bool = True) -> None:
        """The gripper now holds `uid`; it keeps its pose relative to the TCP.

        Slip is drawn once per hold (per transport): with `faults.slip_probability` the object will slip out
        during one of the next three arm motions (lift, transit or the move to the target), chosen at random.
        `slip=False`: no slip draw (an object dragged along under the pressing fingers, see FakeArm).
        """
        self.held_uid = uid
        self.T_tcp_held = inv(self.T_base_tcp()) @ self.objects[uid].T_base_obj
        if not slip:
            self.slip_in_motions = None
            return
        p = self.faults.slip_probability
        self.slip_in_motions = int(self.rng.integers(0, 3)) if p > 0 and self.rng.random() < p else None

    def release(self) -> int | None:
        """Let go of the held object: it stays or drops straight down onto what is below it (never onto an item
        lying on it)."""
        uid = self.held_uid
        if uid is None:
            return None
        self.held_uid, self.T_tcp_held = None, None
        from kitchenbot.fakes.placement import drop_released

        obj = self.objects[uid]
        obj.T_base_obj = drop_released(self, uid, obj.T_base_obj)
        self.version += 1
        return uid

    # ---- geometry -------------------------------------------------------------------------------------------
    def object_mesh(self, uid: int) -> o3d.geometry.TriangleMesh:
        o = self.objects[uid]
        m = o3d.geometry.TriangleMesh(o.model.mesh)
        m.transform(o.T_base_obj)
        return m

    def objects_in_sink(self) -> list[int]:
        return [u for u, o in self.objects.items() if u != self.held_uid and self.cell.in_sink(o.T_base_obj[:3, 3])[0]]
