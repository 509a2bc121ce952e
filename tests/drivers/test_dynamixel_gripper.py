"""DynamixelGripper against the Protocol 2.0 emulator on a pseudo-terminal: the real dynamixel-sdk and pyserial
talk to another process byte for byte (no mocks of the SDK)."""

from __future__ import annotations

import time

import pytest
from dynamixel_sdk import PacketHandler, PortHandler

from kitchenbot.drivers.dynamixel_gripper import DynamixelGripper, DxlPortHandler, decode_hardware_error
from kitchenbot.drivers.errors import DeviceNotConnectedError, DriverError, DriverTimeoutError, HardwareError
from kitchenbot.fakes.dynamixel_emulator import DynamixelEmulator, crc16, frame, unstuff

pytestmark = pytest.mark.timeout(60)


def _port(emu) -> PortHandler:
    """The SDK's PortHandler with a 100 ms timeout floor: the emulator is a Python process on a loaded CI host."""
    return DxlPortHandler(emu.port, 100.0)


@pytest.fixture
def emu():
    e = DynamixelEmulator().start()
    try:
        yield e
    finally:
        e.stop()


@pytest.fixture
def gripper(emu):
    # 100 ms packet-timeout floor: the emulator is a Python process on a shared, loaded CI machine.
    g = DynamixelGripper(emu.port, 57600, 1, min_packet_timeout_ms=100)
    g.connect()
    try:
        yield g
    finally:
        g.disconnect()


# ---- protocol ------------------------------------------------------------------------------------------
def test_crc_and_stuffing_match_the_sdk_byte_for_byte():
    ph = PacketHandler(2.0)
    # Parameters containing FF FF FD: an FD is stuffed after them, the length grows by one.
    params = [0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x01]
    unstuffed = [0xFF, 0xFF, 0xFD, 0x00, 1, len(params) + 3, 0, 0x03] + params + [0, 0]
    sdk_stuffed = bytes(ph.addStuffing(list(unstuffed)))
    ours = frame(1, 0x03, bytes(params))
    assert ours[:-2] == sdk_stuffed[:-2]
    assert ours[7:-2].count(b"\xff\xff\xfd\xfd") == 1
    assert unstuff(ours[7:-2]) == bytes([0x03] + params)
    assert crc16(ours[:-2]) == ph.updateCRC(0, list(ours), len(ours) - 2) == int.from_bytes(ours[-2:], "little")
    # A stuffed status packet from the emulator is parsed back by the SDK's receiver.
    status = frame(1, 0x55, bytes([0x00, 0xFF, 0xFF, 0xFD, 0x07]))
    rx, result = ph.rxPacket(_Wire(status), False)
    assert result == 0 and rx[8:13] == [0x00, 0xFF, 0xFF, 0xFD, 0x07]


class _Wire:
    """A port for PacketHandler.rxPacket that yields fixed bytes (only for checking the framing)."""

    is_using = False

    def __init__(self, data: bytes):
        self.data = bytearray(data)

    def readPort(self, n):
        out, self.data = bytes(self.data[:n]), self.data[n:]
        return out

    def isPacketTimeout(self):
        return not self.data


def test_ping_reports_the_xm430_model_number(emu):
    port = _port(emu)
    assert port.openPort() and port.setBaudRate(57600)
    ph = PacketHandler(2.0)
    try:
        model, result, error = ph.ping(port, 1)
        assert (model, result, error) == (1020, 0, 0)
        assert ph.ping(port, 7)[1] == -3001  # nobody with id 7: timeout
        # A stuffed packet (parameters FF FF FD) is parsed, not rejected as a CRC error: address 0xFFFF
        # does not exist, so the answer is an access error (7).
        result, error = ph.writeTxRx(port, 1, 0xFFFF, 1, [0xFD])
        assert (result, error) == (0, 7)
        # At the wrong baud rate the servo hears only noise.
        port.setBaudRate(115200)
        assert ph.ping(port, 1)[1] == -3001
    finally:
        port.closePort()


