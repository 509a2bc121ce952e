"""Evaluation on scenes with distractors: a dishware pose on a box or a can is counted as a false positive on
that distractor, a right pose is not; --objects turns a dataset's other models into distractors."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np
import pytest

from kitchenbot.executive.config import load_config
from kitchenbot.fakes.bop import generate_dataset
from kitchenbot.perception import evaluate as ev
from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import make_T


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("bop_distractors")
    cfg = load_config()
    kw = {"T_flange_tcp": cfg.robot.tool.T_flange_tcp.matrix(), "T_flange_cam": cfg.T_flange_cam()}
    generate_dataset(out, 1, 3, [np.asarray(cfg.scan_waypoints[1])], kw, 640, 480, distractors=2)
    return out


@dataclass
class _Result:
    poses: list
    views: list
    pose_ms: list = field(default_factory=list)
    timings_ms: dict = field(default_factory=dict)
    pose_cpu_ms: list = field(default_factory=list)
    timings_cpu_ms: dict = field(default_factory=dict)
    rejected: int = 0
    surfaces_from: str = "cell"
    cell_check: object = None


def _scripted_perceiver(poses_for):
    """A Perceiver stand-in that answers with poses computed from the views' ground truth."""

    class Scripted:
        def __init__(self, settings, inventory, cell, database=None, use_cell=True):
            self.database, self.inventory = None, inventory

        def perceive(self, views, up=None):
            return _Result(poses_for(views, self.inventory), list(views), [1.0], {"pose": 1.0})

    return Scripted


def _gt(dataset):
    scene = dataset / "test" / "000000"
    gt = json.loads((scene / "scene_gt.json").read_text())["0"]
    cam = json.loads((scene / "scene_camera.json").read_text())["0"]
    T_cam_base = make_T(np.asarray(cam["cam_R_w2c"]).reshape(3, 3), np.asarray(cam["cam_t_w2c"]) / 1000)
    out = []
    for g in gt:
        T = make_T(np.asarray(g["cam_R_m2c"]).reshape(3, 3), np.asarray(g["cam_t_m2c"]) / 1000)
        out.append((g["obj_id"], np.linalg.inv(T_cam_base) @ T))
    return out


def test_a_pose_on_a_distractor_is_counted(dataset, monkeypatch):
    gts = _gt(dataset)
    inv_ids = {int(k) for k in json.loads((dataset / "models" / "models_info.json").read_text())}
    dishes = [(o, T) for o, T in gts if o in inv_ids]
    distractors = [(o, T) for o, T in gts if o not in inv_ids]
    assert dishes and distractors

    def poses(views, inventory):
        right = [ObjectPose(o, inventory[o].cls, T, 0.9) for o, T in dishes]
        # A cup "found" where a distractor is: centred on it, upright.
        cup = next(m for m in inventory if m.cls == "cup")
        wrong = ObjectPose(cup.obj_id, "cup", make_T(t=distractors[0][1][:3, 3]), 0.5)
        return right + [wrong]

    monkeypatch.setattr(ev, "Perceiver", _scripted_perceiver(poses))
    r = ev.evaluate(dataset, progress=False).report
    names = json.loads((dataset / "models_distractors" / "grasps.json").read_text())["objects"]
    assert r["false_positives_on_distractors"] == 1
    assert list(r["false_positives_on_distractors_by_name"]) == [names[str(distractors[0][0])]["name"]]
    assert r["false_positives"] >= 1 and r["adi_recall_0.1d"] > 0.9
    assert r["distractors"] >= 1 and r["false_positives_per_image"] == r["false_positives"] / r["images"]


def test_right_poses_alone_count_no_distractor(dataset, monkeypatch):
    gts = _gt(dataset)
    inv_ids = {int(k) for k in json.loads((dataset / "models" / "models_info.json").read_text())}

    def poses(views, inventory):
        return [ObjectPose(o, inventory[o].cls, T, 0.9) for o, T in gts if o in inv_ids]

    monkeypatch.setattr(ev, "Perceiver", _scripted_perceiver(poses))
    r = ev.evaluate(dataset, progress=False).report
    assert r["false_positives_on_distractors"] == 0 and r["false_positives"] == 0


