"""Backend registry, weight checks, point-encoder plug-ins, `kitchenbot models` and the model sweep (no model runs)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from kitchenbot.perception import backends, sweep
from kitchenbot.perception.backends import (CHECKPOINTS, BackendError, MissingWeightsError, backend_available,
                                            checkpoint_dir, learned_available)
from kitchenbot.perception.features import POINT_ENCODERS, ColourEncoder, FPFHEncoder, fuse_instance
from kitchenbot.perception.plugins import PluginError, load_point_encoder, point_encoder_names, register_point_encoder
from kitchenbot.perception.settings import PerceptionSettings

HERE = Path(__file__).parent
HAVE_TORCH = learned_available() is None


def _fake_checkpoint(root: Path, backend: str, model_type: str | None = None) -> Path:
    d = CHECKPOINTS[backend].path(root)
    d.mkdir(parents=True)
    (d / "config.json").write_text(json.dumps({"model_type": model_type or CHECKPOINTS[backend].model_types[0]}))
    (d / "model.safetensors").write_bytes(b"")
    if CHECKPOINTS[backend].needs_tokenizer:
        (d / "vocab.txt").write_text("[PAD]\n")
    return d


# ---- names and weights --------------------------------------------------------------------------------------
def test_unknown_names_list_the_choices():
    with pytest.raises(ValidationError, match="llmdet"):
        PerceptionSettings(detector="yolo")
    s = PerceptionSettings().model_copy(update={"detector": "yolo"})  # bypasses validation, as code could
    with pytest.raises(BackendError, match="geometric, llmdet, grounding-dino"):
        backends.make_detector(s, None)
    s = PerceptionSettings().model_copy(update={"image_encoder": "resnet"})
    with pytest.raises(BackendError, match="none, colour, dinov2, beit, clip"):
        backends.make_image_encoder(s)


def test_weight_free_defaults():
    from kitchenbot.perception.segment_geometric import GeometricSegmenter

    s = PerceptionSettings()
    det, seg = backends.make_detector(s, None)
    assert isinstance(det, GeometricSegmenter)
    assert isinstance(backends.make_image_encoder(s), ColourEncoder)
    assert backends.make_image_encoder(s.model_copy(update={"image_encoder": "none"})) is None
    assert isinstance(backends.make_point_encoder("fpfh"), FPFHEncoder)
    nf = backends.make_image_encoder(s.model_copy(update={"fusion": False}))
    assert nf.name == "colour+no-fusion" and nf.dim == ColourEncoder.dim


def test_missing_weights_error_names_checkpoint_layout_and_fetch(tmp_path):
    with pytest.raises(MissingWeightsError) as e:
        checkpoint_dir("grounding-dino", tmp_path)
    msg = str(e.value)
    for part in ("IDEA-Research/grounding-dino-tiny", str(tmp_path / "grounding-dino-tiny"), "config.json",
                 "model.safetensors", "tokenizer", "hf download IDEA-Research/grounding-dino-tiny --local-dir"):
        assert part in msg
    _fake_checkpoint(tmp_path, "sam2", model_type="bert")
    with pytest.raises(MissingWeightsError, match="model_type 'bert', expected 'sam2'"):
        checkpoint_dir("sam2", tmp_path)
    d = _fake_checkpoint(tmp_path, "dinov2")
    assert checkpoint_dir("dinov2", tmp_path) == d
    (d / "model.safetensors").unlink()
    with pytest.raises(MissingWeightsError, match="no model.safetensors"):
        checkpoint_dir("dinov2", tmp_path)


@pytest.mark.skipif(not HAVE_TORCH, reason="loading needs torch and transformers")
def test_corrupt_weights_fail_with_the_checkpoint_named(tmp_path):
    _fake_checkpoint(tmp_path, "clip", model_type="clip_vision_model")  # empty model.safetensors
    s = PerceptionSettings(weights_dir=str(tmp_path), image_encoder="clip")
    with pytest.raises(MissingWeightsError, match="openai/clip-vit-base-patch16.*from_pretrained failed"):
        backends.make_image_encoder(s)


def test_models_command_lists_backends_and_presence(tmp_path, capsys):
    from kitchenbot.executive.cli import main

    _fake_checkpoint(tmp_path, "dinov2")
    _fake_checkpoint(tmp_path, "beit", model_type="vit")
    assert main(["models", "--weights-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    lines = {ln.split()[1]: ln for ln in out.splitlines() if ln.startswith("  ") and len(ln.split()) > 2}
    for name in ("geometric", "llmdet", "grounding-dino", "sam2", "none", "colour", "dinov2", "beit", "clip", "fpfh"):
        assert name in lines, name
    assert "ready" in lines["colour"] and "MISSING" in lines["sam2"]
    assert str(tmp_path / "sam2.1-hiera-tiny") in lines["sam2"]
    assert ("ready" if HAVE_TORCH else "MISSING") in lines["dinov2"]
    assert "MISSING" in lines["beit"] and "model_type 'vit'" in out
    assert f"hf download facebook/sam2.1-hiera-tiny --local-dir {tmp_path / 'sam2.1-hiera-tiny'}" in out
    assert "hf download facebook/dinov2-small" not in out or not HAVE_TORCH


# ---- plug-ins -----------------------------------------------------------------------------------------------
@pytest.fixture
def plugin_path(monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    yield
    POINT_ENCODERS.pop("radial", None)


def _cloud():
    u, v = np.meshgrid(np.linspace(0, 0.05, 11), np.linspace(0, 0.05, 11))
    P = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], 1)
    return P, np.tile([0.0, 0, 1], (len(P), 1))


def test_plugin_by_module_class_string(plugin_path):
    enc = load_point_encoder("example_point_plugin:RadialHistogramEncoder")
    assert enc.name == "radial-hist" and enc.dim == 8
    P, N = _cloud()
    F = enc.encode(P, N, 0.005)
    assert F.shape == (len(P), 8)
    # a flat grid: every normal parallel, so all weight in the last normal bin; corners see fewer neighbours
    assert np.all(F[:, 7] > 0) and F[0, :4].sum() == pytest.approx(1.0)


def test_plugin_errors_are_clear(plugin_path):
    with pytest.raises(PluginError, match=r"returned shape \(117, 3\), expected \(117, 8\)"):
        load_point_encoder("example_point_plugin:BrokenEncoder")
    with pytest.raises(PluginError, match="cannot import module 'no_such_module'"):
        load_point_encoder("no_such_module:X")
    with pytest.raises(PluginError, match="has no attribute 'Nope'"):
        load_point_encoder("example_point_plugin:Nope")
    with pytest.raises(PluginError, match=r"unknown encoder 'gedi'; choose one of .*fpfh.*kitchenbot.point_encoders"):
        load_point_encoder("gedi")


def test_plugin_by_registration_and_entry_point(plugin_path, tmp_path, monkeypatch):
    from example_point_plugin import RadialHistogramEncoder

    register_point_encoder("radial", RadialHistogramEncoder)
    assert load_point_encoder("radial").name == "radial-hist"
    assert point_encoder_names()["radial"] == "registered"
    # an installed distribution advertising the plug-in in the entry-point group
    dist = tmp_path / "kb_example_plugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: kb-example-plugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[kitchenbot.point_encoders]\nradial-ep = example_point_plugin:RadialHistogramEncoder\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "radial-ep" in point_encoder_names()
    assert load_point_encoder("radial-ep").dim == 8


def test_plugin_in_the_perceiver_and_fusion(plugin_path, inventory):
    from kitchenbot.perception.pipeline import Perceiver

    p = Perceiver(PerceptionSettings(point_encoder="example_point_plugin:RadialHistogramEncoder"), inventory,
                  use_cell=False)
    assert p.pt_enc.name == "radial-hist"
    P, N = _cloud()
    rgb = np.full((10, 10, 3), 128, np.uint8)
    cloud = fuse_instance(P, np.zeros(len(P), int), np.zeros((len(P), 2), int), [rgb], [np.ones((10, 10), bool)],
                          np.array([[0.0, 0, 1]]), 0.005, p.img_enc, p.pt_enc)
    assert cloud.pts.shape[1] == 8 and cloud.fused.shape[1] == 8 + ColourEncoder.dim


# ---- the sweep ----------------------------------------------------------------------------------------------
def test_sweep_runs_available_combinations_and_reports_the_rest(tmp_path, monkeypatch):
    calls = []

    def fake_evaluate(dataset, settings, **kw):
        calls.append(settings)
        adi = 0.5 + 0.1 * settings.fusion + 0.01 * len(settings.image_encoder)

        class R:
            report = {"adi_recall_0.1d": adi, "auc_adds_10cm": adi - 0.05, "pose_ms_per_object_median": 12.0,
                      "scan_ms_median": 300.0, "objects": 4}
        return R()

    import kitchenbot.perception.evaluate as ev

    monkeypatch.setattr(ev, "evaluate", fake_evaluate)
    if HAVE_TORCH:
        _fake_checkpoint(tmp_path, "dinov2")
    s = PerceptionSettings(weights_dir=str(tmp_path))
    rows = sweep.run_sweep("DATASET", s, ["fpfh"], log=lambda *_: None, cell=None)
    ran = {(c.detector, c.segmenter, c.image_encoder, c.fusion) for c in calls}
    expect = {("geometric", "geometric", "none", False), ("geometric", "geometric", "colour", False),
              ("geometric", "geometric", "colour", True)}
    if HAVE_TORCH:
        expect |= {("geometric", "geometric", "dinov2", False), ("geometric", "geometric", "dinov2", True)}
    assert ran == expect
    assert len(rows) == 3 * 9 and sum(r.status == "ok" for r in rows) == len(expect)
    llm = next(r for r in rows if r.combo.detector == "llmdet")
    assert llm.status == "skipped" and "llmdet: " in llm.reason and "sam2: " in llm.reason
    md = sweep.table_markdown(rows, "t")
    head = next(ln for ln in md.splitlines() if ln.startswith("| Visual model"))
    assert head.split(" | ")[2:] == ["Geometric: fpfh", "LLMDet + SAM2: fpfh", "GroundingDINO + SAM2: fpfh |"]
    colour_fused = next(ln for ln in md.splitlines() if ln.startswith("| Colour | with fusion"))
    assert colour_fused == "| Colour | with fusion | 66.00 | skipped | skipped |"
    assert "| BEiT | without fusion | skipped | skipped | skipped |" in md
    assert "beit: weights missing" in md and "llmdet: weights missing" in md and "no CUDA timings" in md
    sweep.write_csv(rows, tmp_path / "t.csv")
    lines = (tmp_path / "t.csv").read_text().splitlines()
    assert len(lines) == 1 + 27 and lines[0].startswith("detector,segmenter,image_encoder,point_encoder,fusion,status")


def test_learned_boxes_filter_geometric_masks():
    from kitchenbot.perception.detect import Detection
    from kitchenbot.perception.hf_detectors import BoxFilteredGeometric

    a = np.zeros((100, 100), bool)
    a[10:30, 10:30] = True
    b = np.zeros((100, 100), bool)
    b[60:90, 50:95] = True

    class Geo:
        def detect(self, view):
            return [Detection(np.zeros(4), 1.0, a), Detection(np.zeros(4), 1.0, b)]

    seg = BoxFilteredGeometric(Geo())
    out = seg.segment(None, [Detection(np.array([5.0, 5, 25, 25]), 0.7, label="dishware")])  # 64 % of a inside
    assert len(out) == 1 and out[0].mask is a and out[0].score == 0.7 and out[0].label == "dishware"
    np.testing.assert_array_equal(out[0].box, [10, 10, 30, 30])
    assert seg.segment(None, [Detection(np.array([5.0, 5, 18, 18]), 0.7)]) == []  # 16 % inside: not this object
    assert seg.segment(None, []) == []
