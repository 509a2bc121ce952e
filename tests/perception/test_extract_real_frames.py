"""scripts/extract_real_frames.py on a BOP dataset in a folder and in a git directory (as `fetch` brings a
public repository): the chosen images show the dishware, the ground truth is cut to them, models are
decimated, SOURCE.md names the commit; the result is a BOP set `evaluate` reads with --objects."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from kitchenbot.executive.config import load_config
from kitchenbot.fakes.bop import generate_dataset
from kitchenbot.perception import bop
from kitchenbot.perception.evaluate import load_inventory

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "extract_real_frames.py"


def _script():
    spec = importlib.util.spec_from_file_location("extract_real_frames", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    out = tmp_path_factory.mktemp("src") / "ds"
    cfg = load_config()
    kw = {"T_flange_tcp": cfg.robot.tool.T_flange_tcp.matrix(), "T_flange_cam": cfg.T_flange_cam()}
    generate_dataset(out, 1, 3, [np.asarray(q) for q in cfg.scan_waypoints], kw, 640, 480, distractors=1)
    # The generator keeps distractor models apart; a BOP set has all its models in one folder.
    info = json.loads((out / "models" / "models_info.json").read_text())
    info.update(json.loads((out / "models_distractors" / "models_info.json").read_text()))
    (out / "models" / "models_info.json").write_text(json.dumps(info))
    for p in (out / "models_distractors").glob("*.ply"):
        shutil.copy(p, out / "models" / p.name)
    shutil.rmtree(out / "models_distractors")
    return out


def _dishware(source):
    gt = json.loads((source / "test" / "000000" / "scene_gt.json").read_text())
    inv_ids = {int(k) for k in json.loads((source / "models" / "models_info.json").read_text())}
    info = json.loads((source / "test" / "000000" / "scene_gt_info.json").read_text())
    best = {}
    for rec, inf in zip(gt["0"], info["0"]):
        if rec["obj_id"] in inv_ids:
            best[rec["obj_id"]] = max(best.get(rec["obj_id"], 0), inf["visib_fract"])
    return [max(best, key=best.get)]


def test_extract_from_a_folder(source, tmp_path):
    dish = _dishware(source)
    out = tmp_path / "real"
    mod = _script()
    assert mod.main([str(source), "--scene", "0", "--dishware", *map(str, dish), "--name", f"{dish[0]}=thing:cup",
                     "--images", "2", "--min-visib", "0.05", "--dishware-triangles", "500", "--out", str(out)]) == 0
    gt = json.loads((out / "test" / "000000" / "scene_gt.json").read_text())
    assert len(gt) == 2
    for k in gt:
        assert (out / "test" / "000000" / "rgb" / f"{int(k):06d}.png").is_file()
        assert (out / "test" / "000000" / "depth" / f"{int(k):06d}.png").is_file()
    ids = {r["obj_id"] for recs in gt.values() for r in recs}
    assert {int(p.stem[4:]) for p in (out / "models").glob("obj_*.ply")} == ids
    names = json.loads((out / "models" / "grasps.json").read_text())["objects"]
    assert names[str(dish[0])] == {"name": "thing", "class": "cup", "grasps": []}
    assert any(v["class"] == "distractor" for v in names.values())
    import open3d as o3d

    assert len(o3d.io.read_triangle_mesh(str(out / "models" / f"obj_{dish[0]:06d}.ply")).triangles) <= 520
    # evaluate reads it: the dishware is the inventory, the rest distractors.
    inv, others, _ = load_inventory(out, None, dish)
    assert sorted(inv.models) == dish and set(others) == ids - set(dish)
    images = bop.read_scene(out / "test" / "000000")
    assert len(bop.view_groups(images)) == 1  # world poses: one multi-view scan
    assert "commit: (a plain folder" in (out / "SOURCE.md").read_text()


def test_extract_from_a_git_directory(source, tmp_path):
    work = tmp_path / "repo"
    shutil.copytree(source, work / "data" / "bop")
    git = ["git", "-c", "user.email=t@t", "-c", "user.name=t"]
    subprocess.run(["git", "init", "-q", str(work)], check=True)
    subprocess.run([*git, "-C", str(work), "add", "-A"], check=True)
    subprocess.run([*git, "-C", str(work), "commit", "-qm", "data"], check=True)
    commit = subprocess.run(["git", "-C", str(work), "rev-parse", "HEAD"], capture_output=True, text=True,
                            check=True).stdout.strip()
    bare = tmp_path / "mirror.git"
    subprocess.run(["git", "clone", "-q", "--bare", str(work), str(bare)], check=True)
    dish = _dishware(source)
    out = tmp_path / "real"
    assert _script().main([str(bare), "--path", "data/bop", "--scene", "0", "--dishware", *map(str, dish),
                           "--image-ids", "1", "--repo", "someone/somewhere", "--licence", "CC BY 4.0",
                           "--out", str(out)]) == 0
    src = (out / "SOURCE.md").read_text()
    assert commit in src and "someone/somewhere" in src and "CC BY 4.0" in src
    assert "data/bop/test/000000/depth/000001.png" in src
    ref = (work / "data" / "bop" / "test" / "000000" / "depth" / "000001.png").read_bytes()
    assert (out / "test" / "000000" / "depth" / "000001.png").read_bytes() == ref


def test_a_source_without_depth_is_refused(source, tmp_path):
    nodepth = tmp_path / "nodepth"
    shutil.copytree(source, nodepth)
    shutil.rmtree(nodepth / "test" / "000000" / "depth")
    with pytest.raises(SystemExit, match="depth"):
        _script().main([str(nodepth), "--scene", "0", "--dishware", *map(str, _dishware(source)),
                        "--image-ids", "0", "--out", str(tmp_path / "o")])
