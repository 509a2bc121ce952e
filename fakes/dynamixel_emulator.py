"""A Dynamixel XM430 servo (Protocol 2.0) emulated on a pseudo-terminal, in its own process.

The real ``dynamixel-sdk`` opens the pty's slave path like a U2D2 serial adapter and talks to this process byte
for byte: header ``FF FF FD 00``, CRC-16 (poly 0x8005), byte stuffing, PING / READ / WRITE / REBOOT / SYNC and
BULK read/write, status packets with the error byte (bit 7 = hardware alert). Behind the protocol sits a stateful
XM430 control table (EEPROM and RAM areas; EEPROM writes refused while torque is on) and a small model of the
Fin-Ray gripper it drives: the fingers close at a limited speed, stall on a simulated object (or on each other
when fully closed), and in current-based position mode the present current then rises to the goal current.
The position loop is proportional (Position P Gain @84 / 128 current units per tick of position error) and
clamped at the Goal Current: a stall whose position error asks for more than the clamp (a goal far past the
object) is a saturated output, and after ``overload_after_s`` of it the servo latches Overload (bit 5 of @70), as a
real XM430 does after a sustained stall far from its goal. Hardware errors (overload, overheating, ...) can also be
injected; an error in the Shutdown mask (@63) turns torque off and only a REBOOT clears it. REBOOT restores the RAM
area as at power-on: torque off, errors cleared, Goal Current = Current Limit (@38), Goal PWM = PWM Limit (@36),
Goal Position = the present position. Several servos may share the bus (``extra_ids``); their answers to a sync
or bulk read come in the order of the ids in the instruction.

Why hand-written: the SDK is the client under test, so the emulator must not share its code; and no library
emulates a Dynamixel. This module uses only the standard library, so the child process starts in ~50 ms.

Parent side: :class:`DynamixelEmulator` starts ``python dynamixel_emulator.py`` and drives it over a JSON-lines
control channel on stdin/stdout (set the object width, inject faults, go silent, read the internal state).
"""

from __future__ import annotations

import json
import os
import selectors
import subprocess
import sys
import termios
import time
import tty
from dataclasses import dataclass, field

if __name__ == "__main__":
    # The child process (the servo itself) runs this file with the standard library only; the test-side
    # handle's base class, and the package it lives in, are not needed there.
    EmulatorProcess = object
else:
    from kitchenbot.fakes.emulator_process import EmulatorProcess

# ==================================================================================================
# Protocol 2.0 framing
# ==================================================================================================
HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE

INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REBOOT = 0x08
INST_STATUS = 0x55
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83
INST_BULK_READ = 0x92
INST_BULK_WRITE = 0x93

# Error byte of a status packet (low 7 bits: a number; bit 7: hardware alert)
ERR_RESULT_FAIL = 1
ERR_INSTRUCTION = 2
ERR_CRC = 3
ERR_DATA_RANGE = 4
ERR_DATA_LENGTH = 5
ERR_DATA_LIMIT = 6
ERR_ACCESS = 7
ERR_ALERT = 0x80


def crc16(data: bytes, crc: int = 0) -> int:
    """CRC-16/BUYPASS (poly 0x8005, no reflection, init 0) as the Protocol 2.0 manual specifies."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert 0xFD after every FF FF FD inside instruction+parameters so no header appears mid-packet."""
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Drop the 0xFD inserted after FF FF FD (inverse of :func:`stuff`)."""
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if body[i] == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            if i + 1 < len(body) and body[i + 1] == 0xFD:
                i += 1  # the stuffed byte
        i += 1
    return bytes(out)


def frame(servo_id: int, instruction: int, params: bytes) -> bytes:
    """A complete packet: header, id, length, stuffed instruction+params, CRC over all of it."""
    body = stuff(bytes([instruction]) + params)
    head = HEADER + bytes([servo_id]) + (len(body) + 2).to_bytes(2, "little")
    packet = head + body
    return packet + crc16(packet).to_bytes(2, "little")


def status_packet(servo_id: int, error: int, params: bytes = b"") -> bytes:
    return frame(servo_id, INST_STATUS, bytes([error]) + params)


@dataclass
class Packet:
    servo_id: int
    instruction: int
    params: bytes
    crc_ok: bool = True


class PacketParser:
    """Incremental parser: feed raw bytes, get complete packets (garbage before a header is skipped)."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def feed(self, data: bytes) -> list[Packet]:
        self.buf += data
        packets = []
        while True:
            start = self.buf.find(HEADER)
            if start < 0:
                # keep a possible partial header at the end
                del self.buf[: max(0, len(self.buf) - 3)]
                return packets
            del self.buf[:start]
            if len(self.buf) < 7:
                return packets
            length = int.from_bytes(self.buf[5:7], "little")
            if length < 3:  # instruction + CRC at least
                del self.buf[:4]
                continue
            total = 7 + length
            if len(self.buf) < total:
                return packets
            raw = bytes(self.buf[:total])
            del self.buf[:total]
            crc_ok = crc16(raw[:-2]) == int.from_bytes(raw[-2:], "little")
            body = unstuff(raw[7:-2])
            packets.append(Packet(raw[4], body[0], body[1:], crc_ok))


