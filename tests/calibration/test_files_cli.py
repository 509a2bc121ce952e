from __future__ import annotations

import numpy as np
import pytest
import yaml

from kitchenbot.calibration import synthetic as synth
from kitchenbot.calibration.files import CalibrationFileError, load_hand_eye, load_samples, save_samples
from kitchenbot.executive.cli import main
from kitchenbot.executive.config import load_config
from kitchenbot.transforms import pose_error


@pytest.mark.parametrize("mount,key", [("eye_in_hand", "T_flange_cam"), ("eye_to_hand", "T_base_cam")])
def test_solve_cli_writes_the_documented_yaml(tmp_path, rng, mount, key, capsys):
    F, C = synth.samples(mount, 10, rng, cam_rot_deg=0.02, cam_trans_mm=0.1)
    samples = save_samples(tmp_path / "samples.json", mount, F, C)
    out = tmp_path / "hand_eye.yaml"
    assert main(["calibrate", "solve", str(samples), "--out", str(out)]) == 0
    assert "residuals AX=XB" in capsys.readouterr().out
    doc = yaml.safe_load(out.read_text())
    assert doc["method"] == "park_martin_1994" and doc["mount"] == mount
    assert doc["samples_used"] == 10 and isinstance(doc["date"], str)
    assert set(doc["residuals"]) >= {"rotation_deg", "translation_mm", "pairs_rejected", "board_spread"}
    assert 0 < doc["residuals"]["translation_mm"] < 2.0
    T = load_hand_eye(out, key)
    r, t = pose_error(T, synth.X_TRUE)
    assert np.rad2deg(r) < 0.1 and t < 1e-3
    F2, C2 = load_samples(samples)[1:]
    assert np.allclose(F2[3], F[3]) and np.allclose(C2[3], C[3])


def test_cell_config_reads_the_calibration_file(tmp_path, rng):
    F, C = synth.samples("eye_in_hand", 6, rng)
    samples = save_samples(tmp_path / "s.json", "eye_in_hand", F, C)
    assert main(["calibrate", "solve", str(samples), "--out", str(tmp_path / "cal" / "he.yaml")]) == 0
    cfg_path = tmp_path / "cell.yaml"
    cfg_path.write_text("calibration:\n  file: cal/he.yaml\n")  # relative to the config file
    assert np.allclose(load_config(cfg_path).T_flange_cam(), synth.X_TRUE, atol=1e-9)
    # Without a file the pose in the config is used.
    cfg_path.write_text("calibration:\n  T_flange_cam: {xyz: [0.01, 0.02, 0.03], rpy: [0, 0, 0]}\n")
    assert np.allclose(load_config(cfg_path).T_flange_cam()[:3, 3], [0.01, 0.02, 0.03])


def test_bad_files_name_the_file_and_key(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("method: park_martin_1994\n")
    with pytest.raises(CalibrationFileError, match=r"bad.yaml: missing key T_flange_cam"):
        load_hand_eye(p)
    p.write_text("T_flange_cam: [[1, 0, 0], [0, 1, 0]]\n")
    with pytest.raises(CalibrationFileError, match=r"bad.yaml: T_flange_cam: expected a 4x4"):
        load_hand_eye(p)
    p.write_text("T_flange_cam: [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n")
    with pytest.raises(CalibrationFileError, match="not a rigid transform"):
        load_hand_eye(p)
    p.write_text("T_base_cam: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n")
    with pytest.raises(CalibrationFileError, match="missing key T_flange_cam .the file holds T_base_cam"):
        load_hand_eye(p)
    with pytest.raises(CalibrationFileError, match="cannot read"):
        load_hand_eye(tmp_path / "nope.yaml")
    cfg_path = tmp_path / "cell.yaml"
    cfg_path.write_text("calibration:\n  file: bad.yaml\n")
    with pytest.raises(CalibrationFileError, match="bad.yaml"):
        load_config(cfg_path).T_flange_cam()
    s = tmp_path / "s.json"
    s.write_text('{"mount": "eye_in_hand", "samples": [{"T_base_flange": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}')
    with pytest.raises(CalibrationFileError, match=r"samples\[0\]: missing key T_cam_board"):
        load_samples(s)
    s.write_text('{"mount": "sideways", "samples": []}')
    with pytest.raises(CalibrationFileError, match="mount"):
        load_samples(s)


def test_cli_errors_are_messages(tmp_path, rng, capsys):
    F, C = synth.samples("eye_in_hand", 2, rng)
    samples = save_samples(tmp_path / "two.json", "eye_in_hand", F, C)
    assert main(["calibrate", "solve", str(samples), "--out", str(tmp_path / "o.yaml")]) == 2
    assert "too few samples" in capsys.readouterr().err
    assert main(["calibrate", "solve", "--out", str(tmp_path / "o.yaml")]) == 2
    assert "SAMPLES.json" in capsys.readouterr().err
    assert main(["calibrate", "--board-squares", "8by6", "--out", str(tmp_path / "b.png"), "board"]) == 2
    assert "--board-squares" in capsys.readouterr().err


def test_board_image_cli(tmp_path):
    import cv2

    out = tmp_path / "board.png"
    assert main(["calibrate", "board", "--out", str(out), "--dpi", "150"]) == 0
    img = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    from kitchenbot.calibration.board import BoardDetector, CharucoSpec

    ids, _, _ = BoardDetector(CharucoSpec()).detect(img)
    assert len(ids) == CharucoSpec().n_corners


def test_run_without_sim_on_fake_drivers_is_refused(tmp_path, capsys):
    assert main(["calibrate", "--out", str(tmp_path / "x.yaml")]) == 2
    assert "add --sim" in capsys.readouterr().err


def test_samples_with_corners_are_checked(tmp_path, rng):
    from kitchenbot.calibration.files import Corners, load_corners

    F, C = synth.samples("eye_in_hand", 3, rng)
    obj = [np.zeros((5, 3))] * 3
    p = save_samples(tmp_path / "s.json", "eye_in_hand", F, C,
                     corners=Corners(np.eye(3), None, obj, [np.zeros((5, 2))] * 3))
    got = load_corners(p)
    assert got is not None and len(got.image_points) == 3 and got.image_points[0].shape == (5, 2)
    assert load_corners(save_samples(tmp_path / "plain.json", "eye_in_hand", F, C)) is None
    p = save_samples(tmp_path / "bad.json", "eye_in_hand", F, C,
                     corners=Corners(np.eye(3), None, obj, [np.zeros((4, 2))] * 3))
    with pytest.raises(CalibrationFileError, match=r"bad.json: samples\[0\]: expected object_points"):
        load_corners(p)