def test_eeprom_write_refused_while_torque_is_on(emu):
    port = _port(emu)
    assert port.openPort() and port.setBaudRate(57600)
    ph = PacketHandler(2.0)
    try:
        assert ph.write1ByteTxRx(port, 1, 64, 1) == (0, 0)
        assert ph.write1ByteTxRx(port, 1, 11, 5) == (0, 7)  # access error
        assert emu.state()["operating_mode"] == 3
        assert ph.write1ByteTxRx(port, 1, 64, 0) == (0, 0)
        assert ph.write1ByteTxRx(port, 1, 11, 5) == (0, 0)
        assert emu.state()["operating_mode"] == 5
        assert ph.write1ByteTxRx(port, 1, 132, 0)[1] == 7  # Present Position is read-only
        assert ph.write1ByteTxRx(port, 1, 11, 99)[1] == 4  # out of range
    finally:
        port.closePort()


# ---- driver ----------------------------------------------------------------------------------------
def test_connect_configures_current_based_position_mode(emu, gripper):
    s = emu.state()
    assert s["operating_mode"] == 5
    assert s["current_limit"] == gripper.current_limit_units == round(0.6 / 0.00269)
    assert s["torque_enable"] == 1
    assert gripper.describe()["model"] == "XM430-W350"


def test_grasp_detects_an_object_and_reports_its_width(emu, gripper):
    gripper.open()
    assert gripper.opening() == pytest.approx(0.085, abs=0.002)
    emu.set_object(0.040)
    result = gripper.grasp(current_limit=0.5)
    assert result.holding
    assert result.opening == pytest.approx(0.040, abs=0.003)  # Fin-Ray deflection is a few ticks
    assert result.current == pytest.approx(0.5, rel=0.15)
    st = gripper.status()
    assert st.holding and st.error is None and not st.moving
    assert abs(emu.state()["goal_current"]) == round(0.5 / 0.00269)  # the limit really reached the servo
    assert st.temperature_c is not None and st.voltage_v == pytest.approx(12.0)


def test_fully_closed_without_object_is_not_holding(emu, gripper):
    gripper.open()
    result = gripper.grasp(current_limit=0.5)
    assert not result.holding
    assert result.opening < 0.004
    assert not gripper.is_holding()


def test_grasp_current_limit_is_validated(gripper):
    with pytest.raises(ValueError, match="current_limit"):
        gripper.grasp(current_limit=10.0)


def test_open_to_a_given_width(emu, gripper):
    gripper.open(0.05)
    assert gripper.opening() == pytest.approx(0.05, abs=0.0025)
    with pytest.raises(ValueError, match="opening"):
        gripper.open(0.2)


def test_overload_shuts_down_and_reboot_clears_it(emu, gripper):
    gripper.open()
    emu.inject_fault("overload")
    st = gripper.status()
    assert st.error == "overload"
    assert emu.state()["torque_enable"] == 0
    with pytest.raises(HardwareError, match="overload"):
        gripper.grasp(current_limit=0.5)
    gripper.reboot()
    assert gripper.error() is None
    assert emu.state()["torque_enable"] == 0  # reboot leaves torque off ...
    gripper.open(0.06)  # ... and open() turns it back on
    assert emu.state()["torque_enable"] == 1


def test_hardware_error_text_decoding():
    assert decode_hardware_error(0) is None
    assert decode_hardware_error(0x24) == "overheating, overload"
    assert "unknown bits 0x02" in decode_hardware_error(0x02)


def test_hot_servo_refuses_to_grasp(emu, gripper):
    emu.set_temperature(74.0)
    with pytest.raises(HardwareError, match="74 degC"):
        gripper.grasp(current_limit=0.5)


def test_silent_servo_times_out_after_retries(emu, gripper):
    emu.set_silent(True)
    t0 = time.monotonic()
    with pytest.raises(DriverTimeoutError, match=r"no valid answer .* after 3 tries"):
        gripper.status()
    assert 0.3 <= time.monotonic() - t0 < 5.0  # 3 tries x 100 ms (upper bound loose: a loaded CI host)
    emu.set_silent(False)
    assert gripper.status().error is None  # recovers once the servo answers again


