"""URArm: the real ur_rtde constructors when nothing listens, and fakes injected at the factory boundary the
driver owns (receive / control / dashboard objects) for the watchdog, motions and safety handling."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from kitchenbot.drivers.arm import SafetyState
from kitchenbot.drivers.errors import (
    DeviceNotConnectedError,
    EmergencyStopError,
    LimitViolation,
    ProtectiveStopError,
)
from kitchenbot.drivers.ur_kinematics import ur_model
from kitchenbot.drivers.ur_rtde_arm import URArm, resample_trajectory, safety_from_bits
from kitchenbot.executive.config import CellConfig
from kitchenbot.transforms import to_rotvec

pytestmark = pytest.mark.timeout(60)
HOME = np.array([0.0, -1.9, 1.9, -1.57, -1.57, 0.0])


class FakeReceive:
    """Looks like rtde_receive.RTDEReceiveInterface; the timestamp advances with wall time until `freeze()`."""

    def __init__(self, q=HOME):
        self.q = np.array(q, float)
        self.t0 = time.monotonic()
        self.frozen_at: float | None = None
        self.safety_bits = 1  # normal mode
        self.connected = True
        self.disconnected = False

    def freeze(self):  # the receive thread died; isConnected() stays true
        self.frozen_at = self.getTimestamp()

    def getTimestamp(self):
        return self.frozen_at if self.frozen_at is not None else round(time.monotonic() - self.t0, 3) + 0.002

    def isConnected(self):
        return self.connected

    def getActualQ(self):
        return self.q.tolist()

    def getActualQd(self):
        return [0.0] * 6

    def getActualTCPForce(self):
        return [0.0] * 6

    def getSafetyStatusBits(self):
        return self.safety_bits

    def disconnect(self):
        self.disconnected = True


class FakeControl:
    """Looks like rtde_control.RTDEControlInterface: async moves take `move_time` seconds."""

    def __init__(self, receive_ref, move_time=0.15):
        self.receive_ref = receive_ref  # a callable returning the current FakeReceive
        self.move_time = move_time
        self.calls: list[tuple] = []
        self.busy_until = 0.0
        self.target = None
        self.servo_q: list[list[float]] = []
        self.connected = True
        self.program_running = True

    def isConnected(self):
        return self.connected

    def reconnect(self):
        self.calls.append(("reconnect",))
        self.connected = True
        return True

    def setTcp(self, pose):
        self.calls.append(("setTcp", list(pose)))
        return True

    def setPayload(self, mass, cog):
        self.calls.append(("setPayload", mass, list(cog)))
        return True

    def _finish(self):
        if self.target is not None and time.monotonic() >= self.busy_until:
            self.receive_ref().q = np.array(self.target)
            self.target = None

    def moveJ(self, q, speed, accel, asynchronous):
        self.calls.append(("moveJ", list(q), speed, accel, asynchronous))
        self.busy_until = time.monotonic() + self.move_time
        self.target = list(q)
        return True

    def moveL(self, pose, speed, accel, asynchronous):
        self.calls.append(("moveL", list(pose), speed, accel, asynchronous))
        self.busy_until = time.monotonic() + self.move_time
        return True

    def isPoseWithinSafetyLimits(self, pose):
        return True

    def getAsyncOperationProgress(self):
        self._finish()
        return 0 if time.monotonic() < self.busy_until else -1

    def stopJ(self, a):
        self.calls.append(("stopJ", a))
        self.busy_until = 0.0
        self.target = None

    def stopL(self, a):
        self.calls.append(("stopL", a))
        self.busy_until = 0.0

    def initPeriod(self):
        return time.monotonic()

    def waitPeriod(self, t0):
        pass  # the driver keeps no timing of its own: the vendor's initPeriod/waitPeriod do

    def servoJ(self, q, speed, accel, t, lookahead, gain):
        self.servo_q.append(list(q))
        self.calls.append(("servoJ", t, lookahead, gain)) if len(self.servo_q) == 1 else None
        self.receive_ref().q = np.array(q)
        return True

    def servoStop(self, a):
        self.calls.append(("servoStop", a))
        return True

    def isProgramRunning(self):
        return self.program_running

    def reuploadScript(self):
        self.calls.append(("reuploadScript",))
        self.program_running = True
        return True

    def stopScript(self):
        pass

    def disconnect(self):
        self.connected = False


class FakeDashboard:
    def __init__(self, receive_ref):
        self.receive_ref = receive_ref
        self.unlocks = 0

    def unlockProtectiveStop(self):
        self.unlocks += 1
        self.receive_ref().safety_bits = 1
        return "Protective stop releasing"

    def closeSafetyPopup(self):
        return "closing safety popup"

    def disconnect(self):
        pass


class Rig:
    """URArm wired to fakes; counts factory calls."""

    def __init__(self, receive_timeout=0.1, receive_fails_after=None, **kw):
        cfg = CellConfig()
        self.receives: list[FakeReceive] = []
        self.receive_fails_after = receive_fails_after
        self.control = FakeControl(lambda: self.receives[-1])
        self.dashboards: list[FakeDashboard] = []

        def make_receive(host, freq):
            if self.receive_fails_after is not None and len(self.receives) >= self.receive_fails_after:
                raise RuntimeError(f"Error: Could not connect to: {host} at 30004, verify the IP")
            q = self.receives[-1].q if self.receives else HOME
            self.receives.append(FakeReceive(q))
            return self.receives[-1]

        def make_dashboard(host):
            self.dashboards.append(FakeDashboard(lambda: self.receives[-1]))
            return self.dashboards[-1]

        self.arm = URArm(
            ur_model(cfg.robot.model),
            cfg.safety_limits(),
            "10.0.0.7",
            frequency=500.0,
            receive_timeout=receive_timeout,
            payload_kg=0.9,
            cog=(0.0, 0.0, 0.06),
            reconnect_backoff=0.01,
            receive_factory=make_receive,
            control_factory=lambda host, freq: self.control,
            dashboard_factory=make_dashboard,
            **kw,
        )


@pytest.fixture
def rig():
    r = Rig()
    r.arm.connect()
    yield r
    r.arm.disconnect()


# ---- nothing listens ---------------------------------------------------------------------------------
def test_unreachable_controller_gives_a_clear_error_fast():
    arm = URArm(ur_model("ur5e"), CellConfig().safety_limits(), "127.0.0.1")  # real ur_rtde, nothing on 30004
    t0 = time.monotonic()
    with pytest.raises(DeviceNotConnectedError, match=r"UR arm at 127\.0\.0\.1: cannot open the RTDE receive"):
        arm.connect()
    assert time.monotonic() - t0 < 5.0  # loose bound: a loaded CI host
    assert not arm.is_connected
    with pytest.raises(DeviceNotConnectedError, match="not connected"):
        arm.move_joints(HOME)


# ---- watchdog ----------------------------------------------------------------------------------------
def test_tool_and_payload_come_from_the_config(rig):
    calls = dict((c[0], c[1:]) for c in rig.control.calls)
    np.testing.assert_allclose(calls["setTcp"][0], to_rotvec(CellConfig().robot.tool.T_flange_tcp.matrix()))
    assert calls["setPayload"] == (0.9, [0.0, 0.0, 0.06])
    assert rig.dashboards == []  # the dashboard is only used on request


def test_watchdog_rebuilds_a_stalled_receive_interface(rig):
    first = rig.receives[0]
    first.freeze()
    deadline = time.monotonic() + 2.0
    while len(rig.receives) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(rig.receives) == 2, "the watchdog thread did not rebuild the stalled receive interface"
    assert first.disconnected
    assert rig.arm.receive_rebuilds == 1
    assert rig.arm.is_connected
    rig.receives[1].q = HOME + 0.01
    np.testing.assert_allclose(rig.arm.joint_positions(), HOME + 0.01)  # reads come from the new one


def test_stall_is_caught_on_read_without_the_thread():
    r = Rig(watchdog=False)
    r.arm.connect()
    try:
        r.arm.joint_positions()
        r.receives[0].freeze()
        r.arm.joint_positions()  # within receive_timeout: still trusted
        time.sleep(0.15)
        r.arm.joint_positions()
        assert len(r.receives) == 2
    finally:
        r.arm.disconnect()


def test_receive_that_cannot_be_rebuilt_declares_the_link_lost():
    r = Rig(receive_fails_after=1, watchdog=False)
    r.arm.connect()
    r.arm.joint_positions()
    r.receives[0].freeze()
    time.sleep(0.15)
    t0 = time.monotonic()
    with pytest.raises(DeviceNotConnectedError, match=r"10\.0\.0\.7: link lost: .*not advanced.*failed 3 times"):
        r.arm.joint_positions()
    assert time.monotonic() - t0 < 5.0  # bounded attempts, short backoff (loose bound: a loaded CI host)
    assert not r.arm.is_connected
    with pytest.raises(DeviceNotConnectedError):
        r.arm.move_joints(HOME)
    r.arm.disconnect()


def test_receive_that_keeps_stalling_is_given_up_after_bounded_rebuilds():
    r = Rig(watchdog=False)
    r.arm.connect()
    with pytest.raises(DeviceNotConnectedError, match="keeps stalling"):
        for _ in range(10):
            r.receives[-1].freeze()
            time.sleep(0.12)
            r.arm.joint_positions()
    assert len(r.receives) == 1 + r.arm.reconnect_attempts
    r.arm.disconnect()


# ---- motion ------------------------------------------------------------------------------------------
def test_async_move_polls_progress_and_waits(rig):
    target = HOME + np.array([0.1, 0, 0, 0, 0, 0])
    rig.arm.move_joints(target, speed=1.0, accel=1.4, asynchronous=True)
    assert rig.control.calls[-1][0] == "moveJ" and rig.control.calls[-1][-1] is True
    assert rig.arm.is_moving()
    rig.arm.wait(timeout=2.0)
    assert not rig.arm.is_moving()
    np.testing.assert_allclose(rig.arm.joint_positions(), target)


def test_synchronous_move_is_async_plus_wait(rig):
    t0 = time.monotonic()
    rig.arm.move_joints(HOME + 0.05, speed=1.0, accel=1.4)
    assert time.monotonic() - t0 >= rig.control.move_time * 0.9
    assert not rig.arm.is_moving()


def test_stop_uses_stopj_or_stopl(rig):
    rig.arm.move_joints(HOME + 0.05, asynchronous=True)
    rig.arm.stop(decel=2.5)
    assert rig.control.calls[-1] == ("stopJ", 2.5)
    assert not rig.arm.is_moving()
    T = rig.arm.tcp_pose()
    T[2, 3] -= 0.02
    rig.arm.move_linear(T, speed=0.1, asynchronous=True)
    assert rig.control.calls[-1][0] == "moveL"
    np.testing.assert_allclose(rig.control.calls[-1][1], to_rotvec(T))
    rig.arm.stop(decel=1.0)
    assert rig.control.calls[-1] == ("stopL", 1.0)


def test_limits_are_checked_before_the_controller_sees_a_command(rig):
    bad = HOME.copy()
    bad[2] = 4.0
    n = len(rig.control.calls)
    with pytest.raises(LimitViolation):
        rig.arm.move_joints(bad)
    with pytest.raises(LimitViolation):
        rig.arm.move_joints(HOME + 0.05, speed=50.0)
    assert len(rig.control.calls) == n


def test_trajectory_is_streamed_with_servoj_at_the_rtde_rate(rig):
    times = np.array([0.0, 0.1, 0.2])
    q = np.stack([HOME, HOME + 0.02, HOME + 0.04])
    rig.arm.execute_trajectory(times, q)
    sent = np.array(rig.control.servo_q)
    assert len(sent) == 101  # 0.2 s at 500 Hz, plus the final waypoint
    np.testing.assert_allclose(sent[0], HOME)
    np.testing.assert_allclose(sent[50], HOME + 0.02, atol=1e-9)
    np.testing.assert_allclose(sent[-1], HOME + 0.04)
    servo = next(c for c in rig.control.calls if c[0] == "servoJ")
    assert servo[1] == pytest.approx(1 / 500)
    assert ("servoStop", 10.0) in rig.control.calls


def test_guarded_trajectory_ends_where_the_tcp_force_rises(rig):
    times = np.array([0.0, 0.2])
    q = np.stack([HOME, HOME + 0.04])
    sent = rig.control.servo_q
    rig.receives[-1].getActualTCPForce = lambda: [0.0, 0.0, 20.0 if len(sent) >= 40 else 2.0, 0.0, 0.0, 0.0]
    rig.arm.execute_trajectory(times, q, guarded=True)
    assert len(sent) == 40 and rig.arm.stopped_on_contact
    assert ("servoStop", 10.0) in rig.control.calls
    rig.control.servo_q.clear()  # unguarded, the same force does not stop it
    rig.arm.execute_trajectory(np.array([0.0, 0.2]), np.stack([HOME + 0.04 * 40 / 100, HOME]))
    assert len(rig.control.servo_q) == 101 and not rig.arm.stopped_on_contact


def test_resample_ends_on_the_last_waypoint():
    out = resample_trajectory(np.array([0.0, 0.25]), np.array([[0.0] * 6, [1.0] * 6]), 0.1)
    np.testing.assert_allclose(out[:, 0], [0.0, 0.4, 0.8, 1.0])


# ---- safety ------------------------------------------------------------------------------------------
def test_safety_bits_mapping():
    assert safety_from_bits(0b1) is SafetyState.NORMAL
    assert safety_from_bits(1 << 2) is SafetyState.PROTECTIVE_STOP
    assert safety_from_bits(1 << 4) is SafetyState.PROTECTIVE_STOP  # safeguard stop
    assert safety_from_bits((1 << 7) | (1 << 6)) is SafetyState.EMERGENCY_STOP
    assert safety_from_bits((1 << 9) | (1 << 2)) is SafetyState.FAULT


def test_protective_stop_during_a_move_raises_and_unlock_uses_the_dashboard(rig):
    rig.arm.move_joints(HOME + 0.05, asynchronous=True)
    rig.receives[-1].safety_bits = 1 << 2
    rig.control.program_running = False
    with pytest.raises(ProtectiveStopError):
        rig.arm.wait(timeout=1.0)
    with pytest.raises(ProtectiveStopError, match="unlock"):
        rig.arm.move_joints(HOME)
    assert rig.dashboards == []  # never unlocked on its own
    rig.arm.unlock_protective_stop()
    assert rig.dashboards[0].unlocks == 1
    assert ("reuploadScript",) in rig.control.calls
    assert rig.arm.safety_state() is SafetyState.NORMAL


def test_emergency_stop_cannot_be_unlocked(rig):
    rig.receives[-1].safety_bits = 1 << 7
    with pytest.raises(EmergencyStopError):
        rig.arm.move_joints(HOME)
    with pytest.raises(EmergencyStopError, match="a person"):
        rig.arm.unlock_protective_stop()
    assert rig.dashboards == []


def test_control_link_drop_is_reconnected(rig):
    rig.control.connected = False
    rig.arm.move_joints(HOME + 0.02, asynchronous=True)
    assert ("reconnect",) in rig.control.calls
    # the tool is re-applied after a reconnect
    assert [c[0] for c in rig.control.calls].count("setTcp") == 2
    rig.arm.wait(timeout=2.0)


def test_watchdog_thread_stops_on_disconnect():
    r = Rig()
    r.arm.connect()
    assert any(t.name == "ur-rtde-watchdog" for t in threading.enumerate())
    r.arm.disconnect()
    assert not any(t.name == "ur-rtde-watchdog" and t.is_alive() for t in threading.enumerate())


# ---- read-only probe (doctor) ------------------------------------------------------------------------
class ProbeDashboard(FakeDashboard):
    def getRobotModel(self):
        return "UR5"

    def polyscopeVersion(self):
        return "URSoftware 5.15.0"

    def robotmode(self):
        return "Robotmode: RUNNING"

    def isInRemoteControl(self):
        return True


def test_probe_reads_state_without_a_control_interface():
    from kitchenbot.drivers.ur_rtde_arm import probe

    rec = FakeReceive()
    info = probe("10.0.0.7", watch=0.02, receive_factory=lambda h, f: rec,
                 dashboard_factory=lambda h: ProbeDashboard(lambda: rec))
    assert info["streaming"] and info["safety"] == "normal" and info["model"] == "UR5"
    assert rec.disconnected
    stalled = FakeReceive()
    stalled.freeze()
    stalled.safety_bits = 1 << 2
    info = probe("10.0.0.7", watch=0.02, receive_factory=lambda h, f: stalled,
                 dashboard_factory=lambda h: ProbeDashboard(lambda: stalled))
    assert not info["streaming"] and info["safety"] == "protective_stop"


def test_connect_again_after_a_lost_link():
    r = Rig(receive_fails_after=1, watchdog=False)
    r.arm.connect()
    r.receives[0].freeze()
    time.sleep(0.15)
    with pytest.raises(DeviceNotConnectedError, match="link lost"):
        r.arm.joint_positions()
    r.receive_fails_after = None  # the controller is back
    r.arm.connect()
    assert r.arm.is_connected
    assert r.receives[0].disconnected and len(r.receives) == 2
    np.testing.assert_allclose(r.arm.joint_positions(), HOME)
    r.arm.disconnect()
