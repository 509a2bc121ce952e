"""RTDE protocol version 2 as the UR controller speaks it on TCP port 30004 (UR's "Real-Time Data Exchange
(RTDE) guide"): framing, the package types, and the controller's variable table with wire types.

A package is ``uint16 size (header included) | uint8 type | payload``, all big-endian. Data packages carry a
recipe id byte and then the recipe's fields packed by type. Written by hand: the client under test
(ur_rtde) is the only RTDE implementation at hand, and the emulator must not share its code.
"""

from __future__ import annotations

import struct

HEADER = struct.Struct(">HB")

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

FORMATS = {
    "DOUBLE": ">d",
    "UINT8": ">B",
    "BOOL": ">?",
    "UINT32": ">I",
    "INT32": ">i",
    "UINT64": ">Q",
    "VECTOR3D": ">3d",
    "VECTOR6D": ">6d",
    "VECTOR6INT32": ">6i",
    "VECTOR6UINT32": ">6I",
}

# Controller outputs (what a client may subscribe to) and their wire types, from the RTDE guide (PolyScope 5).
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    "target_q": "VECTOR6D",
    "target_qd": "VECTOR6D",
    "target_qdd": "VECTOR6D",
    "target_current": "VECTOR6D",
    "target_moment": "VECTOR6D",
    "actual_q": "VECTOR6D",
    "actual_qd": "VECTOR6D",
    "actual_current": "VECTOR6D",
    "joint_control_output": "VECTOR6D",
    "actual_TCP_pose": "VECTOR6D",
    "actual_TCP_speed": "VECTOR6D",
    "actual_TCP_force": "VECTOR6D",
    "target_TCP_pose": "VECTOR6D",
    "target_TCP_speed": "VECTOR6D",
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": "VECTOR6D",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": "VECTOR6D",
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "ft_raw_wrench": "VECTOR6D",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": "VECTOR6D",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
}
for _i in range(48):
    OUTPUT_TYPES[f"output_int_register_{_i}"] = "INT32"
    OUTPUT_TYPES[f"output_double_register_{_i}"] = "DOUBLE"
    OUTPUT_TYPES[f"input_int_register_{_i}"] = "INT32"  # inputs may be read back as outputs
    OUTPUT_TYPES[f"input_double_register_{_i}"] = "DOUBLE"

# Fields a client may write.
INPUT_TYPES: dict[str, str] = {"external_force_torque": "VECTOR6D", "speed_slider_mask": "UINT32",
                               "speed_slider_fraction": "DOUBLE"}
for _i in range(48):
    INPUT_TYPES[f"input_int_register_{_i}"] = "INT32"
    INPUT_TYPES[f"input_double_register_{_i}"] = "DOUBLE"

# Registers 0-23 of each kind are shared with the fieldbus adapters (EtherNet/IP, PROFINET): with one enabled
# the controller answers IN_USE for them; 24-47 stay free for RTDE.
FIELDBUS_REGISTERS = frozenset(
    [f"input_int_register_{i}" for i in range(24)] + [f"input_double_register_{i}" for i in range(24)]
)


def package(kind: int, payload: bytes = b"") -> bytes:
    return HEADER.pack(HEADER.size + len(payload), kind) + payload


class Deframer:
    """Splits a byte stream into (type, payload) packages."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        self.buf += data
        out = []
        while len(self.buf) >= HEADER.size:
            size, kind = HEADER.unpack_from(self.buf)
            if size < HEADER.size:
                raise ValueError(f"RTDE package size {size} < header size")
            if len(self.buf) < size:
                break
            out.append((kind, bytes(self.buf[HEADER.size:size])))
            del self.buf[:size]
        return out


def pack_fields(types: list[str], values: list) -> bytes:
    parts = []
    for t, v in zip(types, values):
        fmt = FORMATS[t]
        parts.append(struct.pack(fmt, *v) if fmt[1:2].isdigit() else struct.pack(fmt, v))
    return b"".join(parts)


def unpack_fields(types: list[str], data: bytes) -> list:
    out, off = [], 0
    for t in types:
        fmt = FORMATS[t]
        n = struct.calcsize(fmt)
        vals = struct.unpack_from(fmt, data, off)
        off += n
        out.append(list(vals) if len(vals) > 1 else vals[0])
    return out
