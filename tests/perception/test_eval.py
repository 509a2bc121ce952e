"""End to end on a small generated BOP dataset: `kitchenbot eval` writes a BOP CSV, a report and overlays,
and the default pipeline clears a recall floor."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from kitchenbot.executive.cli import main
from kitchenbot.executive.config import load_config
from kitchenbot.fakes.bop import generate_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("bop")
    cfg = load_config()
    kwargs = {"T_flange_tcp": cfg.robot.tool.T_flange_tcp.matrix(), "T_flange_cam": cfg.T_flange_cam()}
    generate_dataset(out, 2, 1000, [np.asarray(q) for q in cfg.scan_waypoints], kwargs, 640, 480)
    return out


def test_eval_cli_on_a_generated_dataset(dataset, tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))  # the CAD cache goes under ~/.cache
    res, rep, ov = tmp_path / "r.csv", tmp_path / "r.json", tmp_path / "ov"
    rc = main(["eval", str(dataset), "--results", str(res), "--report", str(rep), "--overlays", str(ov),
               "--overlay-scenes", "0", "--no-progress"])
    assert rc == 0
    r = json.loads(rep.read_text())
    for key in ("adi_recall_0.1d", "auc_adds_10cm", "per_object", "false_positives", "timing_median_ms",
                "objects", "scenes", "rejected", "surfaces_from", "cell_misfits", "timing_cpu_median_ms",
                "pose_cpu_ms_per_object_median", "map_seg_cpu_ms_per_scan_median"):
        assert key in r
    # --cell auto (the default): the shipped cell fits the generated scans and is used for both
    assert r["cell"] == "auto" and r["surfaces_from"] == {"cell": 2} and r["cell_misfits"] == []
    assert r["scenes"] == 2 and r["images"] == 6 and r["objects"] >= 6
    assert r["adi_recall_0.1d"] >= 0.8, r
    assert 0.5 < r["auc_adds_10cm"] <= 1.0
    rows = list(csv.DictReader(res.open()))
    assert rows and list(rows[0]) == ["scene_id", "im_id", "obj_id", "score", "R", "t", "time"]
    for row in rows:
        R = np.array(row["R"].split(), float).reshape(3, 3)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-4)
        t = np.array(row["t"].split(), float)
        assert 100 < t[2] < 2000  # mm, in front of the camera
    assert len(list(ov.glob("*.png"))) == 3
    assert (tmp_path / ".cache" / "kitchenbot" / "cad").is_dir()


def test_eval_cli_names_a_missing_dataset(tmp_path, capsys):
    assert main(["eval", str(tmp_path / "nope")]) == 2
    assert "nope" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["eval", str(tmp_path / "empty")]) == 2
    assert "models_info.json" in capsys.readouterr().err
