"""The Fin-Ray gripper on a Dynamixel XM430 servo (Protocol 2.0) through ``dynamixel-sdk`` over pyserial.

The servo runs in current-based position mode (Operating Mode 5): it moves to the goal position but never pushes
harder than the goal current, so closing on a cup stalls on its wall with the current at the goal. A grasp is
*holding* when the fingers closed during the grasp (not a stall on friction where they started) and stalled
inside the object range (above ``min_holding_opening``, below ``max_holding_opening``) with the current near the
goal. A stall far short of the goal saturates the servo's position loop, and a real XM430 latches Overload when
that lasts (torque off: the object drops); so once the fingers stall on an object the goal is moved to just past
the stalled position, where the loop asks for ~90 % of the goal current and no longer saturates, and with nothing
held the goal is set to where the fingers stopped. The offset assumes the loop asks for Position P Gain / 128
current units per tick of error (the emulator's model); if the servo's loop is stiffer, the offset is halved until
the present current falls below the Goal Current.

Connecting never switches torque off on a servo that is on and configured (it may be holding something); the
EEPROM settings (operating mode, Current Limit) are written only when they differ, and when the servo holds an
object that write waits for the next open()/grasp().

Calibration (linear, documented in the constructor): the opening between the finger pads is
``max_opening * (ticks - closed_ticks) / (open_ticks - closed_ticks)``; ``closed_ticks`` is the servo position
where the pads touch, ``open_ticks`` the one where they are ``max_opening`` apart. Measure both once by jogging
the servo with torque off and reading Present Position (e.g. with the Dynamixel Wizard). Either may be larger.

Errors: a missing/unopenable port or a silent servo -> DeviceNotConnectedError (naming port, baud, id); no answer
after the retries -> DriverTimeoutError; Hardware Error Status (@70) set -> HardwareError with the decoded text
(a shutdown needs :meth:`reboot`); a refused write -> DriverError with the SDK's text.
"""

from __future__ import annotations

import logging
import os
import select
import termios
import time
from dataclasses import dataclass

import serial
from dynamixel_sdk import PacketHandler, PortHandler
from serial import SerialException

from kitchenbot.drivers.errors import DeviceNotConnectedError, DriverError, DriverTimeoutError, HardwareError
from kitchenbot.drivers.gripper import GraspResult, Gripper, GripperStatus

log = logging.getLogger(__name__)

# ---- XM430 control table (Protocol 2.0; DESIGN.md section 7) ---------------------------------------------
ADDR_MODEL_NUMBER = 0  # 2
ADDR_FIRMWARE_VERSION = 6  # 1
ADDR_OPERATING_MODE = 11  # 1 (EEPROM)
ADDR_TEMPERATURE_LIMIT = 31  # 1 (EEPROM)
ADDR_MAX_VOLTAGE_LIMIT = 32  # 2 (EEPROM, 0.1 V)
ADDR_MIN_VOLTAGE_LIMIT = 34  # 2 (EEPROM, 0.1 V)
ADDR_CURRENT_LIMIT = 38  # 2 (EEPROM)
ADDR_SHUTDOWN = 63  # 1 (EEPROM): which hardware errors turn torque off
ADDR_TORQUE_ENABLE = 64  # 1
ADDR_HARDWARE_ERROR = 70  # 1
ADDR_POSITION_P_GAIN = 84  # 2: assumed: the position loop asks for Kp/128 current units per tick of error
ADDR_GOAL_CURRENT = 102  # 2
ADDR_GOAL_POSITION = 116  # 4
ADDR_MOVING = 122  # 1; one READ of 122..146 gets every present value at once
ADDR_PRESENT_CURRENT = 126  # 2 signed
ADDR_PRESENT_VELOCITY = 128  # 4 signed
ADDR_PRESENT_POSITION = 132  # 4 signed
ADDR_PRESENT_VOLTAGE = 144  # 2 (0.1 V)
ADDR_PRESENT_TEMPERATURE = 146  # 1 (deg C)

