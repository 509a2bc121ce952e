"""A Universal Robots e-Series arm over RTDE (``ur-rtde``: rtde_control, rtde_receive, dashboard_client).

Every command was already checked by :class:`~kitchenbot.drivers.arm.Arm` (joint limits, speeds, workspace)
before a hook here runs; this module only talks to the controller and maps its failures to our errors.

Field failures it guards against (DESIGN.md section 7):
- nothing listens at the host: the ur_rtde constructors raise ``RuntimeError`` at once -> DeviceNotConnectedError
  naming the host and what to check;
- the receive thread dies while ``isConnected()`` stays true: a watchdog (background thread, and a check on every
  read) requires the RTDE timestamp to advance within ``receive_timeout`` and otherwise rebuilds the receive
  interface, a bounded number of times with exponential backoff, then declares the link lost;
- the control link drops (CPU load, network): ``reconnect()`` with the same bounded policy;
- motions cannot be paused, only stopped: every move is started asynchronously and polled (progress, safety
  status), synchronous calls simply wait; :meth:`stop` uses stopJ/stopL/servoStop;
- protective and emergency stops come from the safety status bits; a protective stop is unlocked through the
  dashboard server only when someone calls :meth:`unlock_protective_stop`.

The three interfaces come from injectable factories so tests can hand in fakes at this boundary.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from kitchenbot.drivers.arm import Arm, ArmState, SafetyState
from kitchenbot.drivers.errors import (
    DeviceNotConnectedError,
    DriverError,
    DriverTimeoutError,
    EmergencyStopError,
    LimitViolation,
    ProtectiveStopError,
)
from kitchenbot.drivers.safety import SafetyLimits
from kitchenbot.drivers.ur_kinematics import URModel, fk_flange
from kitchenbot.transforms import to_rotvec

log = logging.getLogger(__name__)

# RTDE safety_status_bits (UR RTDE guide)
SAFETY_BIT_NORMAL = 0
SAFETY_BIT_REDUCED = 1
SAFETY_BIT_PROTECTIVE_STOPPED = 2
SAFETY_BIT_RECOVERY = 3
SAFETY_BIT_SAFEGUARD_STOPPED = 4
SAFETY_BIT_SYSTEM_EMERGENCY_STOPPED = 5
SAFETY_BIT_ROBOT_EMERGENCY_STOPPED = 6
SAFETY_BIT_EMERGENCY_STOPPED = 7
SAFETY_BIT_VIOLATION = 8
SAFETY_BIT_FAULT = 9
SAFETY_BIT_STOPPED_DUE_TO_SAFETY = 10


def safety_from_bits(bits: int) -> SafetyState:
    """Map RTDE safety status bits to our SafetyState (emergency beats fault beats protective)."""
    bits = int(bits)

    def on(b: int) -> bool:
        return bool(bits >> b & 1)

    if on(SAFETY_BIT_EMERGENCY_STOPPED) or on(SAFETY_BIT_SYSTEM_EMERGENCY_STOPPED) or on(SAFETY_BIT_ROBOT_EMERGENCY_STOPPED):
        return SafetyState.EMERGENCY_STOP
    if on(SAFETY_BIT_VIOLATION) or on(SAFETY_BIT_FAULT):
        return SafetyState.FAULT
    if on(SAFETY_BIT_PROTECTIVE_STOPPED) or on(SAFETY_BIT_SAFEGUARD_STOPPED):
        return SafetyState.PROTECTIVE_STOP
    return SafetyState.NORMAL


def resample_trajectory(times: np.ndarray, q: np.ndarray, dt: float) -> np.ndarray:
    """Joint positions at a fixed period `dt` (linear interpolation), ending exactly on the last waypoint."""
    grid = np.arange(0.0, times[-1], dt)
    if len(grid) == 0 or grid[-1] < times[-1]:
        grid = np.append(grid, times[-1])
    return np.stack([np.interp(grid, times, q[:, j]) for j in range(q.shape[1])], axis=1)


def _default_receive(host: str, frequency: float) -> Any:
    import rtde_receive

    return rtde_receive.RTDEReceiveInterface(host, frequency)


def _default_control(host: str, frequency: float) -> Any:
    import rtde_control

    return rtde_control.RTDEControlInterface(host, frequency)


def _default_dashboard(host: str) -> Any:
    import dashboard_client

    d = dashboard_client.DashboardClient(host)
    d.connect(2000)
    return d


def probe(
    host: str,
    frequency: float = 500.0,
    watch: float = 0.2,
    receive_factory: Callable[[str, float], Any] = _default_receive,
    dashboard_factory: Callable[[str], Any] = _default_dashboard,
) -> dict:
    """Read-only health check (for `kitchenbot doctor`): no control script is uploaded, nothing moves.
    Opens the receive interface, checks that its timestamp advances over `watch` seconds, reads the safety
    state, then asks the dashboard server for model/version/modes. Raises DeviceNotConnectedError."""
    try:
        r = receive_factory(host, frequency)
    except RuntimeError as e:
        raise DeviceNotConnectedError(
            f"UR arm at {host}: cannot open the RTDE receive interface (TCP port 30004): {e}"
        ) from None
    try:
        t0 = float(r.getTimestamp())
        time.sleep(watch)
        t1 = float(r.getTimestamp())
        info = {
            "streaming": t1 > t0,
            "safety": safety_from_bits(r.getSafetyStatusBits()).value,
            "q": np.round(np.asarray(r.getActualQ(), float), 3).tolist(),
        }
    finally:
        URArm._close_quietly(r)
    try:
        d = dashboard_factory(host)
    except RuntimeError as e:
        info["dashboard"] = f"unreachable ({e})"
        return info
    try:
        info.update(
            model=str(d.getRobotModel()),
            polyscope=str(d.polyscopeVersion()),
            robot_mode=str(d.robotmode()),
            remote_control=bool(d.isInRemoteControl()),
        )
    except RuntimeError as e:
        info["dashboard"] = f"error ({e})"
    finally:
        URArm._close_quietly(d)
    return info


class URArm(Arm):
    """UR e-Series over RTDE. Units: radians, metres, seconds."""

    def __init__(
        self,
        model: URModel,
        limits: SafetyLimits,
        host: str,
        *,
        frequency: float = 500.0,
        receive_timeout: float = 0.1,
        payload_kg: float = 0.0,
        cog: tuple[float, float, float] = (0.0, 0.0, 0.0),
        reconnect_attempts: int = 3,
        reconnect_backoff: float = 0.2,
        servo_lookahead: float = 0.1,
        servo_gain: float = 300.0,
        watchdog: bool = True,
        receive_factory: Callable[[str, float], Any] = _default_receive,
        control_factory: Callable[[str, float], Any] = _default_control,
        dashboard_factory: Callable[[str], Any] = _default_dashboard,
    ):
        super().__init__(model, limits)
        self.host = host
        self.frequency = float(frequency)
        self.receive_timeout = float(receive_timeout)
        self.payload_kg = float(payload_kg)
        self.cog = tuple(float(c) for c in cog)
        self.reconnect_attempts = max(1, int(reconnect_attempts))
        self.reconnect_backoff = float(reconnect_backoff)
        self.servo_lookahead = float(servo_lookahead)
        self.servo_gain = float(servo_gain)
        self.use_watchdog = watchdog
        self._receive_factory = receive_factory
        self._control_factory = control_factory
        self._dashboard_factory = dashboard_factory

        self._lock = threading.RLock()
        self._rtde_r: Any = None
        self._rtde_c: Any = None
        self._dashboard: Any = None
        self._last_ts: float | None = None
        self._last_change = 0.0
        self._rebuild_times: list[float] = []  # monotonic times of recent rebuilds (bounded per window)
        self.rebuild_window = 10.0  # s: more than `reconnect_attempts` rebuilds in this window = link lost
        self._link_lost: str | None = None
        self.receive_rebuilds = 0  # how often the watchdog rebuilt the receive interface
        self._watchdog: threading.Thread | None = None
        self._stop_watchdog = threading.Event()
        self._motion: str | None = None  # "J", "L", "servo" while a motion we started may run
        self._servo_thread: threading.Thread | None = None
        self._servo_stop = threading.Event()
        self._servo_error: BaseException | None = None

    # ---- connection -------------------------------------------------------------------------------
    def _unreachable(self, what: str, port: int, e: BaseException) -> DeviceNotConnectedError:
        return DeviceNotConnectedError(
            f"UR arm at {self.host}: cannot open the RTDE {what} interface (TCP port {port}): {e}. "
            "Check the controller is on, the IP (drivers.arm.host), the network cable, and that the robot is in "
            "Remote Control mode."
        )

    def _make_receive(self) -> Any:
        try:
            return self._receive_factory(self.host, self.frequency)
        except RuntimeError as e:
            raise self._unreachable("receive", 30004, e) from None

    def connect(self) -> None:
        if self.is_connected:
            return
        if self._rtde_r is not None or self._rtde_c is not None or self._watchdog is not None:
            self.disconnect()  # after a lost link: drop the dead interfaces and the old watchdog first
        with self._lock:
            self._link_lost = None
            self._rtde_r = self._make_receive()
            try:
                self._rtde_c = self._control_factory(self.host, self.frequency)
            except RuntimeError as e:
                self._close_quietly(self._rtde_r)
                self._rtde_r = None
                raise self._unreachable("control", 30004, e) from None
            self._mark_fresh()
            self._rebuild_times = []
            try:
                self._apply_tool()
            except (DriverError, RuntimeError):
                self.disconnect()
                raise
        if self.use_watchdog:
            self._stop_watchdog.clear()
            self._watchdog = threading.Thread(target=self._watchdog_loop, name="ur-rtde-watchdog", daemon=True)
            self._watchdog.start()

    def _apply_tool(self) -> None:
        """TCP and payload from the config, so the controller's own checks and moveL use the same tool."""
        tcp = to_rotvec(self.limits.T_flange_tcp).tolist()
        if not self._rtde_c.setTcp(tcp):
            raise DriverError(f"UR arm at {self.host}: the controller refused setTcp({tcp})")
        if not self._rtde_c.setPayload(self.payload_kg, list(self.cog)):
            raise DriverError(f"UR arm at {self.host}: the controller refused setPayload({self.payload_kg} kg)")

    @staticmethod
    def _close_quietly(iface: Any, *calls: str) -> None:
        if iface is None:
            return
        for name in (*calls, "disconnect"):
            try:
                getattr(iface, name)()
            except Exception:  # noqa: BLE001 - best effort while tearing down a dead link
                pass

    def disconnect(self) -> None:
        self._stop_watchdog.set()
        if self._watchdog is not None and self._watchdog is not threading.current_thread():
            self._watchdog.join(timeout=2.0)
        self._watchdog = None
        self._end_servo_thread()
        with self._lock:
            self._close_quietly(self._rtde_c, "stopScript")
            self._close_quietly(self._rtde_r)
            self._close_quietly(self._dashboard)
            self._rtde_c = self._rtde_r = self._dashboard = None
            self._motion = None

    @property
    def is_connected(self) -> bool:
        return self._rtde_r is not None and self._rtde_c is not None and self._link_lost is None

    # ---- the receive watchdog ------------------------------------------------------------------------
    def _watchdog_loop(self) -> None:
        period = max(0.005, self.receive_timeout / 2)
        while not self._stop_watchdog.wait(period):
            try:
                with self._lock:
                    if self._rtde_r is None or self._link_lost:
                        continue
                    self._check_receive()
            except DeviceNotConnectedError as e:
                log.error("%s", e)
                self._emergency_stop_motion()
                return

    def _check_receive(self) -> Any:
        """The receive interface, after making sure its timestamp advanced within `receive_timeout`."""
        now = time.monotonic()
        try:
            ts = float(self._rtde_r.getTimestamp())
        except RuntimeError as e:
            return self._rebuild_receive(f"reading the timestamp failed ({e})")
        if ts != self._last_ts:
            self._last_ts, self._last_change = ts, now
            return self._rtde_r
        if now - self._last_change > self.receive_timeout:
            return self._rebuild_receive(
                f"the RTDE timestamp has not advanced for {now - self._last_change:.2f} s (stalled at {ts:.3f} s)"
            )
        return self._rtde_r

    def _rebuild_receive(self, reason: str) -> Any:
        """Replace a stalled/dead receive interface; bounded attempts with exponential backoff."""
        now = time.monotonic()
        self._rebuild_times = [t for t in self._rebuild_times if now - t < self.rebuild_window]
        if len(self._rebuild_times) >= self.reconnect_attempts:
            return self._lose_link(
                f"receive link keeps stalling ({reason}) after {len(self._rebuild_times)} rebuilds "
                f"in {self.rebuild_window:.0f} s"
            )
        self._rebuild_times.append(now)
        log.warning("UR arm at %s: %s; rebuilding the RTDE receive interface", self.host, reason)
        self._close_quietly(self._rtde_r)
        self._rtde_r = None
        last: BaseException | None = None
        for attempt in range(self.reconnect_attempts):
            try:
                self._rtde_r = self._receive_factory(self.host, self.frequency)
                break
            except RuntimeError as e:
                last = e
                time.sleep(self.reconnect_backoff * 2**attempt)
        if self._rtde_r is None:
            return self._lose_link(f"{reason}; rebuilding the receive interface failed {self.reconnect_attempts} times ({last})")
        self.receive_rebuilds += 1
        self._mark_fresh()
        return self._rtde_r

    def _mark_fresh(self) -> None:
        """Start the stall clock at the interface's current timestamp: one that never advances is caught
        `receive_timeout` after it was built."""
        try:
            self._last_ts = float(self._rtde_r.getTimestamp())
        except RuntimeError:
            self._last_ts = None
        self._last_change = time.monotonic()

    def _lose_link(self, why: str) -> Any:
        self._link_lost = why
        raise DeviceNotConnectedError(f"UR arm at {self.host}: link lost: {why}. Call connect() again.")

    def _recv(self) -> Any:
        with self._lock:
            if self._link_lost:
                raise DeviceNotConnectedError(f"UR arm at {self.host}: link lost: {self._link_lost}. Call connect() again.")
            if self._rtde_r is None:
                raise DeviceNotConnectedError(f"UR arm at {self.host}: not connected; call connect() first")
            return self._check_receive()

    def _ctrl(self) -> Any:
        """The control interface, reconnected (bounded, with backoff) when its link dropped."""
        with self._lock:
            if self._rtde_c is None or self._link_lost:
                raise DeviceNotConnectedError(
                    f"UR arm at {self.host}: not connected{': ' + self._link_lost if self._link_lost else ''}"
                )
            c = self._rtde_c
            if c.isConnected():
                return c
            for attempt in range(self.reconnect_attempts):
                log.warning("UR arm at %s: control link down, reconnect attempt %d", self.host, attempt + 1)
                try:
                    if c.reconnect() and c.isConnected():
                        self._apply_tool()
                        return c
                except RuntimeError:
                    pass
                time.sleep(self.reconnect_backoff * 2**attempt)
            return self._lose_link(f"control link dropped and {self.reconnect_attempts} reconnects failed")

    def _call(self, what: str, fn: Callable, *args) -> Any:
        """Run a control call, mapping ur_rtde's RuntimeError (script not running, link down) to ours."""
        try:
            return fn(*args)
        except RuntimeError as e:
            self._raise_for_safety()
            raise DriverError(f"UR arm at {self.host}: {what} failed: {e}") from None

    # ---- state ------------------------------------------------------------------------------------
    def joint_positions(self) -> np.ndarray:
        return np.asarray(self._recv().getActualQ(), dtype=np.float64)

    def safety_state(self) -> SafetyState:
        return safety_from_bits(self._recv().getSafetyStatusBits())

    def state(self) -> ArmState:
        r = self._recv()
        q = np.asarray(r.getActualQ(), dtype=np.float64)
        return ArmState(
            q=q,
            qd=np.asarray(r.getActualQd(), dtype=np.float64),
            T_base_tcp=fk_flange(self.model, q) @ self.limits.T_flange_tcp,
            safety=safety_from_bits(r.getSafetyStatusBits()),
            moving=self.is_moving(),
            stamp=float(r.getTimestamp()),
        )

    def _raise_for_safety(self) -> None:
        s = self.safety_state()
        if s is SafetyState.PROTECTIVE_STOP:
            raise ProtectiveStopError(f"UR arm at {self.host}: protective stop; unlock it before moving")
        if s is SafetyState.EMERGENCY_STOP:
            raise EmergencyStopError(f"UR arm at {self.host}: emergency stop is active; a person must release it")
        if s is SafetyState.FAULT:
            raise DriverError(f"UR arm at {self.host}: safety fault/violation; check the teach pendant")

    # ---- motion -----------------------------------------------------------------------------------
    def _start(self, kind: str, what: str, fn: Callable, *args) -> None:
        self._end_servo_thread()
        ok = self._call(what, fn, *args)
        if not ok:
            self._raise_for_safety()
            raise DriverError(f"UR arm at {self.host}: the controller refused {what}")
        self._motion = kind

    def _move_joints(self, q: np.ndarray, speed: float, accel: float, asynchronous: bool) -> None:
        c = self._ctrl()
        q0 = self.joint_positions()
        self._start("J", "moveJ", c.moveJ, q.tolist(), float(speed), float(accel), True)
        if not asynchronous:
            dist = float(np.max(np.abs(q - q0)))
            self.wait(timeout=2.0 * (dist / speed + speed / accel) + 2.0)

    def _move_linear(self, T_base_tcp: np.ndarray, speed: float, accel: float, asynchronous: bool) -> None:
        # The workspace is a box (convex) and the base class checked the target, so the straight line stays
        # inside when it starts inside: check the start with the same limits, then ask the controller whether
        # the joints stay within its limits along the line (it owns the IK the motion will use).
        start = self.tcp_pose()
        self.limits.check_tcp_pose(start, "linear move start (TCP)")
        c = self._ctrl()
        p0, p1 = start[:3, 3], T_base_tcp[:3, 3]
        for s in np.linspace(0.0, 1.0, 6)[1:]:
            T = T_base_tcp.copy()
            T[:3, 3] = p0 + s * (p1 - p0)
            if not self._call("isPoseWithinSafetyLimits", c.isPoseWithinSafetyLimits, to_rotvec(T).tolist()):
                raise LimitViolation(
                    f"linear move: the controller reports the path point {np.round(T[:3, 3], 4).tolist()} m "
                    "outside its safety limits"
                )
        self._start("L", "moveL", c.moveL, to_rotvec(T_base_tcp).tolist(), float(speed), float(accel), True)
        if not asynchronous:
            dist = float(np.linalg.norm(p1 - p0))
            self.wait(timeout=2.0 * (dist / speed + speed / accel) + 2.0)

    def _execute_trajectory(self, times: np.ndarray, q: np.ndarray, asynchronous: bool, guarded: bool = False) -> None:
        """Stream servoJ at the RTDE frequency (initPeriod/waitPeriod keep the period), in a thread. Guarded: the
        TCP force (getActualTCPForce, zeroed at the start) is read every sample; past CONTACT_FORCE the stream
        ends there (servoStop), as ur_rtde's moveUntilContact does for a speed command."""
        c = self._ctrl()
        dt = 1.0 / self.frequency
        samples = resample_trajectory(times, q, dt)
        self._end_servo_thread()
        self._servo_stop.clear()
        self._servo_error = None
        self._motion = "servo"
        self._servo_thread = threading.Thread(
            target=self._servo_loop, args=(c, samples, dt, guarded), name="ur-rtde-servoj", daemon=True
        )
        self._servo_thread.start()
        if not asynchronous:
            self.wait(timeout=float(times[-1]) * 2.0 + 2.0)

    def _servo_loop(self, c: Any, samples: np.ndarray, dt: float, guarded: bool = False) -> None:
        try:
            f0 = np.asarray(self._recv().getActualTCPForce()[:3], float) if guarded else None
            for k, qk in enumerate(samples):
                if self._servo_stop.is_set():
                    break
                if f0 is not None:
                    f = np.asarray(self._recv().getActualTCPForce()[:3], float)
                    if np.linalg.norm(f - f0) > self.CONTACT_FORCE:
                        self.stopped_on_contact = True
                        break
                t0 = c.initPeriod()
                if not c.servoJ(qk.tolist(), 0.0, 0.0, dt, self.servo_lookahead, self.servo_gain):
                    self._raise_for_safety()
                    raise DriverError(f"UR arm at {self.host}: servoJ refused at sample {k}")
                if k % 25 == 0:  # a safety check every 50 ms at 500 Hz
                    self._raise_for_safety()
                c.waitPeriod(t0)
        except BaseException as e:  # noqa: BLE001 - handed to wait()
            self._servo_error = e
        finally:
            try:
                c.servoStop(10.0)
            except RuntimeError:
                pass

    def _end_servo_thread(self) -> None:
        t = self._servo_thread
        if t is not None and t is not threading.current_thread():
            self._servo_stop.set()
            t.join(timeout=2.0)
        self._servo_thread = None

    def is_moving(self) -> bool:
        if self._servo_thread is not None and self._servo_thread.is_alive():
            return True
        if self._motion in ("J", "L"):
            with self._lock:
                progress = self._call("getAsyncOperationProgress", self._ctrl().getAsyncOperationProgress)
            if progress >= 0:
                return True
            self._motion = None
        return False

    def wait(self, timeout: float | None = None) -> None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            self._raise_for_safety()
            if not self.is_moving():
                break
            if deadline is not None and time.monotonic() > deadline:
                self.stop()
                raise DriverTimeoutError(f"UR arm at {self.host}: motion did not finish within {timeout:.1f} s; stopped it")
            time.sleep(0.005)
        err, self._servo_error = self._servo_error, None
        if self._servo_thread is not None:
            self._servo_thread.join(timeout=1.0)
            self._servo_thread = None
        if err is not None:
            raise err
        self._raise_for_safety()  # a stop that ended the motion

    def stop(self, decel: float = 3.0) -> None:
        """Stop now: servoStop for a streamed trajectory, stopL for a linear move (decel in m/s^2), else stopJ
        (rad/s^2). Allowed at any time."""
        kind = self._motion
        self._end_servo_thread()
        c = self._ctrl()
        if kind == "L":
            self._call("stopL", c.stopL, float(decel))
        elif kind != "servo":
            self._call("stopJ", c.stopJ, float(decel))
        self._motion = None

    def _emergency_stop_motion(self) -> None:
        """Called when the link is declared lost: stop whatever we started, best effort."""
        self._servo_stop.set()
        try:
            if self._rtde_c is not None and self._motion:
                self._rtde_c.stopJ(3.0)
        except Exception:  # noqa: BLE001
            pass

    # ---- protective stop ------------------------------------------------------------------------------
    def dashboard(self) -> Any:
        """The dashboard client (connected on first use)."""
        if self._dashboard is None:
            try:
                self._dashboard = self._dashboard_factory(self.host)
            except RuntimeError as e:
                raise DeviceNotConnectedError(
                    f"UR arm at {self.host}: cannot reach the dashboard server (TCP port 29999): {e}"
                ) from None
        return self._dashboard

    def _unlock_protective_stop(self) -> None:
        s = self.safety_state()
        if s is SafetyState.EMERGENCY_STOP:
            raise EmergencyStopError(f"UR arm at {self.host}: emergency stop is active; a person must release it")
        if s is not SafetyState.PROTECTIVE_STOP:
            return
        reply = str(self.dashboard().unlockProtectiveStop())
        if "releasing" not in reply.lower():
            # e.g. "Cannot unlock protective stop until 5s after occurrence. Always inspect cause..."
            raise ProtectiveStopError(f"UR arm at {self.host}: dashboard refused to unlock: {reply}")
        try:
            self.dashboard().closeSafetyPopup()
        except RuntimeError:
            pass
        c = self._ctrl()
        if not self._call("isProgramRunning", c.isProgramRunning):
            self._call("reuploadScript", c.reuploadScript)  # the control script stops with a protective stop

    def describe(self) -> dict:
        """Model, software version, serial and modes from the dashboard (for `kitchenbot doctor`)."""
        d = self.dashboard()
        return {
            "model": str(d.getRobotModel()),
            "polyscope": str(d.polyscopeVersion()),
            "serial": str(d.getSerialNumber()),
            "robot_mode": str(d.robotmode()),
            "safety": str(d.safetystatus()),
        }