# ==================================================================================================
# XM430 control table
# ==================================================================================================
@dataclass(frozen=True)
class Field:
    name: str
    addr: int
    size: int
    eeprom: bool
    writable: bool
    default: int
    lo: int = 0
    hi: int = 0  # 0 = no range check
    signed: bool = False


# XM430-W350 (model 1020) e-Manual, Protocol 2.0 control table (indirect addresses left out).
FIELDS = [
    Field("model_number", 0, 2, True, False, 1020),
    Field("model_information", 2, 4, True, False, 0),
    Field("firmware_version", 6, 1, True, False, 48),
    Field("id", 7, 1, True, True, 1, 0, 252),
    Field("baud_rate", 8, 1, True, True, 1, 0, 7),
    Field("return_delay_time", 9, 1, True, True, 250, 0, 254),
    Field("drive_mode", 10, 1, True, True, 0, 0, 13),
    Field("operating_mode", 11, 1, True, True, 3, 0, 16),
    Field("secondary_id", 12, 1, True, True, 255, 0, 255),
    Field("protocol_type", 13, 1, True, True, 2, 1, 2),
    Field("homing_offset", 20, 4, True, True, 0, -1044479, 1044479, True),
    Field("moving_threshold", 24, 4, True, True, 10, 0, 1023),
    Field("temperature_limit", 31, 1, True, True, 80, 0, 100),
    Field("max_voltage_limit", 32, 2, True, True, 160, 60, 160),
    Field("min_voltage_limit", 34, 2, True, True, 95, 60, 160),
    Field("pwm_limit", 36, 2, True, True, 885, 0, 885),
    Field("current_limit", 38, 2, True, True, 1193, 0, 1193),
    Field("velocity_limit", 44, 4, True, True, 200, 0, 1023),
    Field("max_position_limit", 48, 4, True, True, 4095, 0, 4095),
    Field("min_position_limit", 52, 4, True, True, 0, 0, 4095),
    Field("startup_configuration", 60, 1, True, True, 0, 0, 3),
    Field("shutdown", 63, 1, True, True, 52, 0, 255),
    Field("torque_enable", 64, 1, False, True, 0, 0, 1),
    Field("led", 65, 1, False, True, 0, 0, 1),
    Field("status_return_level", 68, 1, False, True, 2, 0, 2),
    Field("registered_instruction", 69, 1, False, False, 0),
    Field("hardware_error_status", 70, 1, False, False, 0),
    Field("velocity_i_gain", 76, 2, False, True, 1920, 0, 16383),
    Field("velocity_p_gain", 78, 2, False, True, 100, 0, 16383),
    Field("position_d_gain", 80, 2, False, True, 0, 0, 16383),
    Field("position_i_gain", 82, 2, False, True, 0, 0, 16383),
    Field("position_p_gain", 84, 2, False, True, 800, 0, 16383),
    Field("feedforward_2nd_gain", 88, 2, False, True, 0, 0, 16383),
    Field("feedforward_1st_gain", 90, 2, False, True, 0, 0, 16383),
    Field("bus_watchdog", 98, 1, False, True, 0, 0, 127),
    Field("goal_pwm", 100, 2, False, True, 885, -885, 885, True),
    Field("goal_current", 102, 2, False, True, 1193, -1193, 1193, True),
    Field("goal_velocity", 104, 4, False, True, 0, -1023, 1023, True),
    Field("profile_acceleration", 108, 4, False, True, 0, 0, 32767),
    Field("profile_velocity", 112, 4, False, True, 0, 0, 32767),
    Field("goal_position", 116, 4, False, True, 0, -1048575, 1048575, True),
    Field("realtime_tick", 120, 2, False, False, 0),
    Field("moving", 122, 1, False, False, 0),
    Field("moving_status", 123, 1, False, False, 0),
    Field("present_pwm", 124, 2, False, False, 0, signed=True),
    Field("present_current", 126, 2, False, False, 0, signed=True),
    Field("present_velocity", 128, 4, False, False, 0, signed=True),
    Field("present_position", 132, 4, False, False, 0, signed=True),
    Field("velocity_trajectory", 136, 4, False, False, 0, signed=True),
    Field("position_trajectory", 140, 4, False, False, 0, signed=True),
    Field("present_input_voltage", 144, 2, False, False, 120),
    Field("present_temperature", 146, 1, False, False, 30),
    Field("backup_ready", 147, 1, False, False, 0),
]
BY_NAME = {f.name: f for f in FIELDS}
BY_ADDR = {f.addr: f for f in FIELDS}
TABLE_SIZE = 148
MODE_CURRENT_BASED_POSITION = 5