MODE_CURRENT_BASED_POSITION = 5
XM430_MODELS = {1020: "XM430-W350", 1030: "XM430-W210"}
CURRENT_UNIT_A = 0.00269  # A per current unit (XM430)
HW_ERROR_BITS = {
    0x01: "input voltage out of range",
    0x04: "overheating",
    0x08: "motor encoder error",
    0x10: "electrical shock (circuit fault)",
    0x20: "overload",
}

# ---- SDK result codes (dynamixel_sdk.robotis_def) -----------------------------------------------------------
COMM_SUCCESS = 0
COMM_RETRYABLE = {-3001, -3002, -1001, -1002}  # rx timeout, rx corrupt, tx fail, rx fail
ERRBIT_ALERT = 0x80


def decode_hardware_error(status: int) -> str | None:
    """Hardware Error Status (@70) as text, None when clear."""
    if not status:
        return None
    parts = [text for bit, text in HW_ERROR_BITS.items() if status & bit]
    unknown = status & ~sum(HW_ERROR_BITS)
    if unknown:
        parts.append(f"unknown bits 0x{unknown:02x}")
    return ", ".join(parts)


def _signed(value: int, size: int) -> int:
    bits = 8 * size
    return value - (1 << bits) if value & (1 << (bits - 1)) else value


class DxlPortHandler(PortHandler):
    """The SDK's PortHandler with four changes:
    - the port is opened exclusively (pyserial ``exclusive=True``, an flock): a second program (the doctor, a
      Dynamixel Wizard, another kitchenbot) cannot interleave packets with ours; it gets "port in use";
    - a floor on the status-packet timeout: the SDK waits 2 x 16 ms (the FTDI latency timer) + transfer time;
      a loaded host or a slow USB hub can need more before declaring a timeout;
    - timeouts on the monotonic clock (the SDK uses time.time(), which jumps when NTP steps the clock);
    - no busy wait: the SDK polls a non-blocking read in a tight loop while it waits for a status packet,
      burning a core; here an empty read blocks in select() until a byte arrives (at most 1 ms), which wakes
      as soon as data is there, so latency is unchanged."""

    def __init__(self, port_name: str, min_timeout_ms: float = 0.0):
        super().__init__(port_name)
        self.min_timeout_ms = min_timeout_ms

    def setupPort(self, cflag_baud):  # noqa: N802 - SDK method name
        if self.is_open:
            self.closePort()
        self.ser = serial.Serial(
            port=self.port_name, baudrate=self.baudrate, bytesize=serial.EIGHTBITS, timeout=0, exclusive=True
        )
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def getCurrentTime(self):  # noqa: N802 - SDK method name (milliseconds)
        return time.monotonic() * 1000.0

    def readPort(self, length):  # noqa: N802 - SDK method name
        data = self.ser.read(length)
        if not data:
            select.select([self.ser.fileno()], [], [], 0.001)
        return data

    def setPacketTimeout(self, packet_length):  # noqa: N802 - SDK method name
        super().setPacketTimeout(packet_length)
        self.packet_timeout = max(self.packet_timeout, self.min_timeout_ms)

    def setPacketTimeoutMillis(self, msec):  # noqa: N802
        super().setPacketTimeoutMillis(max(msec, self.min_timeout_ms))


@dataclass
class _Present:
    moving: bool
    current_units: int
    velocity_units: int
    position: int
    voltage_v: float
    temperature_c: float
    alert: bool


@dataclass(frozen=True)
class ServoFacts:
    """What the servo reports about itself at connect (defaults: an XM430's factory values, until then)."""

    model_number: int | None = None
    firmware_version: int | None = None
    temperature_limit_c: float = 80.0
    shutdown_mask: int = 0x34  # overheating, electrical shock, overload
    voltage_range: tuple[float, float] = (9.5, 16.0)
    p_gain_per_tick: float = 800 / 128.0  # Position P Gain (@84) / 128


