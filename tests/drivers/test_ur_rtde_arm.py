"""URArm with the real ur_rtde classes (RTDEReceiveInterface, RTDEControlInterface, DashboardClient) against the
UR controller emulator (fakes/ur_controller_emulator.py). No wall-clock races: stall detection runs on an
injected clock the tests advance; waits are for events (emulator state, thread ends) with generous limits."""

from __future__ import annotations

import dataclasses

import threading
import time

import numpy as np
import pytest

from kitchenbot.drivers.arm import SafetyState
from kitchenbot.drivers.errors import (
    DeviceNotConnectedError,
    DriverError,
    EmergencyStopError,
    LimitViolation,
    ProtectiveStopError,
)
from kitchenbot.drivers.ur_kinematics import fk_flange, ur_model
from kitchenbot.drivers.ur_rtde_arm import URArm, probe, resample_trajectory, safety_from_bits
from kitchenbot.executive.config import CellConfig
from kitchenbot.fakes.ur_controller_emulator import URControllerEmulator
from kitchenbot.transforms import to_rotvec

pytestmark = pytest.mark.timeout(120)
HOME = np.array([0.0, -1.9, 1.9, -1.57, -1.57, 0.0])
CFG = CellConfig()
TCP = to_rotvec(CFG.robot.tool.T_flange_tcp.matrix())