# Hardware Error Status bits
HW_INPUT_VOLTAGE = 0x01
HW_OVERHEATING = 0x04
HW_ENCODER = 0x08
HW_ELECTRICAL_SHOCK = 0x10
HW_OVERLOAD = 0x20
FAULTS = {
    "input_voltage": HW_INPUT_VOLTAGE,
    "overheating": HW_OVERHEATING,
    "encoder": HW_ENCODER,
    "electrical_shock": HW_ELECTRICAL_SHOCK,
    "overload": HW_OVERLOAD,
}
BAUD_CODES = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000, 7: 4_500_000}

CURRENT_UNIT_A = 0.00269  # A per Present/Goal Current unit
VELOCITY_UNIT_TPS = 0.229 / 60.0 * 4096  # ticks/s per Present Velocity unit (0.229 rpm)


class AccessError(Exception):
    def __init__(self, code: int):
        self.code = code


@dataclass
class GripperMechanics:
    """The Fin-Ray gripper the servo drives: a linear map from ticks to finger opening, a hard stop when the
    fingers meet, an optional object between them, and finger compliance once in contact."""

    closed_ticks: int = 2048  # fingers touch
    open_ticks: int = 3072  # fully open (mechanical end of travel)
    max_opening: float = 0.085  # m at open_ticks
    object_width: float | None = None  # m; None = nothing between the fingers
    stiffness: float = 20.0  # current units per tick of finger deflection once in contact
    free_current: int = 8  # current units needed to move the fingers freely

    def ticks_for(self, opening: float) -> float:
        return self.closed_ticks + (self.open_ticks - self.closed_ticks) * opening / self.max_opening

    def closing_sign(self) -> int:
        return 1 if self.closed_ticks > self.open_ticks else -1

    def stop_ticks(self) -> float:
        """Where closing stops without deflection: the object's surface, or the fingers meeting."""
        if self.object_width is not None and 0.0 < self.object_width < self.max_opening:
            return self.ticks_for(self.object_width)
        return float(self.closed_ticks)


