"""The controller process: RTDE server (30004), dashboard server (29999), script ports (30002/30003), a
500 Hz control loop, and a JSON-lines control channel on stdin/stdout for tests.

Everything the clients see is derived from one state (the robot, the running program, the registers) under
one lock; the control loop advances it in 2 ms cycles of controller time (`timestamp`), which follows the
wall clock as on a real controller. Faults on demand: protective / emergency stop, refused unlock, the control
script stopping, RTDE streams that stall (current ones, or new ones after the handshake), TCP accepted but
never answered, dropped connections, fieldbus adapters holding the lower registers, local control.
"""

from __future__ import annotations

import json
import re
import socket
import sys
import threading
import time

import numpy as np

from kitchenbot.drivers.ur_kinematics import ur_model

# The emulator process runs this file as a script, so `kitchenbot.fakes`' package __init__ (the whole simulator,
# seconds to import) stays out of it; imported as part of the package, the relative imports apply.
try:
    from . import protocol as P
    from . import robot as R
    from .script import ControlScript
except ImportError:
    import protocol as P  # type: ignore[no-redef]
    import robot as R  # type: ignore[no-redef]
    from script import ControlScript  # type: ignore[no-redef]

Brake, Robot, T_to_pose, ROBOT_MODES = R.Brake, R.Robot, R.T_to_pose, R.ROBOT_MODES
SAFETY_MODE_NORMAL, SAFETY_MODE_PROTECTIVE_STOP = R.SAFETY_MODE_NORMAL, R.SAFETY_MODE_PROTECTIVE_STOP
SAFETY_MODE_ROBOT_EMERGENCY_STOP = R.SAFETY_MODE_ROBOT_EMERGENCY_STOP

PERIOD = 0.002  # s, one control cycle (e-Series: 500 Hz)
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
PORTS = {"rtde": 30004, "dashboard": 29999, "secondary": 30002, "realtime": 30003}
UNLOCK_REFUSED = ("Cannot unlock protective stop until 5s after occurrence. Always inspect cause of protective "
                  "stop before unlocking")


class Conn:
    def __init__(self, kind: str, sock: socket.socket):
        self.kind, self.sock = kind, sock
        self.send_lock = threading.Lock()
        self.out = bytearray()
        self.closed = False
        # RTDE
        self.out_names: list[str] = []
        self.out_types: list[str] = []
        self.frequency = 0.0
        self.inputs: dict[int, tuple[list[str], list[str]]] = {}
        self.claimed: set[str] = set()
        self.started = False
        self.next_send = 0.0
        self.stalled = False
        self.packages = 0

    def send(self, data: bytes) -> None:
        with self.send_lock:
            if self.out:
                self.sock.sendall(bytes(self.out))
                self.out.clear()
            self.sock.sendall(data)

    def send_nowait(self, data: bytes) -> bool:
        """From the control loop: never blocks on a client that does not read; drops the package instead."""
        with self.send_lock:
            try:
                if self.out:
                    n = self.sock.send(bytes(self.out), socket.MSG_DONTWAIT)
                    del self.out[:n]
                    if self.out:
                        return False
                n = self.sock.send(data, socket.MSG_DONTWAIT)
            except BlockingIOError:
                return False
            except OSError:
                self.closed = True
                return False
            if n < len(data):
                self.out += data[n:]
            return True

    def close(self) -> None:
        self.closed = True
        self.claimed.clear()  # a closed connection holds no input registers
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()