def test_stopped_emulator_gives_a_driver_error_not_a_hang(emu, gripper):
    emu.stop()
    t0 = time.monotonic()
    with pytest.raises(DriverError) as exc:
        gripper.status()
    assert isinstance(exc.value, (DriverTimeoutError, DeviceNotConnectedError))
    assert time.monotonic() - t0 < 5.0  # no hang (loose bound: a loaded CI host)


def test_connect_to_a_silent_bus_names_port_id_and_baud(emu):
    emu.set_silent(True)
    g = DynamixelGripper(emu.port, 57600, servo_id=3)
    with pytest.raises(DeviceNotConnectedError, match=rf"id 3 answers on {emu.port} at 57600 baud"):
        g.connect()
    assert not g.is_connected


def test_missing_serial_port_names_the_port():
    g = DynamixelGripper("/dev/ttyUSB_kitchenbot_absent", 57600, 1)
    with pytest.raises(DeviceNotConnectedError, match="/dev/ttyUSB_kitchenbot_absent does not exist"):
        g.connect()


def test_commands_before_connect_raise():
    g = DynamixelGripper("/dev/null", 57600, 1)
    with pytest.raises(DeviceNotConnectedError, match="not connected"):
        g.status()


def test_calibration_is_linear_both_ways():
    g = DynamixelGripper(closed_ticks=3000, open_ticks=2000, max_opening=0.1)
    assert g.ticks_to_opening(3000) == 0.0
    assert g.ticks_to_opening(2000) == pytest.approx(0.1)
    assert g.opening_to_ticks(0.05) == 2500
    with pytest.raises(ValueError, match="differ"):
        DynamixelGripper(closed_ticks=5, open_ticks=5)


def test_reversed_calibration_grasps_too():
    with DynamixelEmulator(closed_ticks=3000, open_ticks=2000, max_opening=0.1, object_width=0.03) as emu:
        g = DynamixelGripper(emu.port, closed_ticks=3000, open_ticks=2000, max_opening=0.1, min_packet_timeout_ms=100)
        g.connect()
        try:
            g.open()
            r = g.grasp(current_limit=0.4)
            assert r.holding and r.opening == pytest.approx(0.03, abs=0.003)
            assert r.current > 0  # + closing, whatever the servo's direction
        finally:
            g.disconnect()


def test_low_voltage_is_an_alarm_not_a_shutdown(emu, gripper):
    gripper.open()
    emu.set_voltage(8.0)  # below Min Voltage Limit (9.5 V)
    st = gripper.status()
    assert st.voltage_v == pytest.approx(8.0)
    assert st.error == "input voltage out of range"
    emu.set_object(0.03)
    assert gripper.grasp(current_limit=0.4).holding  # the servo keeps working under this alarm
    assert gripper.status().holding


def test_sync_and_bulk_instructions(emu):
    from dynamixel_sdk import GroupBulkRead, GroupSyncRead, GroupSyncWrite

    port = _port(emu)
    assert port.openPort() and port.setBaudRate(57600)
    ph = PacketHandler(2.0)
    try:
        sw = GroupSyncWrite(port, ph, 102, 2)  # Goal Current
        assert sw.addParam(1, [0x2C, 0x01])  # 300
        assert sw.txPacket() == 0
        # Sync Write has no status packet: the SDK returns once the bytes are sent, before the emulator (another
        # process) has parsed them. Wait for the write to land rather than racing it.
        deadline = time.monotonic() + 5.0
        while emu.state()["goal_current"] != 300 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emu.state()["goal_current"] == 300
        sr = GroupSyncRead(port, ph, 102, 2)
        assert sr.addParam(1)
        assert sr.txRxPacket() == 0
        assert sr.getData(1, 102, 2) == 300
        br = GroupBulkRead(port, ph)
        assert br.addParam(1, 0, 2)  # Model Number
        assert br.txRxPacket() == 0
        assert br.getData(1, 0, 2) == 1020
    finally:
        port.closePort()