@dataclass
class Servo:
    """One XM430: the control table plus the motion model, advanced lazily to the time of each packet."""

    mech: GripperMechanics = field(default_factory=GripperMechanics)
    table: bytearray = field(default_factory=lambda: bytearray(TABLE_SIZE))
    ambient_c: float = 30.0
    voltage_v: float = 12.0
    position: float = 0.0  # ticks (float; the table holds the rounded value)
    velocity: float = 0.0  # ticks/s
    current: float = 0.0  # units, signed
    temperature: float = 30.0
    rebooting_until: float = 0.0
    overload_after_s: float = 2.0  # seconds of saturated stall before Overload (not published by ROBOTIS; a model)
    saturated_s: float = 0.0  # how long the output has been saturated while stalled
    last_t: float = field(default_factory=time.monotonic)
    start_t: float = field(default_factory=time.monotonic)

    def __post_init__(self) -> None:
        for f in FIELDS:
            self._put(f, f.default)
        self.position = float(self.mech.open_ticks)
        self.temperature = self.ambient_c
        self._power_on_goals()
        self._publish()

    def _power_on_goals(self) -> None:
        """RAM goals whose initial value the e-Manual gives as '-': taken from the EEPROM limits and the present
        position at power-on/REBOOT, so torque-on neither jumps nor runs at a stale current."""
        self.set("goal_pwm", self.get("pwm_limit"))
        self.set("goal_current", self.get("current_limit"))
        self.set("goal_velocity", 0)
        self.set("goal_position", round(self.position))

    # ---- raw table access -------------------------------------------------------------------------
    def _put(self, f: Field, value: int) -> None:
        self.table[f.addr : f.addr + f.size] = int(value).to_bytes(f.size, "little", signed=f.signed)

    def get(self, name: str) -> int:
        f = BY_NAME[name]
        return int.from_bytes(self.table[f.addr : f.addr + f.size], "little", signed=f.signed)

    def set(self, name: str, value: int) -> None:
        self._put(BY_NAME[name], value)

    @property
    def servo_id(self) -> int:
        return self.get("id")

    @property
    def hw_error(self) -> int:
        return self.get("hardware_error_status")

    def error_byte(self, code: int = 0) -> int:
        return code | (ERR_ALERT if self.hw_error else 0)

    # ---- READ / WRITE semantics -----------------------------------------------------------------------
    def read(self, addr: int, length: int) -> bytes:
        if length == 0 or addr < 0 or addr + length > TABLE_SIZE:
            raise AccessError(ERR_ACCESS)
        return bytes(self.table[addr : addr + length])

    def write(self, addr: int, data: bytes) -> None:
        """Whole fields only; read-only fields, EEPROM with torque on and out-of-range values are refused
        before anything is written (a refused packet changes nothing)."""
        end = addr + len(data)
        if not data or addr < 0 or end > TABLE_SIZE:
            raise AccessError(ERR_ACCESS)
        updates: list[tuple[Field, int]] = []
        a = addr
        while a < end:
            f = BY_ADDR.get(a)
            if f is None:  # a reserved byte or the middle of a field
                raise AccessError(ERR_ACCESS)
            if not f.writable:
                raise AccessError(ERR_ACCESS)
            if a + f.size > end:
                raise AccessError(ERR_DATA_LENGTH)
            if f.eeprom and self.get("torque_enable"):
                raise AccessError(ERR_ACCESS)
            value = int.from_bytes(data[a - addr : a - addr + f.size], "little", signed=f.signed)
            if f.hi and not (f.lo <= value <= f.hi):
                raise AccessError(ERR_DATA_RANGE)
            if f.name == "goal_current" and abs(value) > self.get("current_limit"):
                raise AccessError(ERR_DATA_LIMIT)
            if f.name == "torque_enable" and value == 1 and self.hw_error & self.get("shutdown"):
                raise AccessError(ERR_RESULT_FAIL)  # in shutdown: torque stays off until REBOOT
            updates.append((f, value))
            a += f.size
        for f, value in updates:
            if f.name == "torque_enable" and value == 1 and not self.get("torque_enable"):
                # Torque on: the goal becomes the present position so the servo does not jump.
                self.set("goal_position", round(self.position))
            self._put(f, value)

    def reboot(self, now: float) -> None:
        """As at power-on: RAM back to its initial values (torque off, hardware error cleared, goals from the
        EEPROM limits and the present position), EEPROM kept; deaf for a moment while booting. A cause that
        persists (a servo still too hot) latches its error again on the next step."""
        for f in FIELDS:
            if not f.eeprom:
                self._put(f, f.default)
        self._power_on_goals()
        self.velocity = 0.0
        self.current = 0.0
        self.saturated_s = 0.0
        self.start_t = now
        self.rebooting_until = now + 0.05
        self._publish()

    def fault(self, bits: int) -> None:
        self.set("hardware_error_status", self.hw_error | bits)
        if bits & self.get("shutdown"):
            self.set("torque_enable", 0)
            self.velocity = 0.0
            self.current = 0.0
            self.saturated_s = 0.0
        self._publish()

    # ---- physics ---------------------------------------------------------------------------------
    def advance(self, now: float, max_step: float = 0.005) -> None:
        dt_total = now - self.last_t
        self.last_t = now
        while dt_total > 1e-9:
            dt = min(dt_total, max_step)
            dt_total -= dt
            self._step(dt)
        self._publish()

    def _speed_limit(self) -> float:
        units = self.get("profile_velocity") or self.get("velocity_limit")
        return max(1.0, units * VELOCITY_UNIT_TPS)

    def _step(self, dt: float) -> None:
        m = self.mech
        sign_close = m.closing_sign()
        saturated = False
        if not self.get("torque_enable"):
            self.velocity = 0.0
            self.current = 0.0
            # limp: deflected Fin-Ray fingers spring back to the object's surface (a held object is let go)
            if (self.position - m.stop_ticks()) * sign_close > 0:
                self.position = m.stop_ticks()
        else:
            limit = self.get("current_limit")
            if self.get("operating_mode") == MODE_CURRENT_BASED_POSITION:
                max_cur = min(abs(self.get("goal_current")), limit)
            else:
                max_cur = limit
            goal = float(self.get("goal_position"))
            err = goal - self.position
            direction = 0 if abs(err) < 0.5 else (1 if err > 0 else -1)
            # contact: moving in the closing direction at or past the stop (object surface / fingers meeting)
            stop = m.stop_ticks()
            past_stop = (self.position - stop) * sign_close  # > 0: fingers deflected against the stop
            if direction == sign_close and past_stop >= -0.5:
                # Pressing: the position loop asks for Kp/128 current units per tick of error, clamped at the
                # goal current (saturated when it asks for more); the current follows with a 30 ms time constant
                # and the fingers deflect with it.
                demand = self.get("position_p_gain") / 128.0 * abs(err)
                target = min(demand, max_cur)
                saturated = demand >= max_cur
                magnitude = abs(self.current) + (target - abs(self.current)) * min(1.0, dt / 0.03)
                self.current = sign_close * min(magnitude, max_cur)
                deflection = abs(self.current) / m.stiffness
                new_pos = stop + sign_close * deflection
                # never deflect past the goal
                if (new_pos - goal) * sign_close > 0:
                    new_pos = goal
                self.velocity = (new_pos - self.position) / dt
                self.position = new_pos
            elif direction == 0:
                # at the goal: only the finger deflection (if in contact) needs holding current
                self.velocity = 0.0
                self.current = sign_close * min(max(past_stop, 0.0) * m.stiffness, max_cur)
            else:
                if max_cur < m.free_current:
                    self.velocity = 0.0  # too weak to move the fingers (friction): stalled at full output
                    self.current = direction * max_cur
                    saturated = True
                else:
                    step = min(abs(err), self._speed_limit() * dt)
                    new_pos = self.position + direction * step
                    if direction == sign_close and (new_pos - stop) * sign_close > 0:
                        new_pos = stop  # reached the surface this step
                    self.velocity = (new_pos - self.position) / dt
                    self.position = new_pos
                    self.current = direction * m.free_current
                # opening stops at the mechanical end of travel
                if (self.position - m.open_ticks) * -sign_close > 0:
                    self.position = float(m.open_ticks)
                    self.velocity = 0.0
                    self.current = direction * max_cur
                    saturated = True
        # Overload: the output stays saturated while the motor does not turn (under the Moving Threshold)
        stalled = abs(self.velocity) <= self.get("moving_threshold") * VELOCITY_UNIT_TPS
        self.saturated_s = self.saturated_s + dt if (saturated and stalled) else 0.0
        if self.saturated_s >= self.overload_after_s and not self.hw_error & HW_OVERLOAD:
            self.fault(HW_OVERLOAD)
        # temperature: I^2 heating, first-order cooling to ambient (tau 120 s)
        amps = abs(self.current) * CURRENT_UNIT_A
        self.temperature += dt * (0.8 * amps * amps - (self.temperature - self.ambient_c) / 120.0)
        if self.temperature >= self.get("temperature_limit"):
            self.fault(HW_OVERHEATING)
        min_v, max_v = self.get("min_voltage_limit") / 10.0, self.get("max_voltage_limit") / 10.0
        if not (min_v <= self.voltage_v <= max_v):
            self.fault(HW_INPUT_VOLTAGE)

    def _publish(self) -> None:
        """Mirror the physical state into the read-only table fields."""
        self.set("present_position", round(self.position))
        self.set("present_velocity", round(self.velocity / VELOCITY_UNIT_TPS))
        self.set("present_current", max(-32768, min(32767, round(self.current))))
        self.set("present_pwm", max(-885, min(885, round(self.current / 1193 * 885))))
        moving = abs(self.get("present_velocity")) > self.get("moving_threshold")
        self.set("moving", int(moving))
        in_position = abs(self.get("goal_position") - self.position) <= 20
        self.set("moving_status", (1 if in_position else 0) | (2 if moving else 0))
        self.set("present_input_voltage", round(self.voltage_v * 10))
        self.set("present_temperature", max(0, min(255, round(self.temperature))))
        self.set("realtime_tick", int((self.last_t - self.start_t) * 1000) % 32768)

    def snapshot(self) -> dict:
        d = {f.name: self.get(f.name) for f in FIELDS}
        d["position_exact"] = self.position
        d["object_width"] = self.mech.object_width
        d["saturated_s"] = self.saturated_s
        return d


