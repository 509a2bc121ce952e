from pathlib import Path

import numpy as np
import pytest

from kitchenbot.executive.config import DEFAULT_CONFIG, ConfigError, load_config


def test_shipped_config_loads():
    cfg = load_config()
    assert cfg.robot.model == "ur5e"
    lim = cfg.safety_limits()
    assert lim.joint_upper[2] == pytest.approx(np.pi)
    assert lim.T_flange_tcp[2, 3] == pytest.approx(0.20)


def test_bad_value_names_file_and_field(tmp_path: Path):
    f = tmp_path / "cell.yaml"
    f.write_text("robot:\n  model: ur7\n  limits:\n    max_tcp_speed: 3.0\n")
    with pytest.raises(ConfigError) as e:
        load_config(f)
    msg = str(e.value)
    assert str(f) in msg
    assert "robot.model" in msg and "ur5e" in msg
    assert "robot.limits.max_tcp_speed" in msg


def test_unknown_field_and_driver_kind_rejected(tmp_path: Path):
    f = tmp_path / "cell.yaml"
    f.write_text("drivers:\n  camera: {kind: kinect}\nperceptoin: {}\n")
    with pytest.raises(ConfigError) as e:
        load_config(f)
    msg = str(e.value)
    assert "drivers.camera" in msg and "perceptoin" in msg


def test_missing_and_malformed_files(tmp_path: Path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("robot: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)


def test_default_config_is_the_shipped_file():
    assert DEFAULT_CONFIG.exists()
