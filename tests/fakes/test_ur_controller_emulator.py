"""The UR controller emulator speaks RTDE, the dashboard protocol and the control script's register protocol
the way the real ur_rtde 1.6.5 clients expect (they are the clients here), and simulates honest motion."""

from __future__ import annotations

import socket
import struct
import time

import numpy as np
import pytest

from kitchenbot.fakes.ur_controller_emulator import URControllerEmulator

pytestmark = pytest.mark.timeout(120)
HOME = [0.0, -1.9, 1.9, -1.57, -1.57, 0.0]


class RawRTDE:
    """A minimal RTDE client on a socket, to look at the wire."""

    def __init__(self, host: str):
        self.s = socket.create_connection((host, 30004), timeout=5.0)

    def request(self, kind: str, payload: bytes = b"", expect: str | None = None) -> tuple[str, bytes]:
        if kind:
            self.s.sendall(struct.pack(">HB", 3 + len(payload), ord(kind)) + payload)
        while True:
            size, got = struct.unpack(">HB", self._read(3))
            body = self._read(size - 3)
            if expect is None or chr(got) == expect:
                return chr(got), body

    def _read(self, n: int) -> bytes:
        buf = b""
        while len(buf) < n:
            chunk = self.s.recv(n - len(buf))
            assert chunk, "connection closed"
            buf += chunk
        return buf


@pytest.fixture
def emu():
    with URControllerEmulator(q0=HOME) as e:
        yield e


def test_rtde_handshake_recipes_and_data_rate_on_the_wire(emu):
    c = RawRTDE(emu.host)
    assert c.request("V", struct.pack(">H", 2), "V")[1] == b"\x01"
    assert struct.unpack(">IIII", c.request("v", b"", "v")[1])[:3] == (5, 15, 0)
    _, body = c.request("O", struct.pack(">d", 125.0) + b"timestamp,actual_q,no_such_field", "O")
    assert body[1:].decode().split(",") == ["DOUBLE", "VECTOR6D", "NOT_FOUND"]
    _, body = c.request("O", struct.pack(">d", 125.0) + b"timestamp,actual_q,safety_status_bits", "O")
    assert body[0] == 1 and body[1:].decode() == "DOUBLE,VECTOR6D,UINT32"
    _, body = c.request("I", b"input_int_register_30,input_double_register_30", "I")
    assert body[0] == 1 and body[1:].decode() == "INT32,DOUBLE"
    assert c.request("S", b"", "S")[1] == b"\x01"
    stamps = []
    for _ in range(5):
        _, body = c.request("", b"", "U")
        ts, *q = struct.unpack(">d6d", body[1:57])
        stamps.append(ts)
        np.testing.assert_allclose(q, HOME)
        assert struct.unpack(">I", body[57:61])[0] == 1  # normal mode
    assert np.allclose(np.diff(stamps), 1 / 125.0)  # controller time: one package every 4 cycles
    c.s.sendall(struct.pack(">HB", 3 + 1 + 8, ord("U")) + b"\x01" + struct.pack(">i", 7) + struct.pack(">d", 0.5))
    emu.wait_for(lambda s: True)
    c.s.close()


def test_input_registers_held_by_a_fieldbus_are_in_use(emu):
    emu.set(fieldbus=True)
    c = RawRTDE(emu.host)
    c.request("V", struct.pack(">H", 2), "V")
    _, body = c.request("I", b"input_int_register_0,input_int_register_24", "I")
    assert body[1:].decode() == "IN_USE,INT32"
    import rtde_control

    with pytest.raises(RuntimeError, match="already in use.*EtherNet/IP"):
        rtde_control.RTDEControlInterface(emu.host, 500.0)