# ==================================================================================================
# The bus: packets in, status packets out
# ==================================================================================================
class Bus:
    """Every servo on one RS-485/TTL bus. A packet is heard by all; each answers for itself. Group reads are
    answered in the order of the ids in the instruction (on a real bus each servo waits for the status packet
    of the id before it), whatever order the servos were connected in."""

    def __init__(self, servos: list[Servo]):
        self.servos = list(servos)

    def by_id(self, servo_id: int) -> Servo | None:
        return next((s for s in self.servos if s.servo_id == servo_id), None)

    @staticmethod
    def _reply(s: Servo, error: int, params: bytes = b"", *, instruction: int) -> bytes:
        level = s.get("status_return_level")
        if instruction == INST_PING or level == 2 or (level == 1 and instruction == INST_READ):
            return status_packet(s.servo_id, s.error_byte(error), params)
        return b""

    def handle(self, pkt: Packet, now: float) -> bytes:
        group = pkt.instruction in (INST_SYNC_READ, INST_SYNC_WRITE, INST_BULK_READ, INST_BULK_WRITE)
        awake = [s for s in self.servos if now >= s.rebooting_until]
        for s in awake:
            s.advance(now)
        if group:
            if not pkt.crc_ok or pkt.servo_id != BROADCAST_ID:
                return b""
            return self._group(pkt.instruction, pkt.params, awake)
        if pkt.servo_id == BROADCAST_ID:
            targets = sorted(awake, key=lambda s: s.servo_id)
        else:
            targets = [s for s in awake if s.servo_id == pkt.servo_id]
        return b"".join(self._one(s, pkt, now) for s in targets)

    def _one(self, s: Servo, pkt: Packet, now: float) -> bytes:
        sid = s.servo_id
        broadcast = pkt.servo_id == BROADCAST_ID
        if not pkt.crc_ok:
            return b"" if broadcast else status_packet(sid, s.error_byte(ERR_CRC))
        try:
            if pkt.instruction == INST_PING:  # a broadcast PING is answered by every servo, in id order
                info = s.get("model_number").to_bytes(2, "little") + bytes([s.get("firmware_version")])
                return status_packet(sid, s.error_byte(), info)
            reply = self._single(s, pkt.instruction, pkt.params, now)
            return b"" if broadcast else reply  # broadcast WRITE/REBOOT act but are never answered
        except AccessError as e:
            return b"" if broadcast else self._reply(s, e.code, instruction=pkt.instruction)

    def _single(self, s: Servo, instruction: int, p: bytes, now: float) -> bytes:
        """READ / WRITE / REBOOT addressed to one servo (or broadcast); raises AccessError to refuse."""
        if instruction == INST_READ:
            if len(p) != 4:
                raise AccessError(ERR_DATA_LENGTH)
            addr, length = int.from_bytes(p[0:2], "little"), int.from_bytes(p[2:4], "little")
            return self._reply(s, 0, s.read(addr, length), instruction=INST_READ)
        if instruction == INST_WRITE:
            if len(p) < 3:
                raise AccessError(ERR_DATA_LENGTH)
            s.write(int.from_bytes(p[0:2], "little"), p[2:])
            s._publish()
            return self._reply(s, 0, instruction=INST_WRITE)
        if instruction == INST_REBOOT:
            reply = self._reply(s, 0, instruction=INST_REBOOT)
            s.reboot(now)
            return reply  # sent before the servo goes deaf
        raise AccessError(ERR_INSTRUCTION)

    @staticmethod
    def _read_status(s: Servo, addr: int, length: int) -> bytes:
        try:
            return status_packet(s.servo_id, s.error_byte(), s.read(addr, length))
        except AccessError as e:
            return status_packet(s.servo_id, s.error_byte(e.code))

    def _group(self, instruction: int, p: bytes, awake: list[Servo]) -> bytes:
        by_id = {s.servo_id: s for s in awake}
        out = bytearray()
        if instruction == INST_SYNC_READ:  # addr(2) len(2) id...
            addr, length = int.from_bytes(p[0:2], "little"), int.from_bytes(p[2:4], "little")
            for sid in p[4:]:  # the instruction's order, not the bus's
                if sid in by_id:
                    out += self._read_status(by_id[sid], addr, length)
        elif instruction == INST_SYNC_WRITE:  # addr(2) len(2) [id data(len)]...
            addr, length = int.from_bytes(p[0:2], "little"), int.from_bytes(p[2:4], "little")
            for i in range(4, len(p) - length, length + 1):
                s = by_id.get(p[i])
                if s is not None:
                    try:
                        s.write(addr, p[i + 1 : i + 1 + length])
                        s._publish()
                    except AccessError:
                        pass  # sync write has no status packet
        elif instruction == INST_BULK_READ:  # [id addr(2) len(2)]...
            for i in range(0, len(p) - 4, 5):
                s = by_id.get(p[i])
                if s is not None:
                    addr, length = int.from_bytes(p[i + 1 : i + 3], "little"), int.from_bytes(p[i + 3 : i + 5], "little")
                    out += self._read_status(s, addr, length)
        elif instruction == INST_BULK_WRITE:  # [id addr(2) len(2) data(len)]...
            i = 0
            while i + 5 <= len(p):
                length = int.from_bytes(p[i + 3 : i + 5], "little")
                s = by_id.get(p[i])
                if s is not None:
                    try:
                        s.write(int.from_bytes(p[i + 1 : i + 3], "little"), p[i + 5 : i + 5 + length])
                        s._publish()
                    except AccessError:
                        pass
                i += 5 + length
        return bytes(out)

