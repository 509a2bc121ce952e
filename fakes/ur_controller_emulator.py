"""A UR e-Series controller at protocol level, in its own process, for the real ur_rtde clients.

``RTDEReceiveInterface``, ``RTDEControlInterface`` and ``DashboardClient`` connect to it as to a robot: the
RTDE protocol on 30004 (protocol version, controller version, output/input recipes, start/pause, data
packages at the requested rate, input registers), the dashboard server on 29999 with PolyScope 5 replies, and
the script ports 30002/30003 that take the control script; behind them the control script's register protocol
(fakes/ur_controller/script.py) and a kinematic arm (fakes/ur_controller/robot.py). See
fakes/ur_controller/controller.py for the faults it can inject.

ur_rtde fixes the ports, so each emulator gets its own loopback address (127.x.y.z; Linux routes all of
127/8 to lo). It runs in its own process because ur_rtde's constructors hold the GIL while they wait for the
controller. Control it over a JSON-lines channel::

    with URControllerEmulator() as emu:                      # emu.host is e.g. "127.31.7.200"
        r = rtde_receive.RTDEReceiveInterface(emu.host, 500.0)
        emu.protective_stop(); emu.set(refuse_unlock=True); emu.stall(); emu.set(stall_new=True)
        emu.set(silent=True); emu.disconnect("rtde"); emu.stop_script(); emu.state()
"""

from __future__ import annotations

import json
import os
import random
import subprocess
import time

from kitchenbot.fakes.emulator_process import EmulatorProcess

# Run by path, not with -m: importing the package would import `kitchenbot.fakes` (the whole simulator).
CONTROLLER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "ur_controller", "controller.py")


class URControllerEmulator(EmulatorProcess):
    name = "UR controller emulator"

    def __init__(self, *, model: str = "ur5e", polyscope: str = "5.15.0", q0=None,
                 installation_tcp=(0, 0, 0, 0, 0, 0), unlock_delay: float = 0.0, host: str | None = None):
        """`unlock_delay`: seconds after a protective stop before the dashboard accepts an unlock (the real
        controller: 5 s; 0 here by default so tests need not wait; the refusal itself is a fault to set)."""
        self.args = ["--model", model, "--polyscope", polyscope, "--tcp", json.dumps(list(installation_tcp)),
                     "--unlock-delay", str(unlock_delay)]
        if q0 is not None:
            self.args += ["--q0", json.dumps([float(x) for x in q0])]
        self.fixed_host = host
        self.host = ""
        self.proc: subprocess.Popen | None = None

    @staticmethod
    def _random_host() -> str:
        return f"127.{random.randint(2, 254)}.{random.randint(1, 254)}.{random.randint(2, 254)}"

    def start(self, timeout: float = 20.0) -> URControllerEmulator:
        hello: dict = {}
        for _ in range(5):
            host = self.fixed_host or self._random_host()
            hello = self._spawn([CONTROLLER, "--host", host, *self.args], timeout) or {"ok": False,
                                                                                      "error": "exited at start"}
            if hello.get("ok"):
                self.host = host
                return self
            self.stop()
            if self.fixed_host:
                break
        raise RuntimeError(f"UR controller emulator: {hello.get('error')}")

    # ---- state and settings ----------------------------------------------------------------------------
    def state(self) -> dict:
        """Joints, active TCP/payload, program, safety, connections, RTDE streams, and the event log."""
        return self._call(cmd="state")["state"]

    def set(self, **kw) -> None:
        """stall_new (new RTDE receive streams handshake but send no data), silent (new TCP connections on every port
        are accepted and never answered), refuse_unlock, fieldbus (EtherNet/IP/PROFINET holds input registers
        0-23), remote_control, unlock_delay, thread_start_delay (a busy control script begins an async move
        this many seconds after accepting it; by default it begins in the next 2 ms cycle), contact_z (a surface at this base-frame height), q (teleport)."""
        self._call(cmd="set", **kw)

    def wait_for(self, predicate, timeout: float = 10.0, what: str = "condition") -> dict:
        """Poll the state until `predicate(state)` holds (an event, not a fixed sleep); raises on timeout."""
        deadline = time.monotonic() + timeout
        while True:
            s = self.state()
            if predicate(s):
                return s
            if time.monotonic() > deadline:
                raise TimeoutError(f"UR controller emulator: {what} not reached within {timeout} s; state {s}")
            time.sleep(0.01)

    # ---- faults ---------------------------------------------------------------------------------------
    def protective_stop(self) -> None:
        self._call(cmd="fault", kind="protective_stop")

    def emergency_stop(self, active: bool = True) -> None:
        self._call(cmd="fault", kind="emergency_stop", active=active)

    def stop_script(self) -> None:
        """The control script stops (as after a runtime error): runtime_state STOPPED, TCP/payload revert."""
        self._call(cmd="fault", kind="stop_script")

    def stall(self, active: bool = True, which: str = "rtde_receive") -> None:
        """The RTDE streams open now stop (or resume) sending data packages; the TCP links stay up. `which`:
        rtde_receive (clients without input recipes, the default), rtde_control, or rtde (both). A stalled
        control stream sends ur_rtde's control interface into its reconnect loop (see drivers/ur_rtde_arm.py)."""
        self._call(cmd="fault", kind="stall", active=active, which=which)

    def disconnect(self, which: str = "all") -> None:
        """Close the current connections: all, rtde, rtde_receive (RTDE clients without input recipes),
        rtde_control (with input recipes), dashboard or script."""
        self._call(cmd="fault", kind="disconnect", which=which)


if __name__ == "__main__":  # pragma: no cover - manual use: run one and print its address
    with URControllerEmulator() as emu:
        print(emu.host, flush=True)
        try:
            while True:
                time.sleep(1)
        except KeyboardInterrupt:
            pass
    os._exit(0)