def test_objects_option_makes_the_rest_distractors(dataset, monkeypatch):
    """With --objects, a right pose of a model left out of the inventory would be a false positive; here the
    perceiver (given the smaller inventory) reports only inventory objects, and the left-out ones count as
    distractors seen."""
    gts = _gt(dataset)
    inv_ids = sorted({int(k) for k in json.loads((dataset / "models" / "models_info.json").read_text())})
    present = sorted({o for o, _ in gts if o in inv_ids})
    keep = present[:1]

    def poses(views, inventory):
        assert sorted(inventory.models) == keep
        return [ObjectPose(o, inventory[o].cls, T, 0.9) for o, T in gts if o in keep]

    monkeypatch.setattr(ev, "Perceiver", _scripted_perceiver(poses))
    r = ev.evaluate(dataset, progress=False, object_ids=keep).report
    assert r["inventory"] == keep and r["false_positives"] == 0
    assert set(r["per_object"]) == {str(k) for k in keep}
    with pytest.raises(ValueError, match="--objects"):
        ev.evaluate(dataset, progress=False, object_ids=[999])


def test_cell_dataset_uses_each_scenes_own_cell(tmp_path, monkeypatch):
    """A wide scene's basin differs from the config's; --cell dataset hands the scene's own cell to perception."""
    cfg = load_config()
    kw = {"T_flange_tcp": cfg.robot.tool.T_flange_tcp.matrix(), "T_flange_cam": cfg.T_flange_cam()}
    generate_dataset(tmp_path, 1, 5, [np.asarray(cfg.scan_waypoints[1])], kw, 640, 480, variety="wide")
    meta = json.loads((tmp_path / "test" / "000000" / "scene_sim.json").read_text())
    assert tuple(meta["cell"]["sink"]["inner_size_xy"]) != tuple(cfg.cell.sink.inner_size_xy)
    cells = []

    class Recording:
        def __init__(self, settings, inventory, cell, database=None, use_cell=True):
            self.database = None
            cells.append(cell)

        def perceive(self, views, up=None):
            return _Result([], list(views), [], {})

    monkeypatch.setattr(ev, "Perceiver", Recording)
    ev.evaluate(tmp_path, progress=False, use_cell="dataset")
    assert tuple(cells[-1].spec.sink.inner_size_xy) == tuple(meta["cell"]["sink"]["inner_size_xy"])
    ev.evaluate(tmp_path, progress=False, use_cell="always")
    assert cells[-1].spec.sink.inner_size_xy == (0.50, 0.40)
    with pytest.raises(ValueError, match="--cell"):
        ev.evaluate(tmp_path, progress=False, use_cell="sometimes")


def test_a_right_estimate_of_an_object_seen_too_little_is_ignored_not_paired_with_another():
    """An estimate right about an item under the visibility floor is not matched to a visible item of its model
    (it would count as a wrong pose there and a false positive); one right about a visible item is matched."""
    from kitchenbot.world.inventory import Inventory

    inv = Inventory.builtin()
    m = next(x for x in inv if x.cls == "cup")
    pts = {x.obj_id: x.points for x in inv}
    hidden = make_T(np.eye(3), (0.0, 0.0, 0.6))
    seen = make_T(np.eye(3), (0.2, 0.0, 0.6))
    low, gt = [(m.obj_id, hidden)], [(m.obj_id, seen)]
    assert ev._right_about_only((m.obj_id, hidden, 1.0), low, gt, pts, inv)
    assert not ev._right_about_only((m.obj_id, seen, 1.0), low, gt, pts, inv)
    assert not ev._right_about_only((m.obj_id, hidden, 1.0), low, [(m.obj_id, hidden)], pts, inv)  # a visible one there
    other = next(x for x in inv if x.cls == "mug")
    assert not ev._right_about_only((other.obj_id, hidden, 1.0), low, gt, pts, inv)  # another model: not about it
