"""A Universal Robots e-Series arm over RTDE (``ur-rtde``: rtde_control, rtde_receive, dashboard_client).

Every command was already checked by :class:`~kitchenbot.drivers.arm.Arm` (joint limits, speeds, workspace)
before a hook here runs; this module only talks to the controller and maps its failures to our errors.

What the vendor library does that shapes this driver (ur_rtde 1.6.5, checked against fakes/ur_controller):
- its constructors hold the Python GIL while they wait for the controller: against a host that accepts TCP and
  never answers they block the whole process for minutes, against one that handshakes but never streams they
  return after 2.5 s with a dead interface. So before any constructor runs, a short pure-Python RTDE handshake
  with a timeout (:func:`preflight_rtde`) proves the controller answers and streams;
- ``disconnect()`` sleeps 0.5 s and so does the destructor, GIL held: replaced receive interfaces are
  disconnected in a background thread and kept referenced until :meth:`URArm.disconnect`;
- ``setTcp``/``setPayload`` hold only for the running control script; ``reuploadScript`` and ur_rtde's own
  reconnect start a new one. Before each motion the active TCP (``getTCPOffset``) and payload (RTDE
  ``payload``) are compared with the config and re-sent when they differ;
- an async move starts in the control script's next cycle: ``getAsyncOperationProgress()`` still reads
  "finished" right after moveJ returns. A motion counts as started once the async operation id changed;
- ``DashboardClient.unlockProtectiveStop()`` returns None on success and raises RuntimeError("Unlock
  protective stop failure: <reply>") when the controller refuses;
- range checks raise ``ValueError`` (mapped to LimitViolation), everything else ``RuntimeError``.

Field failures guarded against (DESIGN.md section 7): the receive stream stalls or dies (data age: controller
time must advance with the host clock, and ``isConnected()``; a watchdog thread and every read check it and
rebuild the receive interface a bounded number of times), the control link drops (``reconnect()``, bounded),
protective and emergency stops (safety status bits). :meth:`stop` only needs the control interface and its
own lock, so a receive rebuild never delays or refuses it.

The three interfaces come from injectable factories; tests use the real classes against the emulator.
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
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

RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT = 30004, 29999, 30003

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

# How fast the controller clock may drift against the host clock before the data counts as ageing (s/s).
CLOCK_DRIFT_ALLOWANCE = 1e-3

FIELDBUS_HINT = (
    "RTDE input registers are held by another client or a fieldbus adapter (EtherNet/IP, PROFINET or MODBUS) on "
    "the controller: disable the adapter on the pendant (Installation > Fieldbus) or set "
    "drivers.arm.upper_range_registers: true so ur_rtde uses registers 24-47"
)


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


def polyscope_at_least(version: str, major: int, minor: int) -> bool | None:
    """Whether a PolyScope version string ("5.15.0.112233" or "URSoftware 5.15...") is >= major.minor; None
    when it cannot be read."""
    import re

    m = re.search(r"(\d+)\.(\d+)", str(version))
    if not m:
        return None
    return (int(m.group(1)), int(m.group(2))) >= (major, minor)


# ---- bounded checks before a vendor constructor (which would hold the GIL) ----------------------------------
def _recv_exactly(s: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = s.recv(n - len(buf))
        if not chunk:
            raise ConnectionResetError("the controller closed the connection")
        buf += chunk
    return buf


def _connect(host: str, port: int, what: str, timeout: float) -> socket.socket:
    try:
        return socket.create_connection((host, port), timeout=timeout)
    except TimeoutError:
        raise DeviceNotConnectedError(
            f"UR arm at {host}: no answer on TCP port {port} ({what}) within {timeout:.1f} s: host unreachable? "
            "Check the controller is on, the IP (drivers.arm.host) and the network cable."
        ) from None
    except OSError as e:
        raise DeviceNotConnectedError(
            f"UR arm at {host}: cannot open TCP port {port} ({what}): {e.strerror or e}. Check the controller is "
            "on, the IP (drivers.arm.host), the network cable, and that the robot is in Remote Control mode."
        ) from None


def preflight_rtde(host: str, timeout: float = 2.0) -> tuple[int, int, int, int]:
    """A minimal RTDE session (protocol version, controller version, a one-field output recipe, start, first
    data package, pause) with socket timeouts, so an unreachable, silent or non-streaming controller is found
    in bounded time. Returns the controller version. Raises DeviceNotConnectedError saying which step failed."""
    deadline = time.monotonic() + timeout
    s = _connect(host, RTDE_PORT, "RTDE", timeout)
    stage = "answer the RTDE handshake"

    def request(kind: str, payload: bytes, expect: str | None) -> bytes:
        if kind:
            s.sendall(struct.pack(">HB", 3 + len(payload), ord(kind)) + payload)
        while True:
            s.settimeout(max(1e-3, deadline - time.monotonic()))
            size, got = struct.unpack(">HB", _recv_exactly(s, 3))
            body = _recv_exactly(s, size - 3)
            if expect is None or got == ord(expect):
                return body

    try:
        with s:
            if not request("V", struct.pack(">H", 2), "V")[:1] == b"\x01":
                raise DeviceNotConnectedError(f"UR arm at {host}: the controller refused RTDE protocol version 2")
            version = struct.unpack(">IIII", request("v", b"", "v")[:16])
            reply = request("O", struct.pack(">d", 10.0) + b"timestamp", "O")
            if b"NOT_FOUND" in reply:
                raise DeviceNotConnectedError(f"UR arm at {host}: the RTDE server does not know 'timestamp'")
            request("S", b"", "S")
            stage = "send RTDE data after the handshake (the RTDE stream is stalled)"
            request("", b"", "U")
            try:
                s.sendall(struct.pack(">HB", 3, ord("P")))
            except OSError:
                pass
            return version
    except TimeoutError:
        raise DeviceNotConnectedError(
            f"UR arm at {host}: the controller accepted TCP port {RTDE_PORT} but did not {stage} within "
            f"{timeout:.1f} s. Restart the controller (or its RTDE service) and check nothing else floods it."
        ) from None
    except (ConnectionError, OSError, struct.error) as e:
        raise DeviceNotConnectedError(f"UR arm at {host}: the RTDE connection failed while waiting to {stage}: {e}") from None


def preflight_dashboard(host: str, timeout: float = 2.0) -> None:
    """Connect to the dashboard server and read its greeting within `timeout`."""
    s = _connect(host, DASHBOARD_PORT, "dashboard server", timeout)
    with s:
        s.settimeout(timeout)
        try:
            greeting = s.recv(256)
        except TimeoutError:
            raise DeviceNotConnectedError(
                f"UR arm at {host}: the dashboard server (port {DASHBOARD_PORT}) accepted the connection but sent "
                f"no greeting within {timeout:.1f} s"
            ) from None
        except OSError as e:
            raise DeviceNotConnectedError(f"UR arm at {host}: dashboard server: {e}") from None
        if not greeting:
            raise DeviceNotConnectedError(f"UR arm at {host}: the dashboard server closed the connection at once")


def _default_receive(host: str, frequency: float, upper_range: bool = False) -> Any:
    import rtde_receive

    return rtde_receive.RTDEReceiveInterface(host, frequency, [], False, upper_range)


def _default_control(host: str, frequency: float, upper_range: bool = False) -> Any:
    import rtde_control

    flags = rtde_control.RTDEControlInterface.FLAG_UPLOAD_SCRIPT
    if upper_range:
        flags |= rtde_control.RTDEControlInterface.FLAG_UPPER_RANGE_REGISTERS
    return rtde_control.RTDEControlInterface(host, frequency, flags)


def _default_dashboard(host: str) -> Any:
    import dashboard_client

    d = dashboard_client.DashboardClient(host)
    d.connect(2000)
    return d


def _retire(iface: Any, graveyard: list) -> None:
    """Disconnect a replaced interface off the caller's thread (the vendor call sleeps 0.5 s) and keep the object
    referenced: its destructor would sleep again with the GIL held."""
    if iface is None:
        return
    graveyard.append(iface)

    def run() -> None:
        try:
            iface.disconnect()
        except Exception:  # noqa: BLE001 - best effort on a dead link
            pass

    threading.Thread(target=run, name="ur-rtde-retire", daemon=True).start()


def probe(
    host: str,
    frequency: float = 500.0,
    watch: float = 0.2,
    timeout: float = 2.0,
    receive_factory: Callable[[str, float], Any] = _default_receive,
    dashboard_factory: Callable[[str], Any] = _default_dashboard,
    preflight: bool = True,
) -> dict:
    """Read-only health check (for `kitchenbot doctor`): no control script is uploaded, nothing moves.
    Bounded in time (`timeout` per step) on an unreachable or silent host. Opens the receive interface, checks
    that its timestamp advances over `watch` seconds, reads the safety state, then asks the dashboard server
    for model/version/modes. `remote_control` is None where PolyScope (< 5.6) has no such mode.
    Raises DeviceNotConnectedError."""
    if preflight:
        preflight_rtde(host, timeout)
    try:
        r = receive_factory(host, frequency)
    except RuntimeError as e:
        raise DeviceNotConnectedError(
            f"UR arm at {host}: cannot open the RTDE receive interface (TCP port {RTDE_PORT}): {e}"
        ) from None
    try:
        t0 = float(r.getTimestamp())
        time.sleep(watch)
        t1 = float(r.getTimestamp())
        info = {
            "streaming": t1 > t0 and bool(r.isConnected()),
            "safety": safety_from_bits(r.getSafetyStatusBits()).value,
            "q": np.round(np.asarray(r.getActualQ(), float), 3).tolist(),
        }
    finally:
        _close_quietly(r)
    try:
        if preflight:
            preflight_dashboard(host, timeout)
        d = dashboard_factory(host)
    except (RuntimeError, DeviceNotConnectedError) as e:
        info["dashboard"] = f"unreachable ({e})"
        return info
    try:
        version = str(d.polyscopeVersion())
        info.update(model=str(d.getRobotModel()), polyscope=version, robot_mode=str(d.robotmode()))
        has_remote = polyscope_at_least(version, 5, 6)
        info["remote_control"] = bool(d.isInRemoteControl()) if has_remote else None
    except RuntimeError as e:
        info["dashboard"] = f"error ({e})"
    finally:
        _close_quietly(d)
    return info


def _close_quietly(iface: Any, *calls: str) -> None:
    if iface is None:
        return
    for name in (*calls, "disconnect"):
        try:
            getattr(iface, name)()
        except Exception:  # noqa: BLE001 - best effort while tearing down a dead link
            pass


@dataclass(frozen=True)
class URArmSettings:
    """How the driver talks to the controller (``drivers.arm`` in the config); fixed for the driver's life."""

    frequency: float = 500.0  # Hz, RTDE
    receive_timeout: float = 0.1  # s: data older than this (controller time behind the host clock) is stale
    connect_timeout: float = 2.0
    payload_kg: float = 0.0
    cog: tuple[float, float, float] = (0.0, 0.0, 0.0)
    reconnect_attempts: int = 3
    reconnect_backoff: float = 0.2  # s, doubled per attempt
    servo_lookahead: float = 0.1
    servo_gain: float = 300.0
    servo_settle_tolerance: float = 1e-3  # rad: a streamed waypoint is held until the arm is this close
    servo_settle_time: float = 1.0
    motion_start_timeout: float = 2.0
    motion_slack: float = 2.0  # s a motion may run past twice its planned duration before it counts as stuck
    upper_range_registers: bool = False
    use_watchdog: bool = True
    use_preflight: bool = True
    rebuild_window: float = 10.0  # s: more than `reconnect_attempts` rebuilds in this window = link lost