# ==================================================================================================
# The child process: pty + control channel
# ==================================================================================================
_TERMIOS_BAUD = {getattr(termios, f"B{b}"): b for b in BAUD_CODES.values() if hasattr(termios, f"B{b}")}


def _slave_baud(slave_fd: int) -> int | None:
    try:
        return _TERMIOS_BAUD.get(termios.tcgetattr(slave_fd)[4])
    except termios.error:
        return None


def _control(bus: Bus, state: dict, msg: dict) -> dict:
    cmd = msg.get("cmd")
    now = time.monotonic()
    servo = bus.by_id(msg["id"]) if msg.get("id") is not None else bus.servos[0]
    if servo is None:
        return {"ok": False, "error": f"no servo with id {msg['id']} on the bus"}
    servo.advance(now)
    if cmd == "set":
        if "object_width" in msg:
            servo.mech.object_width = msg["object_width"]
        if "voltage" in msg:
            servo.voltage_v = float(msg["voltage"])
        if "temperature" in msg:
            servo.temperature = float(msg["temperature"])
        if "silent" in msg:
            state["silent"] = bool(msg["silent"])
        if "overload_after_s" in msg:
            servo.overload_after_s = float(msg["overload_after_s"])
        servo.advance(now)
        return {"ok": True}
    if cmd == "fault":
        kind = msg.get("kind")
        if kind not in FAULTS:
            return {"ok": False, "error": f"unknown fault {kind!r}; expected one of {sorted(FAULTS)}"}
        servo.fault(FAULTS[kind])
        return {"ok": True}
    if cmd == "state":
        return {"ok": True, "state": servo.snapshot(), "packets": state["packets"]}
    return {"ok": False, "error": f"unknown command {cmd!r}"}