class DynamixelGripper(Gripper):
    """Fin-Ray gripper on one XM430. All units SI (m, A, V, degC) at this interface."""

    def __init__(
        self,
        port: str = "/dev/ttyUSB0",
        baudrate: int = 57600,
        servo_id: int = 1,
        *,
        closed_ticks: int = 2048,
        open_ticks: int = 3072,
        max_opening: float = 0.085,
        current_limit_ma: float = 600.0,
        closing_overshoot_ticks: int = 40,
        min_holding_opening: float = 0.004,
        max_holding_opening: float | None = None,
        min_grasp_travel: float = 0.001,
        holding_current_fraction: float = 0.7,
        hold_current_fraction: float = 0.9,
        position_tolerance_ticks: int = 25,
        retries: int = 3,
        poll_interval: float = 0.01,
        temperature_warn_c: float = 70.0,
        min_packet_timeout_ms: float = 0.0,
    ):
        """`closed_ticks`/`open_ticks`/`max_opening`: the linear calibration above. `current_limit_ma` is
        written to Current Limit (@38) at connect and bounds every grasp. `closing_overshoot_ticks`: a grasp
        aims this far past closed so the pads press together when there is nothing between them.
        `min_holding_opening` (m): below it a stall counts as fully closed (not holding); `max_holding_opening`
        (m, default 2 mm short of `max_opening`): above it a stall is not on an object. `min_grasp_travel` (m): the
        fingers must close at least this far during a grasp to hold (a stall where they started is friction: a
        current limit too low to move them). `holding_current_fraction`: the present current that counts as
        pressing, of the goal current. `hold_current_fraction`: after the stall the goal moves just past the
        stalled position so that the position loop asks for this fraction of the goal current (not saturated:
        no Overload).
        `retries`: attempts per transaction on timeouts/corrupt packets; `min_packet_timeout_ms`: a floor on the
        SDK's status-packet timeout (0 keeps the SDK's ~34 ms)."""
        if closed_ticks == open_ticks:
            raise ValueError("closed_ticks and open_ticks must differ (the calibration would divide by zero)")
        if max_opening <= 0:
            raise ValueError(f"max_opening {max_opening} m: expected a positive opening")
        self.port_name = port
        self.baudrate = int(baudrate)
        self.servo_id = int(servo_id)
        self.closed_ticks = int(closed_ticks)
        self.open_ticks = int(open_ticks)
        self.max_opening = float(max_opening)
        self.current_limit_units = max(1, int(round(current_limit_ma / 1000.0 / CURRENT_UNIT_A)))
        self.max_current = self.current_limit_units * CURRENT_UNIT_A
        self.closing_overshoot_ticks = int(closing_overshoot_ticks)
        self.min_holding_opening = float(min_holding_opening)
        self.max_holding_opening = (
            self.max_opening - 0.002 if max_holding_opening is None else float(max_holding_opening)
        )
        if not (0.0 <= self.min_holding_opening < self.max_holding_opening <= self.max_opening):
            raise ValueError(
                f"holding range {self.min_holding_opening}..{self.max_holding_opening} m: expected "
                f"0 <= min_holding_opening < max_holding_opening <= max_opening ({self.max_opening} m)"
            )
        self.min_grasp_travel = float(min_grasp_travel)
        self.holding_current_fraction = float(holding_current_fraction)
        if not (0.0 < hold_current_fraction < 1.0):
            raise ValueError(f"hold_current_fraction {hold_current_fraction}: expected 0 < fraction < 1")
        self.hold_current_fraction = float(hold_current_fraction)
        self.position_tolerance_ticks = int(position_tolerance_ticks)
        self.retries = max(1, int(retries))
        self.poll_interval = float(poll_interval)
        self.temperature_warn_c = float(temperature_warn_c)
        self.min_packet_timeout_ms = float(min_packet_timeout_ms)
        self.servo = ServoFacts()  # what the servo reported at connect
        self._port: PortHandler | None = None
        self._ph = PacketHandler(2.0)
        self._goal_current_units = self.current_limit_units
        self._grasping = False
        self._hold_units = 0  # present current (units, + closing) when the last grasp settled on its hold
        self._needs_configure = False  # EEPROM settings differ, deferred because the servo held an object

    # ---- calibration ------------------------------------------------------------------------------
    @property
    def _closing_sign(self) -> int:
        """+1 when closing increases the ticks."""
        return 1 if self.closed_ticks > self.open_ticks else -1

    def ticks_to_opening(self, ticks: float) -> float:
        return self.max_opening * (ticks - self.closed_ticks) / (self.open_ticks - self.closed_ticks)

    def opening_to_ticks(self, opening: float) -> int:
        return int(round(self.closed_ticks + (self.open_ticks - self.closed_ticks) * opening / self.max_opening))

    # ---- connection -------------------------------------------------------------------------------
    def connect(self) -> None:
        where = f"{self.port_name} ({self.baudrate} baud, id {self.servo_id})"
        self._open_port()
        try:
            model = self._ping()
            if model not in XM430_MODELS:
                raise DriverError(
                    f"Dynamixel gripper on {where}: model number {model} is not an XM430 "
                    f"(expected one of {XM430_MODELS})"
                )
            self.servo = ServoFacts(
                model_number=model, firmware_version=self._read(ADDR_FIRMWARE_VERSION, 1),
                temperature_limit_c=float(self._read(ADDR_TEMPERATURE_LIMIT, 1)),
                shutdown_mask=self._read(ADDR_SHUTDOWN, 1),
                voltage_range=(self._read(ADDR_MIN_VOLTAGE_LIMIT, 2) / 10.0,
                               self._read(ADDR_MAX_VOLTAGE_LIMIT, 2) / 10.0),
                p_gain_per_tick=max(1, self._read(ADDR_POSITION_P_GAIN, 2)) / 128.0)
            hw = self._read(ADDR_HARDWARE_ERROR, 1)
            if hw:
                log.warning("gripper servo reports a hardware error at connect: %s", decode_hardware_error(hw))
                return  # stay connected so status()/reboot() work; commands raise HardwareError
            self._adopt_or_configure()
        except BaseException:
            self.disconnect()
            raise

    def _adopt_or_configure(self) -> None:
        """At connect: a servo with torque on keeps it (it may be holding an object: switching torque off would
        drop it). Its grasp state is taken over when it presses on something; EEPROM settings that differ are
        written now when nothing is held, else at the next open()/grasp()."""
        self._needs_configure = self._eeprom_differs()
        if not self._read(ADDR_TORQUE_ENABLE, 1):
            self._configure()
            return
        goal_units = abs(_signed(self._read(ADDR_GOAL_CURRENT, 2), 2)) or self.current_limit_units
        p = self._present()
        pressing = (
            not p.moving
            and self.min_holding_opening < self.ticks_to_opening(p.position) < self.max_holding_opening
            and p.current_units * self._closing_sign >= 0.3 * goal_units
        )
        if pressing:
            self._grasping = True
            self._goal_current_units = goal_units
            self._hold_units = p.current_units * self._closing_sign
            log.info(
                "gripper servo holds something at connect (%.1f mm, %.2f A): torque kept on%s",
                self.ticks_to_opening(p.position) * 1000, self._hold_units * CURRENT_UNIT_A,
                "; its operating mode/Current Limit will be rewritten at the next open()" if self._needs_configure else "",
            )
        elif self._needs_configure:
            self._configure()

    def _eeprom_differs(self) -> bool:
        return self._read(ADDR_OPERATING_MODE, 1) != MODE_CURRENT_BASED_POSITION or (
            self._read(ADDR_CURRENT_LIMIT, 2) != self.current_limit_units
        )

    def _open_port(self) -> None:
        if not os.path.exists(self.port_name):
            raise DeviceNotConnectedError(
                f"Dynamixel gripper: serial port {self.port_name} does not exist. Is the U2D2/USB adapter plugged "
                f"in and powered? Check `ls /dev/ttyUSB* /dev/serial/by-id/` and drivers.gripper.port in the config."
            )
        port = DxlPortHandler(self.port_name, self.min_packet_timeout_ms)
        try:
            port.openPort()
        except (SerialException, OSError) as e:
            hint = " (add your user to the 'dialout' group)" if "ermission" in str(e) else ""
            if "exclusively lock" in str(e):
                hint = " (another program has it open: a Dynamixel Wizard, a second kitchenbot, a running daemon?)"
            raise DeviceNotConnectedError(
                f"Dynamixel gripper: cannot open serial port {self.port_name}: {e}{hint}"
            ) from None
        if not port.setBaudRate(self.baudrate):
            port.closePort()
            raise ValueError(f"drivers.gripper.baudrate {self.baudrate}: not a baud rate the Dynamixel SDK supports")
        self._port = port

    def probe(self) -> dict:
        """Read-only health check (for `kitchenbot doctor`): open the port, PING, read model, firmware, hardware
        error, temperature, voltage, torque and mode; write nothing; close. Raises like connect()."""
        was_connected = self.is_connected
        if not was_connected:
            self._open_port()
        try:
            model = self._ping()
            hw = self._read(ADDR_HARDWARE_ERROR, 1)
            p = self._present()
            return {
                "model": XM430_MODELS.get(model, f"model {model}"),
                "model_number": model,
                "firmware": self._read(ADDR_FIRMWARE_VERSION, 1),
                "hardware_error": decode_hardware_error(hw),
                "torque": bool(self._read(ADDR_TORQUE_ENABLE, 1)),
                "operating_mode": self._read(ADDR_OPERATING_MODE, 1),
                "opening_m": self.ticks_to_opening(p.position),
                "temperature_c": p.temperature_c,
                "voltage_v": p.voltage_v,
            }
        finally:
            if not was_connected:
                self.disconnect()

    def _configure(self) -> None:
        """Operating mode and Current Limit (EEPROM: written only when different, with torque off), then torque on."""
        if self._eeprom_differs():
            if self._read(ADDR_TORQUE_ENABLE, 1):
                self._write(ADDR_TORQUE_ENABLE, 1, 0)
            if self._read(ADDR_OPERATING_MODE, 1) != MODE_CURRENT_BASED_POSITION:
                self._write(ADDR_OPERATING_MODE, 1, MODE_CURRENT_BASED_POSITION)
            if self._read(ADDR_CURRENT_LIMIT, 2) != self.current_limit_units:
                self._write(ADDR_CURRENT_LIMIT, 2, self.current_limit_units)
        self._needs_configure = False
        if not self._read(ADDR_TORQUE_ENABLE, 1):
            self._write(ADDR_TORQUE_ENABLE, 1, 1)

    def disconnect(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.closePort()
            except OSError:
                pass

    @property
    def is_connected(self) -> bool:
        return self._port is not None

    def describe(self) -> dict:
        """Model, firmware and port (for `kitchenbot doctor`)."""
        return {
            "model": XM430_MODELS.get(self.servo.model_number or 0, str(self.servo.model_number)),
            "model_number": self.servo.model_number,
            "firmware": self.servo.firmware_version,
            "port": self.port_name,
            "baudrate": self.baudrate,
            "servo_id": self.servo_id,
        }

    # ---- low-level access with retries ------------------------------------------------------------------
    def _txrx(self, what: str, fn, *args):
        """Run one SDK transaction; retry communication failures; map results to our errors.
        Returns (value, error_byte)."""
        if self._port is None:
            raise DeviceNotConnectedError(f"Dynamixel gripper on {self.port_name}: not connected; call connect() first")
        last = ""
        for attempt in range(self.retries):
            try:
                out = fn(self._port, self.servo_id, *args)
            except (SerialException, OSError, termios.error) as e:
                self._port.is_using = False
                raise DeviceNotConnectedError(f"Dynamixel gripper: serial link {self.port_name} failed: {e}") from None
            value, result, error = (None, out[0], out[1]) if len(out) == 2 else out
            if result == COMM_SUCCESS:
                if error & ~ERRBIT_ALERT:
                    raise DriverError(
                        f"Dynamixel gripper: {what} refused by servo id {self.servo_id}: "
                        f"{self._ph.getRxPacketError(error & ~ERRBIT_ALERT)}"
                    )
                return value, error
            last = self._ph.getTxRxResult(result)
            if result not in COMM_RETRYABLE:
                break
            if attempt + 1 < self.retries:
                time.sleep(0.005 * (attempt + 1))
        raise DriverTimeoutError(
            f"Dynamixel gripper: no valid answer to {what} from servo id {self.servo_id} on {self.port_name} "
            f"after {self.retries} tries ({last}). Is the servo powered and the baud rate {self.baudrate}?"
        )

    def _ping(self) -> int:
        try:
            model, _ = self._txrx("PING", self._ph.ping)
        except DriverTimeoutError as e:
            raise DeviceNotConnectedError(
                f"Dynamixel gripper: no servo with id {self.servo_id} answers on {self.port_name} at "
                f"{self.baudrate} baud. Check power (12 V), the id and the baud rate. ({e})"
            ) from None
        return int(model)

    def _read(self, addr: int, size: int) -> int:
        fn = {1: self._ph.read1ByteTxRx, 2: self._ph.read2ByteTxRx, 4: self._ph.read4ByteTxRx}[size]
        value, _ = self._txrx(f"READ @{addr}", fn, addr)
        return int(value)

    def _write(self, addr: int, size: int, value: int) -> None:
        fn = {1: self._ph.write1ByteTxRx, 2: self._ph.write2ByteTxRx, 4: self._ph.write4ByteTxRx}[size]
        try:
            self._txrx(f"WRITE {value} @{addr}", fn, addr, int(value) & ((1 << (8 * size)) - 1))
        except DriverError as e:
            if type(e) is DriverError:  # refused: a latched hardware error explains it better
                hw = self._read(ADDR_HARDWARE_ERROR, 1)
                if hw:
                    raise HardwareError(
                        f"Dynamixel gripper: {decode_hardware_error(hw)} (Hardware Error Status 0x{hw:02x}); "
                        "the servo shut down, call reboot()"
                    ) from None
            raise

    def _present(self) -> _Present:
        """Moving .. Present Temperature (addresses 122-146) in one READ."""
        data, error = self._txrx("READ present values", self._ph.readTxRx, ADDR_MOVING, 25)

        def field(addr: int, size: int) -> int:
            o = addr - ADDR_MOVING
            return int.from_bytes(bytes(data[o : o + size]), "little")

        return _Present(
            moving=bool(field(ADDR_MOVING, 1)),
            current_units=_signed(field(ADDR_PRESENT_CURRENT, 2), 2),
            velocity_units=_signed(field(ADDR_PRESENT_VELOCITY, 4), 4),
            position=_signed(field(ADDR_PRESENT_POSITION, 4), 4),
            voltage_v=field(ADDR_PRESENT_VOLTAGE, 2) / 10.0,
            temperature_c=float(field(ADDR_PRESENT_TEMPERATURE, 1)),
            alert=bool(error & ERRBIT_ALERT),
        )

    def hardware_error(self) -> str | None:
        return decode_hardware_error(self._read(ADDR_HARDWARE_ERROR, 1))

    def _check_healthy(self, p: _Present | None = None) -> _Present:
        p = p or self._present()
        if p.alert:
            hw = self._read(ADDR_HARDWARE_ERROR, 1)
            if hw & self.servo.shutdown_mask:
                raise HardwareError(
                    f"Dynamixel gripper: {decode_hardware_error(hw)} (Hardware Error Status 0x{hw:02x}); "
                    "the servo shut down, call reboot() to clear it"
                )
            if hw:  # an alarm that does not stop the servo (e.g. input voltage): report, keep working
                log.warning("gripper servo alarm: %s", decode_hardware_error(hw))
        if p.temperature_c >= self.temperature_warn_c:
            raise HardwareError(
                f"Dynamixel gripper: servo at {p.temperature_c:.0f} degC, near its "
                f"{self.servo.temperature_limit_c:.0f} degC shutdown limit; let it cool before grasping"
            )
        lo, hi = self.servo.voltage_range
        if not (lo <= p.voltage_v <= hi):
            log.warning("gripper servo input voltage %.1f V outside %.1f..%.1f V", p.voltage_v, lo, hi)
        return p

    def _ensure_torque(self) -> None:
        if self._needs_configure or not self._read(ADDR_TORQUE_ENABLE, 1):
            self._configure()

    # ---- commands ---------------------------------------------------------------------------------
    def _pressing(self, p: _Present, units: float) -> bool:
        return p.current_units * self._closing_sign >= self.holding_current_fraction * units

    def _in_object_range(self, p: _Present) -> bool:
        return self.min_holding_opening < self.ticks_to_opening(p.position) < self.max_holding_opening

    def _holding(self, p: _Present) -> bool:
        """Still on the object the last grasp closed on: stalled inside the object range, still pressing with
        most of the current it held with (an object that slipped out lets the fingers run on to the hold goal,
        where the current falls away)."""
        return (not p.moving) and self._in_object_range(p) and self._pressing(p, self._hold_units)

    def open(self, opening: float | None = None, timeout: float = 3.0) -> None:
        target = self.max_opening if opening is None else float(opening)
        if not (0.0 <= target <= self.max_opening):
            raise ValueError(f"opening {target} m: expected 0 <= opening <= {self.max_opening} m")
        self._check_healthy()
        self._ensure_torque()
        self._grasping = False
        self._goal_current_units = self.current_limit_units
        self._write(ADDR_GOAL_CURRENT, 2, self.current_limit_units)
        goal = self.opening_to_ticks(target)
        self._write(ADDR_GOAL_POSITION, 4, goal)
        deadline = time.monotonic() + timeout
        while True:
            p = self._check_healthy()
            if abs(p.position - goal) <= self.position_tolerance_ticks:
                return
            if time.monotonic() > deadline:
                raise DriverTimeoutError(
                    f"Dynamixel gripper: did not reach {target * 1000:.1f} mm within {timeout} s "
                    f"(stuck at {self.ticks_to_opening(p.position) * 1000:.1f} mm; something in the way?)"
                )
            time.sleep(self.poll_interval)

    def _settle(
        self, goal: int, goal_units: int, deadline: float, timeout: float, what: str, *, anywhere: bool = False
    ) -> _Present:
        """Poll until the fingers stop (3 polls in a row within a tick, not moving) pressing or at the goal
        (`anywhere`: wherever they stop)."""
        settled, last_pos = 0, None
        while True:
            time.sleep(self.poll_interval)
            p = self._check_healthy()
            reached = abs(p.position - goal) <= self.position_tolerance_ticks
            still = last_pos is not None and abs(p.position - last_pos) <= 1 and not p.moving
            pressing = p.current_units * self._closing_sign >= self.holding_current_fraction * goal_units
            settled = settled + 1 if (still and (pressing or reached or anywhere)) else 0
            last_pos = p.position
            if settled >= 3:
                return p
            if time.monotonic() > deadline:
                raise DriverTimeoutError(
                    f"Dynamixel gripper: {what} did not settle within {timeout} s "
                    f"(at {self.ticks_to_opening(p.position) * 1000:.1f} mm, {p.current_units * CURRENT_UNIT_A:.2f} A)"
                )

    def grasp(self, current_limit: float, timeout: float = 3.0) -> GraspResult:
        limit = self._check_current(current_limit)
        start = self._check_healthy().position
        self._ensure_torque()
        goal_units = max(1, min(self.current_limit_units, int(round(limit / CURRENT_UNIT_A))))
        self._goal_current_units = goal_units
        self._grasping = False
        self._write(ADDR_GOAL_CURRENT, 2, goal_units)
        goal = self.closed_ticks + self._closing_sign * self.closing_overshoot_ticks
        self._write(ADDR_GOAL_POSITION, 4, goal)
        deadline = time.monotonic() + timeout
        p = self._settle(goal, goal_units, deadline, timeout, "grasp")
        travel = (p.position - start) * self._closing_sign * abs(self.max_opening / (self.open_ticks - self.closed_ticks))
        on_object = (
            travel >= self.min_grasp_travel and self._in_object_range(p) and self._pressing(p, goal_units)
        )
        if not on_object:
            # Fully closed, or stuck where it started: no force is needed, and a goal left 40 ticks past a
            # stall would saturate the position loop until the servo trips Overload.
            self._write(ADDR_GOAL_POSITION, 4, p.position)
            if travel < self.min_grasp_travel:
                log.warning(
                    "gripper: fingers did not close (moved %.1f mm at %.2f A): the current limit may be below the "
                    "fingers' friction", travel * 1000, limit,
                )
            return GraspResult(False, max(0.0, self.ticks_to_opening(p.position)), self._amps(p))
        # Hold just past the stalled position: the position loop asks for hold_current_fraction of the goal
        # current instead of saturating at it. Where the servo's loop is stiffer than Kp/128 per tick, the
        # offset is halved until the current falls below the clamp.
        offset = max(1, int(round(self.hold_current_fraction * goal_units / self.servo.p_gain_per_tick)))
        for _ in range(4):
            hold_goal = p.position + self._closing_sign * offset
            self._write(ADDR_GOAL_POSITION, 4, hold_goal)
            p = self._settle(hold_goal, goal_units, deadline, timeout, "grasp hold", anywhere=True)
            if p.current_units * self._closing_sign < 0.97 * goal_units or offset == 1:
                break
            offset = max(1, offset // 2)
        self._hold_units = p.current_units * self._closing_sign
        self._grasping = self._in_object_range(p) and self._hold_units >= 0.3 * goal_units
        return GraspResult(self._grasping, max(0.0, self.ticks_to_opening(p.position)), self._amps(p))

    def _amps(self, p: _Present) -> float:
        return p.current_units * self._closing_sign * CURRENT_UNIT_A

    def status(self) -> GripperStatus:
        p = self._present()
        hw = self._read(ADDR_HARDWARE_ERROR, 1) if p.alert else 0
        shut_down = bool(hw & self.servo.shutdown_mask)
        return GripperStatus(
            opening=self.ticks_to_opening(p.position),
            current=self._amps(p),
            holding=self._grasping and not shut_down and self._holding(p),
            moving=p.moving,
            error=decode_hardware_error(hw),
            temperature_c=p.temperature_c,
            voltage_v=p.voltage_v,
        )

    def reboot(self, timeout: float = 2.0) -> None:
        """REBOOT the servo (clears a shutdown), wait until it answers again; it comes back with torque off."""
        self._txrx("REBOOT", self._ph.reboot)
        self._grasping = False
        deadline = time.monotonic() + timeout
        while True:
            time.sleep(0.05)
            try:
                self._txrx("PING", self._ph.ping)
                break
            except DriverTimeoutError:
                if time.monotonic() > deadline:
                    raise DriverTimeoutError(
                        f"Dynamixel gripper: servo id {self.servo_id} did not come back within {timeout} s of REBOOT"
                    ) from None
        hw = self._read(ADDR_HARDWARE_ERROR, 1)
        if hw:
            raise HardwareError(f"Dynamixel gripper: still {decode_hardware_error(hw)} after REBOOT")
