"""`kitchenbot doctor` on the shipped sim config, on absent devices, and on the Dynamixel emulator."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from kitchenbot.drivers.camera import Frame
from kitchenbot.drivers.recording import CaptureRecorder
from kitchenbot.executive.cli import main
from kitchenbot.fakes.dynamixel_emulator import DynamixelEmulator
from kitchenbot.fakes.ur_controller_emulator import URControllerEmulator

pytestmark = pytest.mark.timeout(60)


def _config(tmp_path, drivers: dict):
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump({"drivers": drivers}))
    return str(path)


def test_doctor_on_the_sim_config_passes(capsys):
    assert main(["doctor"]) == 0
    out = capsys.readouterr().out
    assert out.count("simulated") >= 3
    assert "all configured devices ok" in out


def test_doctor_reports_an_absent_serial_port(tmp_path, capsys):
    cfg = _config(tmp_path, {"gripper": {"kind": "dynamixel", "port": "/dev/ttyUSB_kb_absent"}})
    assert main(["doctor", "--config", cfg]) == 1
    out = capsys.readouterr().out
    assert "/dev/ttyUSB_kb_absent does not exist" in out
    assert "gripper need attention" in out


def test_doctor_reads_the_servo_on_the_emulator_and_flags_a_hardware_error(tmp_path, capsys):
    with DynamixelEmulator() as emu:
        # the emulator is a Python process: on a loaded host it may answer later than a servo's 100 ms floor
        cfg = _config(tmp_path, {"gripper": {"kind": "dynamixel", "port": emu.port, "min_packet_timeout_ms": 1000}})
        assert main(["doctor", "--config", cfg]) == 0
        out = capsys.readouterr().out
        assert "XM430-W350 fw 48" in out and "85.0 mm" in out
        assert emu.state()["torque_enable"] == 0  # read-only: doctor wrote nothing
        emu.inject_fault("overload")
        assert main(["doctor", "--config", cfg]) == 1
        assert "Hardware error 'overload'" in capsys.readouterr().out


def test_doctor_does_not_talk_over_a_gripper_in_use(tmp_path, capsys):
    from kitchenbot.drivers.dynamixel_gripper import DynamixelGripper

    with DynamixelEmulator() as emu:
        g = DynamixelGripper(emu.port, min_packet_timeout_ms=1000)  # emulator on a loaded host
        g.connect()  # a run holds the port
        try:
            cfg = _config(tmp_path, {"gripper": {"kind": "dynamixel", "port": emu.port}})
            before = emu.packets_seen()
            assert main(["doctor", "--config", cfg]) == 1
            out = capsys.readouterr().out
            assert "another program has it open" in out and f"Stop what holds {emu.port}" in out
            assert emu.packets_seen() == before  # not one packet interleaved with the run's
        finally:
            g.disconnect()


def test_doctor_on_absent_arm_and_camera(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(
        "kitchenbot.drivers.oakd_camera.OakDCamera.available_devices", staticmethod(lambda: [])
    )  # keep this test independent of whatever USB devices the machine has; the real call is tested elsewhere
    cfg = _config(tmp_path, {"arm": {"kind": "ur_rtde", "host": "127.0.0.1"}, "camera": {"kind": "oakd"}})
    assert main(["doctor", "--config", cfg]) == 1
    out = capsys.readouterr().out
    assert "UR arm at 127.0.0.1: cannot open TCP port 30004 (RTDE)" in out
    assert "OAK-D camera: no device found" in out
    assert "arm, camera need attention" in out


def test_doctor_on_a_replay_recording(tmp_path, capsys):
    rec = CaptureRecorder(tmp_path / "rec")
    rgb = np.zeros((24, 32, 3), np.uint8)
    rec.save(Frame(rgb=rgb, depth=np.ones((24, 32), np.float32), K=np.eye(3), stamp=0.0))
    cfg = _config(tmp_path, {"camera": {"kind": "replay", "directory": "rec"}})
    assert main(["doctor", "--config", cfg]) == 0
    assert "1 captures 32x24" in capsys.readouterr().out
    cfg = _config(tmp_path, {"camera": {"kind": "replay", "directory": "missing"}})
    assert main(["doctor", "--config", cfg]) == 1
    assert "recording folder does not exist" in capsys.readouterr().out


# ---- UR arm on the controller emulator ----------------------------------------------------------------------
def test_doctor_reads_the_ur_controller(tmp_path, capsys):
    with URControllerEmulator() as emu:
        cfg = _config(tmp_path, {"arm": {"kind": "ur_rtde", "host": emu.host}})
        assert main(["doctor", "--config", cfg]) == 0
        out = capsys.readouterr().out
        assert "UR5 5.15.0" in out and "safety normal" in out
        assert emu.state()["program_starts"] == 0  # read-only: no control script was uploaded
        emu.set(remote_control=False)
        assert main(["doctor", "--config", cfg]) == 1
        assert "Remote Control" in capsys.readouterr().out


def test_doctor_gives_no_remote_control_hint_before_polyscope_5_6(tmp_path, capsys):
    # ur_rtde's isInRemoteControl() answers False on PolyScope < 5.6, which has no such mode
    with URControllerEmulator(polyscope="5.4.3") as emu:
        cfg = _config(tmp_path, {"arm": {"kind": "ur_rtde", "host": emu.host}})
        assert main(["doctor", "--config", cfg]) == 0
        out = capsys.readouterr().out
        assert "5.4.3" in out and "Remote Control" not in out


def test_doctor_is_bounded_on_a_silent_ur_controller(tmp_path, capsys):
    with URControllerEmulator() as emu:
        emu.set(silent=True)  # accepts TCP, never answers: the vendor constructor alone would block for minutes
        cfg = _config(tmp_path, {"arm": {"kind": "ur_rtde", "host": emu.host, "connect_timeout": 0.5}})
        assert main(["doctor", "--config", cfg]) == 1
        out = capsys.readouterr().out
        assert "did not answer the RTDE handshake within 0.5 s" in out
