"""FakeGripper: the Fin-Ray gripper on a Dynamixel in current-based position mode, acting on a SimWorld.

- ``open(opening)`` moves the pads at `speed` (simulated time); opening while holding lets the object go
  (``world.release()``: it drops onto what is below).
- ``grasp(current_limit)`` closes until the pads touch what is between them, or until fully closed. Contact:
  objects whose mesh lies in the pad region (TCP frame: |x| <= 1 cm, |y| <= opening/2, z over the pad
  length ending at the finger tips, see world.gripper.FingerGeometry) are probed with rays along the
  closing axis from each pad inwards, as planning.grasp_synthesis.pad_span does; each pad stops at the first
  surface it meets. Fin-Ray pads conform, so the span is taken on lines near the pad centre (+-5 mm), and over
  the whole pad face only if nothing crosses the centre. Stalled on an object: holding, opening = the
  object's span, current near the limit, the object is attached to the TCP (``world.attach``). Nothing in
  between: closed (~0), not holding, small current.
- Faults (``world.faults``): ``gripper_overload`` makes the next grasp end in an overload shutdown (status
  error "overload", HardwareError on every command until ``reboot()``; reboot drops any held object); slip is
  drawn by FakeArm during motions while holding (it calls ``world.release()`` and closes the fingers).

The pad opening lives in ``world.gripper_opening`` so the arm's collision model sees the fingers where they are.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from kitchenbot.drivers.errors import DeviceNotConnectedError, DriverTimeoutError, HardwareError
from kitchenbot.drivers.gripper import GraspResult, Gripper, GripperStatus
from kitchenbot.world.gripper import FINGERS, MAX_OPENING, FingerGeometry

IDLE_CURRENT = 0.04  # A, holding a position with nothing to push against
MOVING_CURRENT = 0.12  # A, moving the fingers freely
MIN_HOLDING_OPENING = 0.002  # m, a stall below this counts as closed on nothing (fingers meet)


class FakeGripper(Gripper):
    def __init__(self, world, max_opening: float = MAX_OPENING, max_current: float = 1.2,
                 speed: float = 0.1, geometry: FingerGeometry | None = None, pad_half_x: float = 0.01):
        if not (max_opening > 0 and max_current > 0 and speed > 0):
            raise ValueError(
                f"FakeGripper: max_opening {max_opening} m, max_current {max_current} A and speed {speed} m/s "
                "must all be positive"
            )
        self.world = world
        self.max_opening = float(max_opening)
        self.max_current = float(max_current)
        self.speed = float(speed)
        self.geometry = geometry or FINGERS
        self.pad_half_x = float(pad_half_x)
        self._connected = False
        self._error: str | None = None
        self._torque = True
        self._current = IDLE_CURRENT
        self._grasped_uid: int | None = None  # what this gripper attached (slip/release clear the world's side)
        self._temperature = 31.0
        self.world.gripper_opening = min(float(self.world.gripper_opening), self.max_opening)

    # ---- connection -----------------------------------------------------------------------------------
    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    @property
    def is_connected(self) -> bool:
        return self._connected

    def _require(self, healthy: bool = True) -> None:
        if not self._connected:
            raise DeviceNotConnectedError("FakeGripper: not connected; call connect() first")
        if healthy and self._error is not None:
            raise HardwareError(f"FakeGripper: {self._error} (hardware error); call reboot() to clear it")

    # ---- commands -------------------------------------------------------------------------------------
    def open(self, opening: float | None = None, timeout: float = 3.0) -> None:
        target = self.max_opening if opening is None else float(opening)
        if not (0.0 <= target <= self.max_opening):
            raise ValueError(f"opening {target} m: expected 0 <= opening <= {self.max_opening} m")
        self._require()
        self._torque = True
        if self.world.held_uid is not None and target > self.world.gripper_opening - 1e-9:
            self.world.release()
            self._grasped_uid = None
        start = float(self.world.gripper_opening)
        stop_at = target
        if target < start:  # closing in position mode: the pads stop at whatever is between them
            contact = self._contact(start)
            if contact is not None and contact[0] > target:
                stop_at = contact[0]
        self._travel(start, stop_at, timeout)
        self._current = IDLE_CURRENT if stop_at == target else 0.9 * self.max_current
        if stop_at != target:  # stalled short of the goal: the driver waits out its timeout
            self.world.clock.advance(max(0.0, timeout - abs(stop_at - start) / self.speed))
            raise DriverTimeoutError(
                f"FakeGripper: did not reach {target * 1000:.1f} mm (stuck at {stop_at * 1000:.1f} mm; "
                "something between the pads)"
            )

    def grasp(self, current_limit: float, timeout: float = 3.0) -> GraspResult:
        limit = self._check_current(current_limit)
        self._require()
        self._torque = True
        start = float(self.world.gripper_opening)
        if self.world.held_uid is not None:  # already holding: squeezing again changes nothing
            return GraspResult(True, start, 0.95 * limit)
        contact = self._contact(start)
        end = contact[0] if contact is not None and contact[0] >= MIN_HOLDING_OPENING else 0.0
        self._travel(start, end, timeout)
        f = self.world.faults
        if f.gripper_overload > 0:
            f.gripper_overload -= 1
            self._error = "overload"
            self._torque = False
            self._current = 0.0
            self._temperature += 6.0
            raise HardwareError("FakeGripper: overload during grasp (servo shut down); call reboot() to clear it")
        if contact is not None and end > 0.0:
            self.world.attach(contact[1])
            self._grasped_uid = contact[1]
            self._current = 0.95 * limit
            self._temperature += 0.5
            return GraspResult(True, end, self._current)
        self._current = IDLE_CURRENT
        return GraspResult(False, end, self._current)

    def status(self) -> GripperStatus:
        self._require(healthy=False)
        holding = (self._error is None and self._grasped_uid is not None and self.world.held_uid == self._grasped_uid)
        if not holding and self._grasped_uid is not None:  # slipped out (FakeArm) or released elsewhere
            self._grasped_uid = None
            self._current = IDLE_CURRENT if self._torque else 0.0
        return GripperStatus(
            opening=float(self.world.gripper_opening),
            current=float(self._current),
            holding=holding,
            moving=False,
            error=self._error,
            temperature_c=round(self._temperature + 4.0 * abs(self._current), 1),
            voltage_v=12.1 - 0.2 * abs(self._current),
        )

    def reboot(self) -> None:
        """Clear a hardware error; the servo comes back with torque off and lets go of anything it held."""
        self._require(healthy=False)
        if self.world.held_uid is not None:
            self.world.release()
        self._grasped_uid = None
        self._error = None
        self._torque = False
        self._current = 0.0

    # ---- simulation -----------------------------------------------------------------------------------
    def _travel(self, start: float, end: float, timeout: float) -> None:
        """Move the pads from `start` to `end` (m), taking simulated time; DriverTimeoutError past `timeout`."""
        dt = abs(end - start) / self.speed
        if dt > timeout:
            frac = timeout / dt
            self.world.clock.advance(timeout)
            self.world.gripper_opening = start + (end - start) * frac
            raise DriverTimeoutError(
                f"FakeGripper: motion {start:.3f} -> {end:.3f} m did not finish within {timeout} s"
            )
        self.world.clock.advance(dt)
        self.world.gripper_opening = float(end)

    def _contact(self, opening: float) -> tuple[float, int] | None:
        """(pad distance at contact, uid) of what the pads close on from `opening`, or None."""
        w = self.world
        T = w.T_base_tcp()
        x, y, z, p = T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3]
        half = opening / 2
        z0, z1 = self.geometry.pad_z
        lo_local = np.array([-self.pad_half_x, -half, z0])
        hi_local = np.array([self.pad_half_x, half, z1])
        corners = np.array([[a, b, c] for a in (lo_local[0], hi_local[0]) for b in (lo_local[1], hi_local[1])
                            for c in (lo_local[2], hi_local[2])]) @ T[:3, :3].T + p
        r_lo, r_hi = corners.min(0), corners.max(0)
        scene = o3d.t.geometry.RaycastingScene()
        ids: list[int] = []
        for uid, o in w.objects.items():
            V = np.asarray(o.model.mesh.vertices) @ o.T_base_obj[:3, :3].T + o.T_base_obj[:3, 3]
            if np.any(V.min(0) > r_hi) or np.any(V.max(0) < r_lo):
                continue
            scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(w.object_mesh(uid)))
            ids.append(uid)
        if not ids:
            return None
        # Rays from each pad inwards along lines across the gap. The Fin-Ray pads conform to the object, so the
        # closed opening is the object's span near the pad centre (what planning.grasp_synthesis.pad_span measures);
        # the rest of the pad face only counts when nothing lies across the centre lines.
        core = self._lines(np.array([-0.005, 0.0, 0.005]), np.array([-0.005, 0.0, 0.005]))
        face = self._lines(np.linspace(-self.pad_half_x, self.pad_half_x, 5), np.linspace(z0, z1, 8))
        for lines in (core, face):
            hit = self._widest_line(scene, ids, p + lines @ np.stack([x, z]), y, half, opening)
            if hit is not None:
                return hit
        return None

    @staticmethod
    def _lines(xs: np.ndarray, zs: np.ndarray) -> np.ndarray:
        X, Z = np.meshgrid(xs, zs)
        return np.column_stack([X.ravel(), Z.ravel()])

    @staticmethod
    def _widest_line(scene, ids, starts, y, half, opening) -> tuple[float, int] | None:
        """Max over lines of the span between the first surfaces each pad meets; (width, uid) or None."""
        n = len(starts)
        rays_pos = np.hstack([starts + half * y, np.broadcast_to(-y, starts.shape)])  # +y pad closing along -y
        rays_neg = np.hstack([starts - half * y, np.broadcast_to(y, starts.shape)])
        ans = scene.cast_rays(o3d.core.Tensor(np.vstack([rays_pos, rays_neg]).astype(np.float32)))
        t, gid = ans["t_hit"].numpy(), ans["geometry_ids"].numpy()
        t_pos, t_neg = t[:n], t[n:]
        # a line crossing an object is hit from both sides; one-sided hits mean a pad already sits in a mesh
        width = np.where(np.isfinite(t_pos) & np.isfinite(t_neg), opening - t_pos - t_neg, -np.inf)
        i = int(np.argmax(width))
        if not width[i] > 0:
            return None
        u_pos, u_neg = ids[int(gid[i])], ids[int(gid[n + i])]
        # two different objects across the gap: the one nearer a pad is the one held
        return float(width[i]), (u_pos if t_pos[i] <= t_neg[i] else u_neg)