class FakeClock:
    """The host clock the driver judges data age by; only the test moves it."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


def make_arm(emu: URControllerEmulator, **kw) -> URArm:
    # the emulator is another process: on a loaded host it may answer the handshake (a CI run beside another
    # measured 2 s exceeded) and start a short move seconds late; tests of those timeouts pass their own
    args = dict(receive_timeout=0.1, connect_timeout=10.0, payload_kg=0.9, cog=(0.0, 0.0, 0.06),
                reconnect_backoff=0.01, watchdog=False, clock=FakeClock(),
                motion_start_timeout=30.0, motion_slack=30.0)
    args.update(kw)
    return URArm(ur_model(CFG.robot.model), CFG.safety_limits(), emu.host, **args)


def wait_until(predicate, what: str, timeout: float = 20.0) -> None:
    """Wait for an event the test cannot be told about directly (e.g. a state reaching the client's stream)."""
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"{what}: not within {timeout} s"
        time.sleep(0.005)


def logged(emu: URControllerEmulator, what: str) -> int:
    return sum(1 for line in emu.state()["log"] if line.split(" ", 1)[1] == what)


@pytest.fixture
def emu():
    with URControllerEmulator(q0=HOME) as e:
        yield e


@pytest.fixture
def arm(emu):
    a = make_arm(emu)
    a.connect()
    yield a
    a.disconnect()


# ---- connecting ----------------------------------------------------------------------------------------
def test_unreachable_controller_gives_a_clear_error_fast():
    arm = URArm(ur_model("ur5e"), CFG.safety_limits(), "127.0.0.1")  # real ur_rtde, nothing on 30004
    t0 = time.monotonic()
    with pytest.raises(DeviceNotConnectedError, match=r"UR arm at 127\.0\.0\.1: cannot open TCP port 30004"):
        arm.connect()
    assert time.monotonic() - t0 < 5.0  # loose bound: a loaded CI host
    assert not arm.is_connected
    with pytest.raises(DeviceNotConnectedError, match="not connected"):
        arm.move_joints(HOME)


def test_a_silent_controller_is_refused_in_bounded_time(emu):
    # A host that accepts TCP and never answers: the vendor constructor would block this process (GIL held).
    emu.set(silent=True)
    arm = make_arm(emu, connect_timeout=0.5)
    with pytest.raises(DeviceNotConnectedError, match="accepted TCP port 30004 but did not answer the RTDE handshake"):
        arm.connect()
    assert not arm.is_connected


def test_a_stream_that_never_starts_is_refused_at_connect(emu):
    emu.set(stall_new=True)  # handshake completes, no data packages follow
    arm = make_arm(emu, connect_timeout=2.0)  # a loaded host may answer the handshake later than 0.5 s
    with pytest.raises(DeviceNotConnectedError, match="RTDE stream is stalled"):
        arm.connect()


def test_tool_and_payload_come_from_the_config(emu, arm):
    s = emu.state()
    np.testing.assert_allclose(s["tcp"], TCP, atol=1e-9)
    assert s["payload"] == pytest.approx(0.9) and s["payload_cog"] == pytest.approx([0.0, 0.0, 0.06])
    assert logged(emu, "dashboard: unlock protective stop") == 0


def test_registers_held_by_a_fieldbus_are_named_and_the_upper_range_works(emu):
    emu.set(fieldbus=True)
    arm = make_arm(emu)
    with pytest.raises(DeviceNotConnectedError, match=r"EtherNet/IP.*upper_range_registers"):
        arm.connect()
    arm = make_arm(emu, upper_range_registers=True)
    arm.connect()
    try:
        assert any("register offset 24" in line for line in emu.state()["log"])
        arm.move_joints(HOME + 0.02)
        np.testing.assert_allclose(arm.joint_positions(), HOME + 0.02, atol=1e-6)
    finally:
        arm.disconnect()


# ---- control script restarts ------------------------------------------------------------------------------
def test_tool_is_sent_again_after_the_script_was_uploaded_again(emu, arm):
    arm._rtde_c.reuploadScript()  # what a recovery tool or ur_rtde itself may do: a new script, installation TCP
    s = emu.wait_for(lambda s: s["program_starts"] == 2 and s["program_running"], what="new control script")
    assert s["tcp"] == [0.0] * 6 and s["payload"] == 0.0
    T = arm.tcp_pose()
    T[2, 3] -= 0.03
    arm.move_linear(T, speed=0.1)
    np.testing.assert_allclose(emu.state()["tcp"], TCP, atol=1e-9)
    np.testing.assert_allclose(arm.tcp_pose()[:3, 3], T[:3, 3], atol=1e-4)  # moveL used our TCP
    assert emu.state()["payload"] == pytest.approx(0.9)
    assert arm.tool_reapplied == 1


def test_a_dropped_receive_link_is_rebuilt_on_the_next_read(emu, arm):
    emu.disconnect("rtde_receive")  # the controller closes the receive client's connection
    arm.move_joints(HOME + 0.02)  # isConnected() turns false: rebuilt on the way
    assert arm.receive_rebuilds == 1
    np.testing.assert_allclose(arm.joint_positions(), HOME + 0.02, atol=1e-6)


def test_a_stopped_script_is_uploaded_again_before_the_next_motion(emu, arm):
    emu.stop_script()
    wait_until(lambda: not arm._rtde_c.isProgramRunning(), "script stop seen by the control interface")
    arm.move_joints(HOME + 0.02)
    s = emu.state()
    assert s["program_running"] and s["program_starts"] == 2
    np.testing.assert_allclose(s["tcp"], TCP, atol=1e-9)
    np.testing.assert_allclose(arm.joint_positions(), HOME + 0.02, atol=1e-6)


# ---- motion --------------------------------------------------------------------------------------------
def test_synchronous_move_returns_only_when_the_arm_is_there(emu, arm):
    # The control script starts an async move a cycle (here, busy: 0.2 s) after moveJ returns; a wait that
    # trusted the first progress reading (< 0, "finished") returned at once, with the arm still at HOME.
    emu.set(thread_start_delay=0.2)
    target = HOME + np.array([0.2, 0, 0, 0, 0, 0])
    arm.move_joints(target, speed=1.0, accel=1.4)
    np.testing.assert_allclose(arm.joint_positions(), target, atol=1e-6)
    assert not emu.state()["moving"]


def test_async_move_is_moving_from_the_start_and_wait_ends_it(emu, arm):
    emu.set(thread_start_delay=0.2)
    target = HOME + np.array([0.1, 0, 0, 0, 0, 0])
    arm.move_joints(target, asynchronous=True)
    assert arm.is_moving()
    arm.wait(timeout=10.0)
    assert not arm.is_moving()
    np.testing.assert_allclose(arm.joint_positions(), target, atol=1e-6)


def test_stop_uses_stopj_or_stopl(emu, arm):
    target = HOME + np.array([1.0, 0, 0, 0, 0, 0])  # > 2 s of motion: the stop lands well before the end
    arm.move_joints(target, speed=0.5, asynchronous=True)
    emu.wait_for(lambda s: s["moving"], what="moving")
    arm.stop(decel=2.5)
    assert logged(emu, "stopJ") == 1
    assert not arm.is_moving() and not emu.state()["moving"]
    assert abs(arm.joint_positions()[0] - target[0]) > 0.1  # stopped on the way
    T = arm.tcp_pose()
    T[2, 3] -= 0.1
    arm.move_linear(T, speed=0.05, asynchronous=True)
    emu.wait_for(lambda s: s["moving"], what="moving")
    arm.stop(decel=1.0)
    assert logged(emu, "stopL") == 1
    assert arm.tcp_pose()[2, 3] > T[2, 3] + 0.01


def test_limits_are_checked_before_the_controller_sees_a_command(emu, arm):
    bad = HOME.copy()
    bad[2] = 4.0
    n = len(emu.state()["log"])
    with pytest.raises(LimitViolation):
        arm.move_joints(bad)
    with pytest.raises(LimitViolation):
        arm.move_joints(HOME + 0.05, speed=50.0)
    assert len(emu.state()["log"]) == n
    np.testing.assert_allclose(arm.joint_positions(), HOME, atol=1e-9)


def test_a_range_error_from_ur_rtde_is_a_limit_violation(emu):
    arm = make_arm(emu, servo_lookahead=0.5)  # ur_rtde accepts 0.03..0.2 s and raises ValueError
    arm.connect()
    try:
        with pytest.raises(LimitViolation, match="ur_rtde refused servoJ"):
            arm.execute_trajectory(np.array([0.0, 0.1]), np.stack([HOME, HOME + 0.01]))
    finally:
        arm.disconnect()


def test_trajectory_is_streamed_with_servoj_and_ends_on_the_last_waypoint(emu, arm):
    arm.settings = dataclasses.replace(arm.settings, servo_settle_time=30.0)  # an upper bound only: the stream ends as soon as the arm is there
    times = np.array([0.0, 0.3, 0.6])
    q = np.stack([HOME, HOME + 0.05, HOME + 0.1])
    arm.execute_trajectory(times, q)
    # servoJ lags by about the lookahead time; stopping the stream at the last sample stopped short of it
    np.testing.assert_allclose(arm.joint_positions(), q[-1], atol=arm.settings.servo_settle_tolerance)
    assert logged(emu, "servoStop") == 1


def test_guarded_trajectory_ends_where_the_tcp_force_rises(emu, arm):
    T_ft = CFG.safety_limits().T_flange_tcp
    q1 = HOME + np.array([0.0, 0.0, 0.0, 0.15, 0.0, 0.0])
    z0 = (fk_flange(arm.model, HOME) @ T_ft)[2, 3]
    z1 = (fk_flange(arm.model, q1) @ T_ft)[2, 3]
    assert z1 < z0 - 0.01  # the wrist turns the tool down
    plane = z0 - 0.5 * (z0 - z1)
    emu.set(contact_z=plane)
    arm.execute_trajectory(np.array([0.0, 1.0]), np.stack([HOME, q1]), guarded=True)
    assert arm.stopped_on_contact
    z = arm.tcp_pose()[2, 3]
    assert z1 + 0.002 < z < plane  # pressed into the surface a little, well before the end
    emu.set(contact_z=None)


def test_resample_ends_on_the_last_waypoint():
    out = resample_trajectory(np.array([0.0, 0.25]), np.array([[0.0] * 6, [1.0] * 6]), 0.1)
    np.testing.assert_allclose(out[:, 0], [0.0, 0.4, 0.8, 1.0])


# ---- receive link: stalls, rebuilds, lost links ---------------------------------------------------------------
def test_stall_is_caught_on_read_by_the_age_of_the_data(emu, arm):
    clock = arm._clock
    arm.joint_positions()
    emu.stall()  # the stream stops; the TCP link stays up
    clock.advance(0.05)
    arm.joint_positions()  # 50 ms old: still trusted
    assert arm.receive_rebuilds == 0
    clock.advance(0.2)
    arm.joint_positions()  # 250 ms old: rebuilt
    assert arm.receive_rebuilds == 1
    np.testing.assert_allclose(arm.joint_positions(), HOME, atol=1e-9)  # the new stream is fresh
    assert arm.receive_rebuilds == 1


def test_watchdog_thread_rebuilds_a_stalled_receive_interface(emu):
    arm = make_arm(emu, watchdog=True, receive_timeout=1.0, clock=time.monotonic)  # real clock: be lenient
    arm.connect()
    try:
        assert any(t.name == "ur-rtde-watchdog" for t in threading.enumerate())
        emu.stall()
        deadline = time.monotonic() + 20.0
        while arm.receive_rebuilds == 0 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert arm.receive_rebuilds >= 1, "the watchdog thread did not rebuild the stalled receive interface"
        assert arm.is_connected
        arm.move_joints(HOME + 0.02)
        np.testing.assert_allclose(arm.joint_positions(), HOME + 0.02, atol=1e-6)
    finally:
        arm.disconnect()
    assert not any(t.name == "ur-rtde-watchdog" and t.is_alive() for t in threading.enumerate())


def _connected_with_short_rebuilds(emu):
    """An arm connected with the default handshake timeout (a loaded host may take longer than 0.3 s to answer),
    whose later rebuilds against a stalled controller give up after 0.3 s each."""
    arm = make_arm(emu)
    arm.connect()
    arm.settings = dataclasses.replace(arm.settings, connect_timeout=0.3)
    return arm


def test_receive_that_cannot_be_rebuilt_declares_the_link_lost(emu):
    arm = _connected_with_short_rebuilds(emu)
    try:
        emu.stall()
        emu.set(stall_new=True)
        arm._clock.advance(1.0)
        with pytest.raises(DeviceNotConnectedError, match=r"link lost: .*s old.*failed 3 times.*stalled"):
            arm.joint_positions()
        assert not arm.is_connected
        with pytest.raises(DeviceNotConnectedError):
            arm.move_joints(HOME)
    finally:
        arm.disconnect()


def test_receive_that_keeps_stalling_is_given_up_after_bounded_rebuilds(emu, arm):
    with pytest.raises(DeviceNotConnectedError, match="keeps stalling"):
        for _ in range(10):
            emu.stall()
            arm._clock.advance(0.5)
            arm.joint_positions()
    assert arm.receive_rebuilds == arm.settings.reconnect_attempts


def test_connect_again_after_a_lost_link(emu):
    arm = _connected_with_short_rebuilds(emu)
    emu.stall()
    emu.set(stall_new=True)
    arm._clock.advance(1.0)
    with pytest.raises(DeviceNotConnectedError, match="link lost"):
        arm.joint_positions()
    emu.set(stall_new=False)  # the controller is back
    arm.connect()
    try:
        assert arm.is_connected
        np.testing.assert_allclose(arm.joint_positions(), HOME, atol=1e-9)
        arm.move_joints(HOME + 0.02)
    finally:
        arm.disconnect()


def test_stop_is_not_delayed_by_a_receive_rebuild(emu):
    arm = make_arm(emu, connect_timeout=2.0, reconnect_backoff=0.5)
    arm.connect()
    try:
        arm.move_joints(HOME + np.array([0.6, 0, 0, 0, 0, 0]), speed=0.3, asynchronous=True)
        emu.wait_for(lambda s: s["moving"], what="moving")
        emu.stall()
        emu.set(stall_new=True)  # every rebuild attempt now waits out its timeout: >= 3 x 2 s
        arm._clock.advance(1.0)
        errors = []
        reader = threading.Thread(target=lambda: errors.append(pytest.raises(DeviceNotConnectedError, arm.joint_positions)))
        reader.start()
        deadline = time.monotonic() + 20.0
        while not arm._rebuild_lock.locked() and time.monotonic() < deadline:
            time.sleep(0.005)
        assert arm._rebuild_lock.locked(), "the rebuild did not start"
        arm.stop(decel=3.0)
        assert reader.is_alive(), "stop() returned only after the rebuild ended"
        assert logged(emu, "stopJ") == 1
        reader.join(timeout=60.0)
        assert errors, "the rebuild should have failed against a stalled controller"
        assert not emu.state()["moving"]
    finally:
        arm.disconnect()


def test_stop_still_sends_stopj_after_the_receive_link_is_lost(emu):
    arm = _connected_with_short_rebuilds(emu)
    try:
        arm.move_joints(HOME + np.array([0.6, 0, 0, 0, 0, 0]), speed=0.3, asynchronous=True)
        emu.wait_for(lambda s: s["moving"], what="moving")
        emu.stall()
        emu.set(stall_new=True)
        arm._clock.advance(1.0)
        with pytest.raises(DeviceNotConnectedError, match="link lost"):
            arm.joint_positions()
        n = logged(emu, "stopJ")
        arm.stop(decel=3.0)  # the control link is fine: stop acts
        assert logged(emu, "stopJ") == n + 1
        emu.wait_for(lambda s: not s["moving"], what="stopped")
    finally:
        arm.disconnect()


# ---- safety ------------------------------------------------------------------------------------------
def test_safety_bits_mapping():
    assert safety_from_bits(0b1) is SafetyState.NORMAL
    assert safety_from_bits(1 << 2) is SafetyState.PROTECTIVE_STOP
    assert safety_from_bits(1 << 4) is SafetyState.PROTECTIVE_STOP  # safeguard stop
    assert safety_from_bits((1 << 7) | (1 << 6)) is SafetyState.EMERGENCY_STOP
    assert safety_from_bits((1 << 9) | (1 << 2)) is SafetyState.FAULT


def test_protective_stop_during_a_move_raises_and_unlock_uses_the_dashboard(emu, arm):
    arm.move_joints(HOME + np.array([0.5, 0, 0, 0, 0, 0]), speed=0.5, asynchronous=True)
    emu.wait_for(lambda s: s["moving"], what="moving")
    emu.protective_stop()
    with pytest.raises(ProtectiveStopError):
        arm.wait(timeout=10.0)
    with pytest.raises(ProtectiveStopError, match="unlock"):
        arm.move_joints(HOME)
    assert logged(emu, "dashboard: unlock protective stop") == 0  # never unlocked on its own
    arm.unlock_protective_stop()  # the real client returns None on success
    assert logged(emu, "dashboard: unlock protective stop") == 1
    s = emu.state()
    assert arm.safety_state() is SafetyState.NORMAL
    assert s["program_running"] and s["program_starts"] == 2  # the stopped control script was uploaded again
    np.testing.assert_allclose(s["tcp"], TCP, atol=1e-9)  # ... with our tool
    arm.move_joints(HOME)
    np.testing.assert_allclose(arm.joint_positions(), HOME, atol=1e-6)


def test_unlock_refused_by_the_controller_is_a_protective_stop_error_in_its_words():
    with URControllerEmulator(q0=HOME, unlock_delay=600.0) as emu:  # the real controller waits 5 s
        arm = make_arm(emu)
        arm.connect()
        try:
            emu.protective_stop()
            wait_until(lambda: arm.safety_state() is SafetyState.PROTECTIVE_STOP, "protective stop seen")
            with pytest.raises(ProtectiveStopError, match="refused to unlock.*Cannot unlock protective stop until 5s"):
                arm.unlock_protective_stop()
            assert arm.safety_state() is SafetyState.PROTECTIVE_STOP
            emu.set(unlock_delay=0.0)
            arm.unlock_protective_stop()
            assert arm.safety_state() is SafetyState.NORMAL
        finally:
            arm.disconnect()


def test_emergency_stop_cannot_be_unlocked(emu, arm):
    emu.emergency_stop()
    wait_until(lambda: arm.safety_state() is SafetyState.EMERGENCY_STOP, "emergency stop seen")
    with pytest.raises(EmergencyStopError):
        arm.move_joints(HOME)
    with pytest.raises(EmergencyStopError, match="a person"):
        arm.unlock_protective_stop()
    assert logged(emu, "dashboard: unlock protective stop") == 0


def test_describe_reads_the_dashboard(emu, arm):
    info = arm.describe()
    assert info["model"] == "UR5" and info["polyscope"].startswith("5.15") and info["serial"].isdigit()
    assert "NORMAL" in info["safety"] and "RUNNING" in info["robot_mode"]


# ---- read-only probe (doctor) ------------------------------------------------------------------------
def test_probe_reads_state_without_a_control_interface(emu):
    info = probe(emu.host, watch=0.05)
    assert info["streaming"] and info["safety"] == "normal" and info["model"] == "UR5"
    assert info["remote_control"] is True
    np.testing.assert_allclose(info["q"], np.round(HOME, 3))
    assert emu.state()["program_starts"] == 0  # nothing uploaded
    emu.protective_stop()
    emu.wait_for(lambda s: s["safety_mode"] == 3, what="protective stop")
    info = probe(emu.host, watch=0.05)
    assert info["safety"] == "protective_stop"


def test_probe_has_no_remote_control_answer_before_polyscope_5_6():
    with URControllerEmulator(q0=HOME, polyscope="5.4.3") as emu:
        info = probe(emu.host, watch=0.05)
    assert info["polyscope"].startswith("5.4") and info["remote_control"] is None


def test_probe_is_bounded_on_a_silent_host(emu):
    emu.set(silent=True)
    t0 = time.monotonic()
    with pytest.raises(DeviceNotConnectedError, match="did not answer"):
        probe(emu.host, timeout=0.5)
    assert time.monotonic() - t0 < 10.0  # loose: without the bound the vendor constructor blocks for minutes


def test_probe_refuses_a_controller_in_error():
    with pytest.raises(DriverError):
        probe("127.0.0.1", timeout=0.5)