def serve(
    mech: GripperMechanics,
    servo_id: int = 1,
    baudrate: int = 57600,
    check_baud: bool = True,
    extra_ids: tuple[int, ...] = (),
    overload_after_s: float = 2.0,
) -> None:
    """Run the emulator until stdin closes: print the pty path first, then answer the bus and the control
    channel (one JSON object per line on stdin -> one on stdout). `extra_ids`: more XM430s on the same bus
    (each driving an empty gripper), listed after the first."""
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo / line editing until the client configures the port itself
    code = {v: k for k, v in BAUD_CODES.items()}.get(baudrate)
    if code is None:
        raise SystemExit(f"baudrate {baudrate}: expected one of {sorted(BAUD_CODES.values())}")
    servos = []
    for i, sid in enumerate((servo_id, *extra_ids)):
        servo = Servo(mech=mech if i == 0 else GripperMechanics(), overload_after_s=overload_after_s)
        servo.set("id", sid)
        servo.set("baud_rate", code)
        servos.append(servo)
    servo = servos[0]
    bus = Bus(servos)
    parser = PacketParser()
    state = {"silent": False, "packets": 0}
    sys.stdout.write(json.dumps({"port": os.ttyname(slave), "pid": os.getpid()}) + "\n")
    sys.stdout.flush()

    sel = selectors.DefaultSelector()
    sel.register(master, selectors.EVENT_READ, "bus")
    sel.register(sys.stdin, selectors.EVENT_READ, "control")
    while True:
        for key, _ in sel.select():
            if key.data == "bus":
                try:
                    data = os.read(master, 4096)
                except OSError:
                    continue
                now = time.monotonic()
                for pkt in parser.feed(data):
                    state["packets"] += 1
                    if state["silent"]:
                        continue
                    wanted = BAUD_CODES[servo.get("baud_rate")]
                    if check_baud and _slave_baud(slave) not in (None, wanted):
                        continue  # at the wrong baud rate the servo only hears noise
                    reply = bus.handle(pkt, now)
                    if reply:
                        os.write(master, reply)
            else:
                line = sys.stdin.readline()
                if not line:  # parent gone: exit so no orphan keeps the pty
                    return
                try:
                    out = _control(bus, state, json.loads(line))
                except (ValueError, TypeError) as e:
                    out = {"ok": False, "error": str(e)}
                sys.stdout.write(json.dumps(out) + "\n")
                sys.stdout.flush()