def test_dashboard_replies_as_polyscope_5(emu):
    import dashboard_client

    d = dashboard_client.DashboardClient(emu.host)
    d.connect(2000)
    assert d.polyscopeVersion().startswith("5.15.0")
    assert d.isInRemoteControl() is True
    assert d.getSerialNumber().isdigit()
    assert d.robotmode() == "Robotmode: RUNNING" and d.safetystatus() == "Safetystatus: NORMAL"
    emu.set(unlock_delay=600.0)
    emu.protective_stop()
    assert d.safetystatus() == "Safetystatus: PROTECTIVE_STOP"
    with pytest.raises(RuntimeError, match="Unlock protective stop failure: Cannot unlock protective stop until 5s"):
        d.unlockProtectiveStop()
    emu.set(unlock_delay=0.0)
    assert d.unlockProtectiveStop() is None  # the real client returns nothing on success
    assert d.safetystatus() == "Safetystatus: NORMAL"
    d.closeSafetyPopup()
    d.disconnect()


def test_polyscope_before_5_6_has_no_remote_control_or_serial():
    import dashboard_client

    with URControllerEmulator(polyscope="5.4.3") as emu:
        d = dashboard_client.DashboardClient(emu.host)
        d.connect(2000)
        assert d.isInRemoteControl() is False  # ur_rtde does not even ask
        with pytest.raises(RuntimeError, match="less than 5.6"):
            d.getSerialNumber()
        d.disconnect()


def test_control_script_registers_async_progress_and_honest_motion_time(emu):
    import rtde_control
    import rtde_receive

    r = rtde_receive.RTDEReceiveInterface(emu.host, 500.0)
    c = rtde_control.RTDEControlInterface(emu.host, 500.0)
    try:
        assert emu.state()["program_starts"] == 1 and c.isProgramRunning()
        emu.set(thread_start_delay=0.1)
        target = list(np.add(HOME, [0.3, 0, 0, 0, 0, 0]))
        assert c.moveJ(target, 1.0, 1.4, True)
        assert c.getAsyncOperationProgress() < 0  # accepted, not begun: the script starts it later
        deadline = time.monotonic() + 10.0
        while not c.getAsyncOperationProgressEx().isAsyncOperationRunning():
            assert time.monotonic() < deadline
            time.sleep(0.002)
        while c.getAsyncOperationProgressEx().isAsyncOperationRunning():
            assert time.monotonic() < deadline
            time.sleep(0.01)
        np.testing.assert_allclose(emu.state()["q"], target, atol=1e-9)
        log = emu.state()["log"]
        t_cmd = next(float(x.split()[0]) for x in log if x.endswith(" moveJ"))
        t_done = next(float(x.split()[0]) for x in log if x.endswith(" movej done"))
        # 0.3 rad at a = 1.4 rad/s^2 never reaches 1 rad/s: a triangle of 2 sqrt(d/a) s, after the start delay
        assert t_done - t_cmd == pytest.approx(0.1 + 2 * np.sqrt(0.3 / 1.4), abs=0.02)
        assert c.setTcp([0.0, 0.0, 0.15, 0.0, 0.0, 0.0]) and c.setPayload(1.2, [0.0, 0.0, 0.05])
        np.testing.assert_allclose(c.getTCPOffset(), [0.0, 0.0, 0.15, 0.0, 0.0, 0.0])
        assert r.getPayload() == pytest.approx(1.2, abs=1e-9) or emu.state()["payload"] == pytest.approx(1.2)
        assert c.reuploadScript()
        emu.wait_for(lambda s: s["program_starts"] == 2 and s["program_running"], what="second script")
        assert emu.state()["tcp"] == [0.0] * 6  # a new script runs with the installation's TCP
        with pytest.raises(ValueError):  # ur_rtde's own range check
            c.servoJ(HOME, 0.0, 0.0, 0.002, 0.5, 300.0)
    finally:
        c.stopScript()
        c.disconnect()
        r.disconnect()


def test_stalled_stream_gives_the_vendor_constructor_a_dead_interface(emu):
    import rtde_receive

    emu.set(stall_new=True)
    r = rtde_receive.RTDEReceiveInterface(emu.host, 500.0)  # returns after ur_rtde's 2.5 s read deadline
    assert not r.isConnected() and r.getTimestamp() == 0.0
    r.disconnect()


def test_silent_host_accepts_tcp_and_never_answers(emu):
    emu.set(silent=True)
    s = socket.create_connection((emu.host, 29999), timeout=2.0)
    s.settimeout(0.3)
    with pytest.raises(socket.timeout):
        s.recv(10)
    s.close()