@dataclass
class _LinkWatch:
    """The receive stream's health, read and written under the arm's `_rx_lock` / rebuild lock."""

    lag_base: float | None = None  # host time minus controller time when the data was freshest
    last_check: tuple[float, float] | None = None  # (host time, controller time) of the last check
    rebuild_times: list[float] = field(default_factory=list)  # clock() of recent rebuilds (bounded per window)
    lost: str | None = None  # why the link counts as lost, once it does


@dataclass
class _MoveWatch:
    """The motion this driver started, until it is seen finished."""

    kind: str | None = None  # "J", "L", "servo" while a motion we started may run
    op_before: int | None = None  # async operation id before our move was sent
    started: bool = False  # the async move was seen running (or finished) in the control script
    start_deadline: float = 0.0


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
        connect_timeout: float = 2.0,
        payload_kg: float = 0.0,
        cog: tuple[float, float, float] = (0.0, 0.0, 0.0),
        reconnect_attempts: int = 3,
        reconnect_backoff: float = 0.2,
        servo_lookahead: float = 0.1,
        servo_gain: float = 300.0,
        servo_settle_tolerance: float = 1e-3,
        servo_settle_time: float = 1.0,
        motion_start_timeout: float = 2.0,
        motion_slack: float = 2.0,
        upper_range_registers: bool = False,
        watchdog: bool = True,
        preflight: bool = True,
        clock: Callable[[], float] = time.monotonic,
        receive_factory: Callable[[str, float], Any] | None = None,
        control_factory: Callable[[str, float], Any] | None = None,
        dashboard_factory: Callable[[str], Any] = _default_dashboard,
    ):
        super().__init__(model, limits)
        self.host = host
        self.settings = URArmSettings(
            frequency=float(frequency), receive_timeout=float(receive_timeout), connect_timeout=float(connect_timeout),
            payload_kg=float(payload_kg), cog=tuple(float(c) for c in cog),
            reconnect_attempts=max(1, int(reconnect_attempts)), reconnect_backoff=float(reconnect_backoff),
            servo_lookahead=float(servo_lookahead), servo_gain=float(servo_gain),
            servo_settle_tolerance=float(servo_settle_tolerance), servo_settle_time=float(servo_settle_time),
            motion_start_timeout=float(motion_start_timeout), motion_slack=float(motion_slack),
            upper_range_registers=bool(upper_range_registers), use_watchdog=bool(watchdog),
            use_preflight=bool(preflight))
        self._clock = clock  # host clock for the data age and the rebuild window (tests inject one)
        self._receive_factory = receive_factory or (
            lambda h, f: _default_receive(h, f, self.settings.upper_range_registers))
        self._control_factory = control_factory or (
            lambda h, f: _default_control(h, f, self.settings.upper_range_registers))
        self._dashboard_factory = dashboard_factory

        # Locks: the control interface takes one command at a time (`_ctrl_lock`, the only lock stop() takes);
        # the receive interface is swapped under `_rx_lock` (no I/O under it); one rebuild at a time.
        self._ctrl_lock = threading.RLock()
        self._rx_lock = threading.Lock()
        self._rebuild_lock = threading.Lock()
        self._rtde_r: Any = None
        self._rtde_c: Any = None
        self._dashboard: Any = None
        self._graveyard: list[Any] = []  # replaced interfaces, released in disconnect()
        self._link = _LinkWatch()  # the receive stream's health: data age, recent rebuilds, why the link was lost
        self.receive_rebuilds = 0  # how often the receive interface was rebuilt
        self.tool_reapplied = 0  # how often TCP/payload were re-sent because a new control script had started
        self._watchdog: threading.Thread | None = None
        self._stop_watchdog = threading.Event()
        self._move = _MoveWatch()  # the motion we started, until it is seen finished
        self._servo_thread: threading.Thread | None = None
        self._servo_stop = threading.Event()
        self._servo_error: BaseException | None = None

    # ---- connection -------------------------------------------------------------------------------
    def _unreachable(self, what: str, port: int, e: BaseException) -> DeviceNotConnectedError:
        text = str(e)
        if "already in use" in text:
            return DeviceNotConnectedError(f"UR arm at {self.host}: cannot open the RTDE {what} interface: {FIELDBUS_HINT}. ({text})")
        if "remote control" in text.lower():
            return DeviceNotConnectedError(
                f"UR arm at {self.host}: the controller is in Local mode: switch the pendant to Remote Control "
                f"(PolyScope >= 5.6) so the control script may be uploaded. ({text})"
            )
        return DeviceNotConnectedError(
            f"UR arm at {self.host}: cannot open the RTDE {what} interface (TCP port {port}): {text}. "
            "Check the controller is on, the IP (drivers.arm.host), the network cable, and that the robot is in "
            "Remote Control mode, powered on with its brakes released."
        )

    def _make_receive(self) -> Any:
        if self.settings.use_preflight:
            preflight_rtde(self.host, self.settings.connect_timeout)
        try:
            r = self._receive_factory(self.host, self.settings.frequency)
        except RuntimeError as e:
            raise self._unreachable("receive", RTDE_PORT, e) from None
        if not r.isConnected():  # handshake done but no data: the vendor constructor returns a dead interface
            _retire(r, self._graveyard)
            raise DeviceNotConnectedError(f"UR arm at {self.host}: the RTDE receive interface connected but gets no data")
        return r

    def _make_control(self) -> Any:
        if self.settings.use_preflight:
            preflight_rtde(self.host, self.settings.connect_timeout)
            preflight_dashboard(self.host, self.settings.connect_timeout)
            _connect(self.host, SCRIPT_PORT, "script port", self.settings.connect_timeout).close()
        try:
            return self._control_factory(self.host, self.settings.frequency)
        except RuntimeError as e:
            raise self._unreachable("control", RTDE_PORT, e) from None

    def connect(self) -> None:
        if self.is_connected:
            return
        if self._rtde_r is not None or self._rtde_c is not None or self._watchdog is not None:
            self.disconnect()  # after a lost link: drop the dead interfaces and the old watchdog first
        self._link.lost = None
        r = self._make_receive()
        try:
            c = self._make_control()
        except DeviceNotConnectedError:
            _retire(r, self._graveyard)
            raise
        with self._rx_lock:
            self._rtde_r = r
            self._link.lag_base = self._link.last_check = None
        self._prime(r)
        with self._ctrl_lock:
            self._rtde_c = c
        self._link.rebuild_times = []
        try:
            self._apply_tool()
        except (DriverError, RuntimeError):
            self.disconnect()
            raise
        if self.settings.use_watchdog:
            self._stop_watchdog.clear()
            self._watchdog = threading.Thread(target=self._watchdog_loop, name="ur-rtde-watchdog", daemon=True)
            self._watchdog.start()

    def _tcp_pose(self) -> list[float]:
        return to_rotvec(self.limits.T_flange_tcp).tolist()

    def _apply_tool(self) -> None:
        """TCP and payload from the config, so the controller's own checks and moveL use the same tool."""
        tcp = self._tcp_pose()
        c = self._rtde_c
        if not self._call("setTcp", c.setTcp, tcp):
            raise DriverError(f"UR arm at {self.host}: the controller refused setTcp({tcp})")
        if not self._call("setPayload", c.setPayload, self.settings.payload_kg, list(self.settings.cog)):
            raise DriverError(
                f"UR arm at {self.host}: the controller refused setPayload({self.settings.payload_kg} kg)")

    def _ensure_program(self) -> Any:
        """Before a motion: the control script runs and uses our TCP and payload. A script restarted by
        reuploadScript or by ur_rtde's own reconnect runs with the installation's tool until we re-send it."""
        c = self._ctrl()
        for _ in range(2):
            if not self._call("isProgramRunning", c.isProgramRunning):
                self._fresh_safety()  # a protective or emergency stop ends the script: report that, do not upload
                log.warning("UR arm at %s: the control script is not running; uploading it again", self.host)
                self._reupload(c)
                return c
            try:
                tcp = np.asarray(self._call("getTCPOffset", c.getTCPOffset), float)
            except DriverError:  # the script stopped under the call: isProgramRunning now knows
                continue
            stale = tcp.shape != (6,) or not np.allclose(tcp, self._tcp_pose(), atol=1e-6)
            r = self._recv()
            if hasattr(r, "getPayload"):
                stale |= abs(float(r.getPayload()) - self.settings.payload_kg) > 1e-6
            if stale:  # a control script we did not start (reuploadScript, ur_rtde's reconnect)
                log.warning("UR arm at %s: a new control script runs with the installation's TCP/payload; "
                            "sending ours again", self.host)
                self._apply_tool()
                self.tool_reapplied += 1
            return c
        raise DriverError(f"UR arm at {self.host}: the control script keeps stopping; check the pendant's log")

    def _reupload(self, c: Any) -> None:
        if not self._call("reuploadScript", c.reuploadScript):
            raise DriverError(f"UR arm at {self.host}: uploading the control script failed")
        deadline = time.monotonic() + 5.0
        while not self._call("isProgramRunning", c.isProgramRunning):
            if time.monotonic() > deadline:
                raise DriverError(f"UR arm at {self.host}: the control script did not start within 5 s after upload")
            time.sleep(0.01)
        self._apply_tool()
        self.tool_reapplied += 1

    def disconnect(self) -> None:
        self._stop_watchdog.set()
        if self._watchdog is not None and self._watchdog is not threading.current_thread():
            self._watchdog.join(timeout=2.0)
        self._watchdog = None
        self._end_servo_thread()
        with self._ctrl_lock:
            c, self._rtde_c = self._rtde_c, None
            _close_quietly(c, "stopScript")
            d, self._dashboard = self._dashboard, None
            _close_quietly(d)
        with self._rx_lock:
            r, self._rtde_r = self._rtde_r, None
        _close_quietly(r)
        self._graveyard.clear()  # the vendor destructors sleep 0.5 s each; nothing moves now
        self._move.kind = None

    @property
    def is_connected(self) -> bool:
        return self._rtde_r is not None and self._rtde_c is not None and self._link.lost is None

    # ---- the receive watchdog ------------------------------------------------------------------------
    def _watchdog_loop(self) -> None:
        period = max(0.005, self.settings.receive_timeout / 2)
        while not self._stop_watchdog.wait(period):
            if self._rtde_r is None or self._link.lost:
                continue
            try:
                self._recv()
            except DeviceNotConnectedError as e:
                log.error("%s", e)
                return

    def _data_age(self, ts: float, now: float) -> float:
        """How old the controller's latest data is: the growth of (host time - controller time) over its
        smallest value, which may creep up by CLOCK_DRIFT_ALLOWANCE to absorb clock drift."""
        with self._rx_lock:
            lag = now - ts
            last = self._link.last_check
            if self._link.lag_base is None or last is None or ts < last[1]:  # new interface or controller restarted
                base = lag
            else:
                base = min(lag, self._link.lag_base + CLOCK_DRIFT_ALLOWANCE * max(0.0, now - last[0]))
            self._link.lag_base, self._link.last_check = base, (now, ts)
            return lag - base

    def _prime(self, r: Any) -> None:
        """Start the data-age reference at a new interface's first sample."""
        try:
            self._data_age(float(r.getTimestamp()), self._clock())
        except RuntimeError:
            pass

    def _fresh_safety(self) -> None:
        """_raise_for_safety on receive data newer than now: the control stream (isProgramRunning) and the
        receive stream (safety bits) are separate connections, a few cycles apart."""
        r = self._recv()
        ts0 = float(r.getTimestamp())
        deadline = time.monotonic() + 0.5
        while float(r.getTimestamp()) <= ts0 + 2.0 / self.settings.frequency and time.monotonic() < deadline:
            time.sleep(0.002)
        self._raise_for_safety()

    def _check_receive(self, r: Any) -> Any:
        """The receive interface, after making sure it is connected and its data is younger than
        `receive_timeout`; otherwise a rebuilt one."""
        now = self._clock()
        try:
            connected = bool(r.isConnected())
            ts = float(r.getTimestamp())
        except RuntimeError as e:
            return self._rebuild_receive(r, f"reading the timestamp failed ({e})")
        if not connected:
            return self._rebuild_receive(r, "the RTDE receive interface lost its connection")
        age = self._data_age(ts, now)
        if age > self.settings.receive_timeout:
            return self._rebuild_receive(
                r, f"the RTDE data is {age:.2f} s old (controller time stopped at {ts:.3f} s)"
            )
        return r

    def _rebuild_receive(self, old: Any, reason: str) -> Any:
        """Replace a stalled/dead receive interface; bounded attempts with exponential backoff. Runs without
        the control lock, so stop() keeps working meanwhile."""
        with self._rebuild_lock:
            if self._link.lost:
                return self._lose_link(self._link.lost)
            if self._rtde_r is not old:  # another thread rebuilt it while we waited
                return self._rtde_r
            now = self._clock()
            self._link.rebuild_times = [t for t in self._link.rebuild_times if now - t < self.settings.rebuild_window]
            if len(self._link.rebuild_times) >= self.settings.reconnect_attempts:
                return self._lose_link(
                    f"receive link keeps stalling ({reason}) after {len(self._link.rebuild_times)} rebuilds "
                    f"in {self.settings.rebuild_window:.0f} s"
                )
            self._link.rebuild_times.append(now)
            log.warning("UR arm at %s: %s; rebuilding the RTDE receive interface", self.host, reason)
            new, last = None, None
            for attempt in range(self.settings.reconnect_attempts):
                try:
                    new = self._make_receive()
                    break
                except DeviceNotConnectedError as e:
                    last = e
                    time.sleep(self.settings.reconnect_backoff * 2**attempt)
            if new is None:
                return self._lose_link(f"{reason}; rebuilding the receive interface failed "
                                       f"{self.settings.reconnect_attempts} times ({last})")
            with self._rx_lock:
                self._rtde_r = new
                self._link.lag_base = self._link.last_check = None
            self._prime(new)
            _retire(old, self._graveyard)
            self.receive_rebuilds += 1
            return new

    def _lose_link(self, why: str) -> Any:
        self._link.lost = why
        self._emergency_stop_motion()
        raise DeviceNotConnectedError(f"UR arm at {self.host}: link lost: {why}. Call connect() again.")

    def _recv(self) -> Any:
        if self._link.lost:
            raise DeviceNotConnectedError(f"UR arm at {self.host}: link lost: {self._link.lost}. Call connect() again.")
        with self._rx_lock:
            r = self._rtde_r
        if r is None:
            raise DeviceNotConnectedError(f"UR arm at {self.host}: not connected; call connect() first")
        return self._check_receive(r)

    def _ctrl(self) -> Any:
        """The control interface, reconnected (bounded, with backoff) when its link dropped. reconnect() uploads
        a new control script, so the tool is sent again. (ur_rtde 1.6.5's own reconnect, run by the
        interface's receive thread when the controller closes the connection, never clears its reconnect
        flag: it reconnects and uploads a new script every cycle and can crash the process; the emulator
        reproduces it. Nothing in-process recovers from that: see docs/hardware.md.)"""
        with self._ctrl_lock:
            if self._rtde_c is None or self._link.lost:
                raise DeviceNotConnectedError(
                    f"UR arm at {self.host}: not connected{': ' + self._link.lost if self._link.lost else ''}"
                )
            c = self._rtde_c
            if c.isConnected():
                return c
            for attempt in range(self.settings.reconnect_attempts):
                log.warning("UR arm at %s: control link down, reconnect attempt %d", self.host, attempt + 1)
                try:
                    if c.reconnect() and c.isConnected():
                        self._apply_tool()
                        self.tool_reapplied += 1
                        return c
                except RuntimeError:
                    pass
                time.sleep(self.settings.reconnect_backoff * 2**attempt)
        return self._lose_link(f"control link dropped and {self.settings.reconnect_attempts} reconnects failed")

    def _call(self, what: str, fn: Callable, *args) -> Any:
        """One control call under the control lock, mapping ur_rtde's errors to ours: ValueError (a range
        check in ur_rtde) -> LimitViolation, RuntimeError (script not running, link down) -> the safety error
        if a stop explains it, else DriverError."""
        try:
            with self._ctrl_lock:
                return fn(*args)
        except ValueError as e:
            raise LimitViolation(f"UR arm at {self.host}: ur_rtde refused {what}: {e}") from None
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
    def _async_op(self, c: Any) -> tuple[bool, int]:
        st = self._call("getAsyncOperationProgressEx", c.getAsyncOperationProgressEx)
        return bool(st.isAsyncOperationRunning()), int(st.operationId())

    def _start(self, kind: str, what: str, c: Any, fn: Callable, *args) -> None:
        self._end_servo_thread()
        _, op_before = self._async_op(c)
        ok = self._call(what, fn, *args)
        if not ok:
            self._raise_for_safety()
            raise DriverError(f"UR arm at {self.host}: the controller refused {what}")
        self._move.op_before, self._move.started = op_before, False
        self._move.start_deadline = time.monotonic() + self.settings.motion_start_timeout
        self._move.kind = kind

    def _move_joints(self, q: np.ndarray, speed: float, accel: float, asynchronous: bool) -> None:
        q0 = self.joint_positions()
        c = self._ensure_program()
        self._start("J", "moveJ", c, c.moveJ, q.tolist(), float(speed), float(accel), True)
        if not asynchronous:
            dist = float(np.max(np.abs(q - q0)))
            self.wait(timeout=2.0 * (dist / speed + speed / accel) + self.settings.motion_slack)

    def _move_linear(self, T_base_tcp: np.ndarray, speed: float, accel: float, asynchronous: bool) -> None:
        # The workspace is a box (convex) and the base class checked the target, so the straight line stays
        # inside when it starts inside: check the start with the same limits, then ask the controller whether
        # the joints stay within its limits along the line (it owns the IK the motion will use).
        start = self.tcp_pose()
        self.limits.check_tcp_pose(start, "linear move start (TCP)")
        c = self._ensure_program()
        p0, p1 = start[:3, 3], T_base_tcp[:3, 3]
        for s in np.linspace(0.0, 1.0, 6)[1:]:
            T = T_base_tcp.copy()
            T[:3, 3] = p0 + s * (p1 - p0)
            if not self._call("isPoseWithinSafetyLimits", c.isPoseWithinSafetyLimits, to_rotvec(T).tolist()):
                raise LimitViolation(
                    f"linear move: the controller reports the path point {np.round(T[:3, 3], 4).tolist()} m "
                    "outside its safety limits"
                )
        self._start("L", "moveL", c, c.moveL, to_rotvec(T_base_tcp).tolist(), float(speed), float(accel), True)
        if not asynchronous:
            dist = float(np.linalg.norm(p1 - p0))
            self.wait(timeout=2.0 * (dist / speed + speed / accel) + self.settings.motion_slack)

    def _execute_trajectory(self, times: np.ndarray, q: np.ndarray, asynchronous: bool, guarded: bool = False) -> None:
        """Stream servoJ at the RTDE frequency (initPeriod/waitPeriod keep the period), in a thread. Guarded: the
        TCP force (getActualTCPForce, zeroed at the start) is read every sample; past CONTACT_FORCE the stream
        ends there (servoStop), as ur_rtde's moveUntilContact does for a speed command. Unguarded, the last
        waypoint is held until the arm is within `servo_settle_tolerance` of it (servoJ lags by about the
        lookahead time), then servoStop."""
        c = self._ensure_program()
        dt = 1.0 / self.settings.frequency
        samples = resample_trajectory(times, q, dt)
        self._end_servo_thread()
        self._servo_stop.clear()
        self._servo_error = None
        self._move.kind = "servo"
        self._servo_thread = threading.Thread(
            target=self._servo_loop, args=(c, samples, dt, guarded), name="ur-rtde-servoj", daemon=True
        )
        self._servo_thread.start()
        if not asynchronous:
            self.wait(timeout=float(times[-1]) * 2.0 + self.settings.servo_settle_time + self.settings.motion_slack)

    def _servo_loop(self, c: Any, samples: np.ndarray, dt: float, guarded: bool = False) -> None:
        try:
            f0 = np.asarray(self._recv().getActualTCPForce()[:3], float) if guarded else None
            settle_until = None
            k = 0
            while not self._servo_stop.is_set():
                qk = samples[min(k, len(samples) - 1)]
                if f0 is not None:
                    f = np.asarray(self._recv().getActualTCPForce()[:3], float)
                    if np.linalg.norm(f - f0) > self.CONTACT_FORCE:
                        self.stopped_on_contact = True
                        break
                if k >= len(samples) - 1:  # holding the last waypoint: done once the arm is there
                    err = float(np.max(np.abs(self.joint_positions() - samples[-1])))
                    if err <= self.settings.servo_settle_tolerance:
                        break
                    settle_until = settle_until or time.monotonic() + self.settings.servo_settle_time
                    if time.monotonic() > settle_until:
                        log.warning("UR arm at %s: servoJ ended %.4f rad from the last waypoint", self.host, err)
                        break
                t0 = c.initPeriod()
                st = self.settings
                if not self._call("servoJ", c.servoJ, qk.tolist(), 0.0, 0.0, dt, st.servo_lookahead, st.servo_gain):
                    self._raise_for_safety()
                    raise DriverError(f"UR arm at {self.host}: servoJ refused at sample {k}")
                if k % 25 == 0:  # a safety check every 50 ms at 500 Hz
                    self._raise_for_safety()
                c.waitPeriod(t0)
                k += 1
        except BaseException as e:  # noqa: BLE001 - handed to wait()
            self._servo_error = e
        finally:
            try:
                with self._ctrl_lock:
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
        if self._move.kind in ("J", "L"):
            running, op = self._async_op(self._ctrl())
            if running:
                self._move.started = True
                return True
            if not self._move.started and op == self._move.op_before:  # sent, but the script has not begun it yet
                if time.monotonic() > self._move.start_deadline:
                    self._move.kind = None
                    self._raise_for_safety()
                    raise DriverError(f"UR arm at {self.host}: the controller accepted the move but did not start it "
                                      f"within {self.settings.motion_start_timeout:.1f} s")
                return True
            self._move.kind = None
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
        self._fresh_safety()  # a stop that ended the motion; and state reads after wait() see the end

    def stop(self, decel: float = 3.0) -> None:
        """Stop now: stopL for a linear move (decel in m/s^2), else stopJ (rad/s^2); a streamed trajectory ends
        with servoStop first. Allowed at any time; needs only the control link (not the receive link, nor a
        receive rebuild in progress)."""
        kind = self._move.kind
        self._servo_stop.set()
        self._end_servo_thread()
        c = self._rtde_c
        if c is None:
            raise DeviceNotConnectedError(f"UR arm at {self.host}: not connected; nothing to stop")
        try:
            with self._ctrl_lock:
                if not c.isConnected():
                    raise DeviceNotConnectedError(
                        f"UR arm at {self.host}: the control link is down, stop{'L' if kind == 'L' else 'J'} cannot "
                        "be sent; use the pendant's stop")
                if kind == "L":
                    c.stopL(float(decel))
                else:
                    c.stopJ(float(decel))
        except ValueError as e:
            raise LimitViolation(f"UR arm at {self.host}: ur_rtde refused the stop: {e}") from None
        except RuntimeError as e:
            if isinstance(e, DriverError):
                raise
            raise DriverError(f"UR arm at {self.host}: stop failed: {e}") from None
        finally:
            self._move.kind = None

    def _emergency_stop_motion(self) -> None:
        """Called when the link is declared lost: stop whatever we started, best effort."""
        self._servo_stop.set()
        c = self._rtde_c
        if c is None or not self._move.kind:
            return
        try:
            with self._ctrl_lock:
                c.stopJ(3.0)
        except Exception:  # noqa: BLE001
            pass

    # ---- protective stop ------------------------------------------------------------------------------
    def dashboard(self) -> Any:
        """The dashboard client (connected on first use, in bounded time)."""
        if self._dashboard is None:
            if self.settings.use_preflight:
                preflight_dashboard(self.host, self.settings.connect_timeout)
            try:
                self._dashboard = self._dashboard_factory(self.host)
            except RuntimeError as e:
                raise DeviceNotConnectedError(
                    f"UR arm at {self.host}: cannot reach the dashboard server (TCP port {DASHBOARD_PORT}): {e}"
                ) from None
        return self._dashboard

    def _unlock_protective_stop(self) -> None:
        s = self.safety_state()
        if s is SafetyState.EMERGENCY_STOP:
            raise EmergencyStopError(f"UR arm at {self.host}: emergency stop is active; a person must release it")
        if s is not SafetyState.PROTECTIVE_STOP:
            return
        d = self.dashboard()
        try:
            d.unlockProtectiveStop()  # None on success; RuntimeError("Unlock protective stop failure: <reply>")
        except RuntimeError as e:
            reply = str(e).split("failure:", 1)[-1].strip()
            # e.g. "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of ..."
            raise ProtectiveStopError(f"UR arm at {self.host}: the controller refused to unlock the protective "
                                      f"stop: {reply}") from None
        try:
            d.closeSafetyPopup()
        except RuntimeError:
            pass
        deadline = time.monotonic() + 2.0
        while self.safety_state() is SafetyState.PROTECTIVE_STOP:
            if time.monotonic() > deadline:
                raise ProtectiveStopError(f"UR arm at {self.host}: the dashboard accepted the unlock but the "
                                          "protective stop is still active after 2 s")
            time.sleep(0.01)
        c = self._ctrl()
        if not self._call("isProgramRunning", c.isProgramRunning):
            self._reupload(c)  # the control script stops with a protective stop; a new one needs our tool again

    def describe(self) -> dict:
        """Model, software version, serial and modes from the dashboard (for `kitchenbot doctor`)."""
        d = self.dashboard()
        version = str(d.polyscopeVersion())
        try:
            serial = str(d.getSerialNumber())
        except RuntimeError:
            serial = "n/a (PolyScope < 5.6)"
        return {
            "model": str(d.getRobotModel()),
            "polyscope": version,
            "serial": serial,
            "robot_mode": str(d.robotmode()),
            "safety": str(d.safetystatus()),
        }