# ==================================================================================================
# Parent side
# ==================================================================================================
class DynamixelEmulator(EmulatorProcess):
    name = "Dynamixel emulator"

    """Handle on an emulator process. Use as a context manager (or call :meth:`stop`) so it never outlives
    the test: ``with DynamixelEmulator(object_width=0.04) as emu: gripper = DynamixelGripper(emu.port, ...)``.
    """

    def __init__(
        self,
        servo_id: int = 1,
        baudrate: int = 57600,
        closed_ticks: int = 2048,
        open_ticks: int = 3072,
        max_opening: float = 0.085,
        object_width: float | None = None,
        extra_ids: tuple[int, ...] = (),
        overload_after_s: float = 2.0,
    ):
        """`extra_ids`: more servos on the bus (empty grippers); `overload_after_s`: seconds of saturated stall
        before the servo latches Overload."""
        self.args = [
            "--id", str(servo_id), "--baudrate", str(baudrate), "--closed-ticks", str(closed_ticks),
            "--open-ticks", str(open_ticks), "--max-opening", str(max_opening),
            "--overload-after", str(overload_after_s),
        ]  # fmt: skip
        if object_width is not None:
            self.args += ["--object-width", str(object_width)]
        if extra_ids:
            self.args += ["--extra-ids", ",".join(str(i) for i in extra_ids)]
        self.proc: subprocess.Popen | None = None
        self.port = ""
        self.pid = 0

    def start(self, timeout: float = 10.0) -> "DynamixelEmulator":
        hello = self._spawn([os.path.abspath(__file__), *self.args], timeout)
        if hello is None:
            raise RuntimeError("Dynamixel emulator exited at start")
        self.port, self.pid = hello["port"], hello["pid"]
        return self

    def set_object(self, width: float | None) -> None:
        """Put an object of `width` metres between the fingers (None: nothing)."""
        self._call(cmd="set", object_width=width)

    def set_voltage(self, volts: float) -> None:
        self._call(cmd="set", voltage=volts)

    def set_temperature(self, celsius: float) -> None:
        self._call(cmd="set", temperature=celsius)

    def set_silent(self, silent: bool) -> None:
        """Stop (or resume) answering on the bus, like a servo that lost power."""
        self._call(cmd="set", silent=silent)

    def set_overload_after(self, seconds: float) -> None:
        """Seconds of saturated stall before Overload latches."""
        self._call(cmd="set", overload_after_s=seconds)

    def inject_fault(self, kind: str, servo_id: int | None = None) -> None:
        """Latch a hardware error: overload, overheating, encoder, electrical_shock, input_voltage."""
        self._call(cmd="fault", kind=kind, id=servo_id)

    def state(self, servo_id: int | None = None) -> dict:
        """The control table by field name, plus the exact position and the object width (first servo unless
        `servo_id` names another on the bus)."""
        return self._call(cmd="state", id=servo_id)["state"]

    def packets_seen(self) -> int:
        return self._call(cmd="state")["packets"]


def main(argv: list[str] | None = None) -> None:
    import argparse

    p = argparse.ArgumentParser(description="Dynamixel XM430 (Protocol 2.0) emulator on a pseudo-terminal")
    p.add_argument("--id", type=int, default=1)
    p.add_argument("--baudrate", type=int, default=57600)
    p.add_argument("--closed-ticks", type=int, default=2048)
    p.add_argument("--open-ticks", type=int, default=3072)
    p.add_argument("--max-opening", type=float, default=0.085)
    p.add_argument("--object-width", type=float, default=None)
    p.add_argument("--no-baud-check", action="store_true")
    p.add_argument("--extra-ids", default="", help="comma-separated ids of more servos on the bus")
    p.add_argument("--overload-after", type=float, default=2.0, help="seconds of saturated stall before Overload")
    a = p.parse_args(argv)
    mech = GripperMechanics(a.closed_ticks, a.open_ticks, a.max_opening, a.object_width)
    extra = tuple(int(x) for x in a.extra_ids.split(",") if x.strip())
    try:
        serve(mech, a.id, a.baudrate, check_baud=not a.no_baud_check, extra_ids=extra,
              overload_after_s=a.overload_after)
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