class Controller:
    def __init__(self, host: str, model: str = "ur5e", q0=None, polyscope: str = "5.15.0",
                 installation_tcp=(0, 0, 0, 0, 0, 0), unlock_delay: float = 5.0, script_start_delay: float = 0.05,
                 serial: str = "20235500123"):
        self.host = host
        self.lock = threading.RLock()
        q0 = q0 if q0 is not None else [0.0, -1.9, 1.9, -1.57, -1.57, 0.0]
        self.robot = Robot(ur_model(model), q0, installation_tcp)
        self.model_name = model
        self.version = [int(x) for x in polyscope.split(".")] + [0] * (4 - len(polyscope.split(".")))
        self.version[3] = self.version[3] or 112233
        self.serial = serial
        self.unlock_delay = float(unlock_delay)
        self.script_start_delay = float(script_start_delay)
        self.cycles = 0
        self.regs: dict = {}
        self.script: ControlScript | None = None
        self.pending_program: tuple[float, int] | None = None  # (start time, register offset)
        self.program_starts = 0
        self.program_stops: list[str] = []
        self.conns: list[Conn] = []
        self.listeners: list[socket.socket] = []
        self.log_lines: list[tuple[float, str]] = []
        # faults
        self.stall_new = False
        self.silent = False
        self.refuse_unlock = False
        self.fieldbus = False
        self.remote_control = True
        self.thread_start_delay = 0.0  # s: a busy control script starts an async move this much later
        self.stopping = False

    @property
    def now(self) -> float:
        return self.cycles * PERIOD

    def log(self, what: str) -> None:
        self.log_lines.append((round(self.now, 3), what))
        del self.log_lines[:-500]

    # ---- the program ----------------------------------------------------------------------------------
    def load_program(self, text: str) -> None:
        with self.lock:
            if "def rtde_control():" not in text:
                self.log("program ignored (not the rtde_control script)")
                return
            m = re.search(r"# int register offset\n\s*(\d+)", text)
            offset = int(m.group(1)) if m else 0
            if self.script is not None:
                self.stop_program("replaced by a new program")
            self.pending_program = (self.now + self.script_start_delay, offset)
            self.log(f"program received (register offset {offset})")

    def _start_pending_program(self) -> None:
        t, offset = self.pending_program
        if self.now < t:
            return
        self.pending_program = None
        r = self.robot
        if r.mode != 7 or r.safety_mode != SAFETY_MODE_NORMAL or not self._remote_ok():
            why = "robot not running" if r.mode != 7 else "safety stop" if r.safety_mode != 1 else "local control"
            self.log(f"program not started: {why}")
            return
        r.reset_program_settings()
        self.script = ControlScript(self.regs, r, offset, self.log, lambda: self.now, self.thread_start_delay)
        self.program_starts += 1
        self.log("program started")

    def stop_program(self, why: str) -> None:
        if self.script is None:
            return
        self.script = None
        self.program_stops.append(why)
        self.log(f"program stopped: {why}")
        r = self.robot
        if r.motion is not None:
            if hasattr(r.motion, "brake"):
                r.motion.brake = r.motion.brake or 4.0
            else:
                r.motion = Brake(4.0)
        r.reset_program_settings()

    def _remote_ok(self) -> bool:
        return self.remote_control or not self._has_remote_control_mode()

    def _has_remote_control_mode(self) -> bool:
        return self.version[0] == 5 and self.version[1] >= 6

    # ---- safety ---------------------------------------------------------------------------------------
    def protective_stop(self, why: str = "protective stop") -> None:
        r = self.robot
        if r.safety_mode == SAFETY_MODE_PROTECTIVE_STOP:
            return
        r.safety_mode = SAFETY_MODE_PROTECTIVE_STOP
        r.protective_since = self.now
        self.log(f"protective stop: {why}")
        self.stop_program("protective stop")
        if r.motion is not None:
            r.motion = Brake(20.0)

    def emergency_stop(self, active: bool) -> None:
        r = self.robot
        if active:
            r.safety_mode = SAFETY_MODE_ROBOT_EMERGENCY_STOP
            self.stop_program("emergency stop")
            r.motion = Brake(40.0) if r.motion is not None else None
        elif r.safety_mode == SAFETY_MODE_ROBOT_EMERGENCY_STOP:
            r.safety_mode = SAFETY_MODE_NORMAL
            r.mode = 5  # IDLE: brakes engaged until "brake release"

    def safety_bits(self) -> int:
        m = self.robot.safety_mode
        if m == SAFETY_MODE_NORMAL:
            return 1 << R.BIT_NORMAL_MODE
        if m == SAFETY_MODE_PROTECTIVE_STOP:
            return (1 << R.BIT_PROTECTIVE_STOPPED) | (1 << R.BIT_STOPPED_DUE_TO_SAFETY)
        return (1 << R.BIT_ROBOT_EMERGENCY_STOPPED) | (1 << R.BIT_EMERGENCY_STOPPED) | (1 << R.BIT_STOPPED_DUE_TO_SAFETY)

    # ---- the control loop -----------------------------------------------------------------------------
    def cycle(self) -> None:
        self.cycles += 1
        r = self.robot
        r.step(PERIOD)
        while r.finished:
            self.log(f"{r.finished.pop(0)} done")
        if r.last_failure:
            why, r.last_failure = r.last_failure, None
            self.protective_stop(why)
        if self.script is not None:
            self.script.cycle()
            if self.script is not None and self.script.request_protective_stop:
                self.protective_stop("triggered by the program")
            elif self.script is not None and not self.script.keep_running:
                self.stop_program("stop script command")
        if self.pending_program is not None:
            self._start_pending_program()

    def run(self) -> None:
        next_t = time.monotonic()
        while not self.stopping:
            now = time.monotonic()
            if now < next_t:
                time.sleep(next_t - now)
                continue
            n = min(int((now - next_t) / PERIOD) + 1, 50)
            with self.lock:
                for _ in range(n):
                    self.cycle()
                    self.publish()
            next_t += n * PERIOD
            if now - next_t > 0.1:  # starved for long: do not replay the backlog
                next_t = now

    # ---- RTDE outputs ---------------------------------------------------------------------------------
    def values(self) -> dict:
        r = self.robot
        tcp = T_to_pose(r.tcp_T())
        running = self.script is not None
        v = {
            "timestamp": self.now,
            "actual_q": r.q.tolist(), "target_q": r.q.tolist(),
            "actual_qd": r.qd.tolist(), "target_qd": r.qd.tolist(),
            "actual_TCP_pose": tcp, "target_TCP_pose": tcp,
            "actual_TCP_force": r.tcp_force(), "ft_raw_wrench": r.tcp_force(),
            "robot_mode": r.mode, "safety_mode": r.safety_mode, "safety_status": r.safety_mode,
            "joint_mode": [253] * 6,
            "runtime_state": RUNTIME_PLAYING if running else RUNTIME_STOPPED,
            "robot_status_bits": (1 if r.mode != 3 else 0) | (2 if running else 0),
            "safety_status_bits": self.safety_bits(),
            "speed_scaling": 1.0, "target_speed_fraction": 1.0,
            "payload": r.payload, "payload_cog": list(r.payload_cog),
            "actual_main_voltage": 48.0, "actual_robot_voltage": 48.0,
            "joint_temperatures": [32.0] * 6,
        }
        return v

    def _field(self, v: dict, name: str, typ: str):
        if name in v:
            return v[name]
        if name in self.regs:
            return self.regs[name]
        fmt = P.FORMATS[typ]
        n = int(fmt[1]) if fmt[1:2].isdigit() else 1
        zero = 0.0 if fmt[-1] == "d" else 0
        return [zero] * n if n > 1 else zero

    def publish(self) -> None:
        v = None
        t = self.now
        for c in list(self.conns):
            if c.closed:
                self._forget(c)
                continue
            if c.kind != "rtde" or not c.started or c.stalled or t + 1e-9 < c.next_send:
                continue
            # every 500/f cycles of controller time, counted from the first package
            c.next_send = (c.next_send if t - c.next_send < PERIOD / 2 else t) + 1.0 / c.frequency
            if v is None:
                v = self.values()
            body = P.pack_fields(c.out_types, [self._field(v, n, ty) for n, ty in zip(c.out_names, c.out_types)])
            if c.send_nowait(P.package(P.DATA_PACKAGE, b"\x01" + body)):
                c.packages += 1

    def _forget(self, c: Conn) -> None:
        if c in self.conns:
            self.conns.remove(c)

    # ---- RTDE server ----------------------------------------------------------------------------------
    def rtde_package(self, c: Conn, kind: int, payload: bytes) -> bytes | None:
        if kind == P.REQUEST_PROTOCOL_VERSION:
            (version,) = np.frombuffer(payload[:2], dtype=">u2")
            return P.package(kind, bytes([1 if version in (1, 2) else 0]))
        if kind == P.GET_URCONTROL_VERSION:
            return P.package(kind, b"".join(int(x).to_bytes(4, "big") for x in self.version))
        if kind == P.SETUP_OUTPUTS:
            freq = float(np.frombuffer(payload[:8], dtype=">f8")[0])
            names = [n for n in payload[8:].decode().split(",") if n]
            types = [P.OUTPUT_TYPES.get(n, "NOT_FOUND") for n in names]
            if not 0 < freq <= 500 or "NOT_FOUND" in types:
                return P.package(kind, b"\x00" + ",".join(types).encode())
            c.out_names, c.out_types, c.frequency = names, types, freq
            return P.package(kind, b"\x01" + ",".join(types).encode())
        if kind == P.SETUP_INPUTS:
            names = [n for n in payload.decode().split(",") if n]
            busy = set(P.FIELDBUS_REGISTERS) if self.fieldbus else set()
            for other in self.conns:
                if other is not c and not other.closed:
                    busy |= other.claimed
            types = []
            for n in names:
                t = P.INPUT_TYPES.get(n, "NOT_FOUND")
                types.append("IN_USE" if t != "NOT_FOUND" and n in busy else t)
            if "IN_USE" in types or "NOT_FOUND" in types:
                return P.package(kind, b"\x00" + ",".join(types).encode())
            rid = len(c.inputs) + 1
            c.inputs[rid] = (names, types)
            c.claimed |= set(names)
            return P.package(kind, bytes([rid]) + ",".join(types).encode())
        if kind == P.START:
            ok = bool(c.out_names)
            c.started = ok
            c.next_send = self.now
            c.stalled = self.stall_new and not c.inputs  # stall_new: new receive clients (no input recipes)
            return P.package(kind, bytes([1 if ok else 0]))
        if kind == P.PAUSE:
            c.started = False
            return P.package(kind, b"\x01")
        if kind == P.DATA_PACKAGE and payload:
            recipe = c.inputs.get(payload[0])
            if recipe is not None:
                names, types = recipe
                for n, val in zip(names, P.unpack_fields(types, payload[1:])):
                    self.regs[n] = val
            return None
        return None

    # ---- dashboard ------------------------------------------------------------------------------------
    def dashboard(self, line: str) -> str:
        cmd = line.strip()
        low = cmd.lower()
        r = self.robot
        self.log(f"dashboard: {low}")
        ps56 = self._has_remote_control_mode()
        if low == "robotmode":
            return f"Robotmode: {ROBOT_MODES.get(r.mode, 'RUNNING')}"
        if low in ("safetystatus", "safetymode"):
            name = {1: "NORMAL", 3: "PROTECTIVE_STOP", 7: "ROBOT_EMERGENCY_STOP"}[r.safety_mode]
            return f"{'Safetystatus' if low == 'safetystatus' else 'Safetymode'}: {name}"
        if low == "unlock protective stop":
            if r.safety_mode == SAFETY_MODE_PROTECTIVE_STOP:
                if self.refuse_unlock or self.now - (r.protective_since or 0.0) < self.unlock_delay:
                    return UNLOCK_REFUSED
                r.safety_mode = SAFETY_MODE_NORMAL
                self.log("protective stop unlocked")
            return "Protective stop releasing"
        if low == "close safety popup":
            return "closing safety popup"
        if low == "close popup":
            return "closing popup"
        if low == "power on":
            r.mode = 5 if r.mode == 3 else r.mode
            return "Powering on"
        if low == "power off":
            self.stop_program("power off")
            r.mode = 3
            return "Powering off"
        if low == "brake release":
            r.mode = 7 if r.mode == 5 else r.mode
            return "Brake releasing"
        if low == "polyscopeversion":
            return "URSoftware {}.{}.{}.{} (Mar 05 2024)".format(*self.version)
        if low == "is in remote control" and ps56:
            return "true" if self.remote_control else "false"
        if low == "get serial number" and ps56:
            return self.serial
        if low == "get robot model":
            return {"ur3e": "UR3", "ur5e": "UR5", "ur10e": "UR10"}.get(self.model_name, "UR5")
        if low == "programstate":
            return "PLAYING <unnamed>" if self.script is not None else "STOPPED <unnamed>"
        if low == "running":
            return f"Program running: {'true' if self.script is not None else 'false'}"
        if low == "stop":
            self.stop_program("dashboard stop")
            return "Stopped"
        if low == "restart safety":
            r.safety_mode = SAFETY_MODE_NORMAL
            r.mode = 3
            return "Restarting safety"
        if low == "get loaded program":
            return "No program loaded"
        if low == "quit":
            return "Disconnected"
        return f"could not understand: '{cmd}'"

    # ---- control channel ------------------------------------------------------------------------------
    def control(self, msg: dict) -> dict:
        cmd = msg.get("cmd")
        r = self.robot
        if cmd == "state":
            return {"ok": True, "state": {
                "time": self.now, "q": r.q.tolist(), "qd": r.qd.tolist(), "moving": r.motion is not None,
                "motion": getattr(r.motion, "kind", None), "tcp": T_to_pose(r.tcp),
                "tcp_pose": T_to_pose(r.tcp_T()), "payload": r.payload, "payload_cog": list(r.payload_cog),
                "program_running": self.script is not None, "program_starts": self.program_starts,
                "program_stops": list(self.program_stops), "safety_mode": r.safety_mode, "robot_mode": r.mode,
                "safety_status_bits": self.safety_bits(),
                "connections": {k: sum(1 for c in self.conns if c.kind == k and not c.closed)
                                for k in ("rtde", "dashboard", "script")},
                "rtde_streams": [{"frequency": c.frequency, "packages": c.packages, "stalled": c.stalled,
                                  "inputs": len(c.inputs)} for c in self.conns if c.kind == "rtde" and c.started],
                "log": [f"{t:.3f} {w}" for t, w in self.log_lines],
            }}
        if cmd == "fault":
            kind = msg.get("kind")
            if kind == "protective_stop":
                self.protective_stop("injected")
            elif kind == "emergency_stop":
                self.emergency_stop(bool(msg.get("active", True)))
            elif kind == "stop_script":
                self.stop_program("script stopped (injected)")
            elif kind == "stall":
                which = msg.get("which", "rtde_receive")
                for c in self.conns:
                    role = "rtde_control" if c.inputs else "rtde_receive"
                    if c.kind == "rtde" and c.started and which in ("rtde", role):
                        c.stalled = bool(msg.get("active", True))
            elif kind == "disconnect":
                which = msg.get("which", "all")
                for c in list(self.conns):
                    role = c.kind if c.kind != "rtde" else ("rtde_control" if c.inputs else "rtde_receive")
                    if which in ("all", c.kind, role):
                        c.close()
                        self._forget(c)
            else:
                return {"ok": False, "error": f"unknown fault {kind!r}"}
            return {"ok": True}
        if cmd == "set":
            for key in ("stall_new", "silent", "refuse_unlock", "fieldbus", "remote_control"):
                if key in msg:
                    setattr(self, key, bool(msg[key]))
            if "unlock_delay" in msg:
                self.unlock_delay = float(msg["unlock_delay"])
            if "thread_start_delay" in msg:
                self.thread_start_delay = float(msg["thread_start_delay"])
                if self.script is not None:
                    self.script.thread_start_delay = self.thread_start_delay
            if "contact_z" in msg:
                r.contact_z = None if msg["contact_z"] is None else float(msg["contact_z"])
            if "q" in msg:
                if r.motion is not None:
                    return {"ok": False, "error": "set q: the robot is moving"}
                r.q = np.asarray(msg["q"], float)
            return {"ok": True}
        return {"ok": False, "error": f"unknown command {cmd!r}"}

    # ---- sockets --------------------------------------------------------------------------------------
    def listen(self) -> None:
        for kind, port in PORTS.items():
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((self.host, port))  # raises OSError when taken: the parent picks another address
            s.listen(16)
            self.listeners.append(s)
            threading.Thread(target=self._accept, args=(s, kind), daemon=True).start()

    def _accept(self, s: socket.socket, kind: str) -> None:
        while not self.stopping:
            try:
                sock, _ = s.accept()
            except OSError:
                return
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            kind2 = "script" if kind in ("secondary", "realtime") else kind
            c = Conn(kind2, sock)
            with self.lock:
                self.conns.append(c)
                silent = self.silent
            target = self._silent if silent else {"rtde": self._serve_rtde, "dashboard": self._serve_dashboard,
                                                  "script": self._serve_script}[kind2]
            threading.Thread(target=target, args=(c,), daemon=True).start()

    def _recv(self, c: Conn) -> bytes:
        try:
            data = c.sock.recv(65536)
        except OSError:
            data = b""
        if not data:
            with self.lock:
                c.closed = True
                c.claimed.clear()
                self._forget(c)
            try:
                c.sock.close()
            except OSError:
                pass
        return data

    def _silent(self, c: Conn) -> None:
        while self._recv(c):
            pass

    def _serve_rtde(self, c: Conn) -> None:
        deframer = P.Deframer()
        while True:
            data = self._recv(c)
            if not data:
                return
            for kind, payload in deframer.feed(data):
                with self.lock:
                    reply = self.rtde_package(c, kind, payload)
                if reply is not None:
                    try:
                        c.send(reply)
                    except OSError:
                        return

    def _serve_dashboard(self, c: Conn) -> None:
        try:
            c.send(b"Connected: Universal Robots Dashboard Server\n")
        except OSError:
            return
        buf = b""
        while True:
            data = self._recv(c)
            if not data:
                return
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                with self.lock:
                    reply = self.dashboard(line.decode(errors="replace"))
                try:
                    c.send(reply.encode() + b"\n")
                except OSError:
                    return
                if reply == "Disconnected":
                    c.close()
                    return

    def _serve_script(self, c: Conn) -> None:
        text = ""
        while True:
            data = self._recv(c)
            if not data:
                return
            text += data.decode(errors="replace")
            # a program is complete at its top-level "end" (column 0) after a top-level "def"
            while True:
                m = re.search(r"^def [^\n]*\n.*?^end[ \t]*(\n|$)", text, re.DOTALL | re.MULTILINE)
                if not m:
                    break
                self.load_program(m.group(0))
                text = text[m.end():]


def main(argv: list[str] | None = None) -> None:
    import argparse

    p = argparse.ArgumentParser(description="UR e-Series controller emulator (RTDE, dashboard, script ports)")
    p.add_argument("--host", required=True)
    p.add_argument("--model", default="ur5e")
    p.add_argument("--polyscope", default="5.15.0")
    p.add_argument("--q0", default=None, help="JSON list of 6 joint positions")
    p.add_argument("--tcp", default="[0,0,0,0,0,0]", help="installation TCP, JSON [x,y,z,rx,ry,rz]")
    p.add_argument("--unlock-delay", type=float, default=5.0)
    a = p.parse_args(argv)
    import faulthandler
    import signal

    faulthandler.register(signal.SIGUSR1)  # `kill -USR1 <pid>` prints every thread's stack to stderr
    ctl = Controller(a.host, a.model, json.loads(a.q0) if a.q0 else None, a.polyscope, json.loads(a.tcp),
                     a.unlock_delay)
    try:
        ctl.listen()
    except OSError as e:
        sys.stdout.write(json.dumps({"ok": False, "error": f"bind {a.host}: {e}"}) + "\n")
        sys.stdout.flush()
        return
    threading.Thread(target=ctl.run, daemon=True).start()
    sys.stdout.write(json.dumps({"ok": True, "host": a.host}) + "\n")
    sys.stdout.flush()
    for line in sys.stdin:
        try:
            with ctl.lock:
                out = ctl.control(json.loads(line))
        except (ValueError, TypeError, KeyError) as e:
            out = {"ok": False, "error": str(e)}
        sys.stdout.write(json.dumps(out) + "\n")
        sys.stdout.flush()
    ctl.stopping = True  # stdin closed: the parent is gone


if __name__ == "__main__":
    main()
