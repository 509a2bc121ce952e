"""Learned backends through the real adapter code, on tiny randomly initialised `transformers` models built from
configs and saved with `save_pretrained` into a temporary weights folder (no downloads)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="learned backends need torch (pip install torch==2.13.0)")
transformers = pytest.importorskip("transformers", reason="learned backends need transformers (pip install -e .[learned])")

from kitchenbot.perception.associate import associate  # noqa: E402
from kitchenbot.perception.backends import CHECKPOINTS, detect_and_segment, make_detector, make_image_encoder  # noqa: E402
from kitchenbot.perception.detect import Detection  # noqa: E402
from kitchenbot.perception.features import FPFHEncoder, fuse_instance, l2n  # noqa: E402
from kitchenbot.perception.hf_detectors import (BoxFilteredGeometric, GroundedDetector, boxes_to_pixels,  # noqa: E402
                                                 resized_hw, select_boxes)
from kitchenbot.perception.hf_encoders import ClassTokenOnly, HFImageEncoder, crop_sampling_grid, pad_to_square  # noqa: E402
from kitchenbot.perception.hf_sam2 import Sam2Segmenter, sam2_boxes, upsample_masks  # noqa: E402
from kitchenbot.perception.rgbd import backproject  # noqa: E402
from kitchenbot.perception.settings import PerceptionSettings  # noqa: E402
from kitchenbot.perception.types import View  # noqa: E402

VOCAB = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", ".", "dish", "##ware", "cup", "plate", "bowl", "a"]


def _detector(cls_cfg, cls_model, folder, tok):
    from transformers import BertConfig, SwinConfig

    sw = SwinConfig(image_size=224, embed_dim=16, depths=[1, 1, 1, 1], num_heads=[1, 1, 1, 1], window_size=7,
                    out_features=["stage2", "stage3", "stage4"])
    bc = BertConfig(vocab_size=len(VOCAB), hidden_size=32, num_hidden_layers=1, num_attention_heads=2,
                    intermediate_size=64)
    cfg = cls_cfg(backbone_config=sw, text_config=bc, d_model=32, encoder_layers=1, decoder_layers=2,
                  encoder_ffn_dim=64, decoder_ffn_dim=64, encoder_attention_heads=2, decoder_attention_heads=2,
                  num_queries=20)
    torch.manual_seed(0)
    cls_model(cfg).save_pretrained(folder)
    tok.save_pretrained(folder)
    (folder / "preprocessor_config.json").write_text(json.dumps(
        {"size": {"shortest_edge": 224, "longest_edge": 320}, "image_mean": [0.485, 0.456, 0.406],
         "image_std": [0.229, 0.224, 0.225]}))


def _sam2(folder):
    from transformers import (Sam2Config, Sam2HieraDetConfig, Sam2MaskDecoderConfig, Sam2Model,
                              Sam2PromptEncoderConfig, Sam2VisionConfig)

    bb = Sam2HieraDetConfig(hidden_size=16, num_attention_heads=1, blocks_per_stage=[1, 1, 2, 1],
                            embed_dim_per_stage=[16, 32, 64, 128], num_attention_heads_per_stage=[1, 1, 1, 1],
                            window_size_per_stage=[8, 4, 14, 7], global_attention_blocks=[3], image_size=[224, 224])
    vc = Sam2VisionConfig(backbone_config=bb, backbone_channel_list=[128, 64, 32, 16], fpn_hidden_size=32,
                          backbone_feature_sizes=[[56, 56], [28, 28], [14, 14]])
    pc = Sam2PromptEncoderConfig(hidden_size=32, image_size=224, patch_size=16)
    mc = Sam2MaskDecoderConfig(hidden_size=32, num_hidden_layers=1, num_attention_heads=1, mlp_dim=64,
                               iou_head_hidden_dim=32)
    torch.manual_seed(0)
    Sam2Model(Sam2Config(vision_config=vc, prompt_encoder_config=pc, mask_decoder_config=mc)).save_pretrained(folder)


def _encoders(root):
    from transformers import BeitConfig, BeitModel, CLIPVisionConfig, CLIPVisionModel, Dinov2Config, Dinov2Model

    small = dict(hidden_size=32, num_hidden_layers=1, num_attention_heads=2, intermediate_size=64, image_size=224)
    torch.manual_seed(0)
    Dinov2Model(Dinov2Config(patch_size=14, **small)).save_pretrained(root / CHECKPOINTS["dinov2"].folder)
    (root / CHECKPOINTS["dinov2"].folder / "preprocessor_config.json").write_text(json.dumps(
        {"crop_size": {"height": 224, "width": 224}, "resample": 3, "image_mean": [0.485, 0.456, 0.406],
         "image_std": [0.229, 0.224, 0.225]}))
    BeitModel(BeitConfig(patch_size=16, use_mean_pooling=True, **small)).save_pretrained(root / CHECKPOINTS["beit"].folder)
    CLIPVisionModel(CLIPVisionConfig(patch_size=16, **small)).save_pretrained(root / CHECKPOINTS["clip"].folder)


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    from transformers import (BertTokenizer, GroundingDinoConfig, GroundingDinoForObjectDetection,
                              MMGroundingDinoConfig, MMGroundingDinoForObjectDetection)

    root = tmp_path_factory.mktemp("weights")
    vocab = root / "vocab.txt"
    vocab.write_text("\n".join(VOCAB) + "\n")
    tok = BertTokenizer(str(vocab))
    _detector(MMGroundingDinoConfig, MMGroundingDinoForObjectDetection, root / CHECKPOINTS["llmdet"].folder, tok)
    _detector(GroundingDinoConfig, GroundingDinoForObjectDetection, root / CHECKPOINTS["grounding-dino"].folder, tok)
    _sam2(root / CHECKPOINTS["sam2"].folder)
    _encoders(root)
    return root


def _settings(weights, **kw) -> PerceptionSettings:
    return PerceptionSettings(weights_dir=str(weights), **kw)


K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])


def _plane_view(rgb=None, z=0.5) -> View:
    h, w = 240, 320
    if rgb is None:
        rgb = (np.random.default_rng(0).random((h, w, 3)) * 255).astype(np.uint8)
    return View(rgb, np.full((h, w), z, np.float32), K, np.eye(4))


# ---- detectors -----------------------------------------------------------------------------------------------
def test_box_postprocessing_is_pixel_exact():
    b = boxes_to_pixels(np.array([[0.5, 0.25, 0.2, 0.1], [0.99, 0.5, 0.2, 0.2]]), width=320, height=240)
    np.testing.assert_allclose(b[0], [128, 48, 192, 72])
    assert b[1, 2] == 320  # clipped at the right edge
    scores = np.array([0.9, 0.8, 0.2, 0.95])
    boxes = np.array([[10, 10, 50, 50], [12, 11, 51, 50], [100, 100, 140, 140], [0, 0, 320, 240]], float)
    # #1 is a duplicate of #0 (NMS), #2 is under the threshold, #3 covers the whole image (too large)
    assert select_boxes(scores, boxes, 320, 240, 0.3, 0.5, 10, 0.6) == [0]
    assert resized_hw(480, 640, 800, 1333) == (800, 1067)
    assert resized_hw(240, 2000, 800, 1333) == (160, 1333)


@pytest.mark.parametrize("backend", ["llmdet", "grounding-dino"])
def test_grounded_detector_from_settings(weights, backend):
    det, seg = make_detector(_settings(weights, detector=backend), cell=None)
    assert isinstance(det, GroundedDetector) and isinstance(seg, BoxFilteredGeometric)
    expected = {"llmdet": "MMGroundingDinoForObjectDetection", "grounding-dino": "GroundingDinoForObjectDetection"}
    assert type(det.model).__name__ == expected[backend]
    assert det.prompt == "dishware."
    # "[CLS] dish ##ware . [SEP]": the phrase is tokens 1 and 2 only
    assert det.phrase_tokens.tolist() == [1, 2]
    det.box_threshold = 0.0  # random weights: take what the model gives
    views = [_plane_view(), _plane_view(rgb=np.zeros((240, 320, 3), np.uint8))]
    out = det.detect_batch(views)
    assert len(out) == 2
    for dets in out:
        assert 0 < len(dets) <= det.max_detections
        for d in dets:
            x0, y0, x1, y1 = d.box
            assert 0 <= x0 < x1 <= 320 and 0 <= y0 < y1 <= 240 and 0.0 <= d.score <= 1.0
            assert d.mask is None and d.label == "dishware"
    # batching does not change a view's answer
    single = det.detect(views[0])
    np.testing.assert_allclose([d.box for d in single], [d.box for d in out[0]], atol=1e-3)


# ---- SAM2 ----------------------------------------------------------------------------------------------------
def test_sam2_coordinate_plumbing():
    np.testing.assert_allclose(sam2_boxes(np.array([[32, 24, 64, 48]]), (240, 320), 1024), [[102.4, 102.4, 204.8, 204.8]])
    low = np.full((1, 56, 56), -5.0, np.float32)
    low[0, 14:28, 28:42] = 5.0  # a blob in the low-res square logits: rows 1/4-1/2, cols 1/2-3/4
    m = upsample_masks(low, (240, 320))[0]
    assert m.shape == (240, 320)
    r, c = np.nonzero(m)
    assert abs(r.min() - 60) <= 3 and abs(r.max() - 119) <= 3 and abs(c.min() - 160) <= 4 and abs(c.max() - 239) <= 4


def test_sam2_boxes_to_masks_to_association(weights):
    det, seg = make_detector(_settings(weights, detector="grounding-dino", segmenter="sam2"), cell=None)
    assert isinstance(seg, Sam2Segmenter) and seg.size == 224
    view = _plane_view()
    boxes = [np.array([20.0, 30, 100, 90]), np.array([180.0, 120, 300, 220])]
    dets = [Detection(b, 0.9, label="dishware") for b in boxes]
    out = seg.segment(view, dets)  # random weights: real shapes and plumbing, arbitrary masks
    for d in out:
        assert d.mask.shape == (240, 320) and d.mask.dtype == bool
    # With every logit accepted the mask is exactly the prompt box (box clip, no margin): checks the resize
    # back to the image and the box clipping, and gives masks we can associate across two views.
    seg.mask_threshold, seg.box_margin = -1e9, 0.0
    v1 = seg.segment(view, dets)
    assert [int(d.mask.sum()) for d in v1] == [80 * 60, 120 * 100]
    assert v1[0].mask[30:90, 20:100].all() and not v1[0].mask[:, 100:].any()
    # view 2: same scene, detections listed the other way round; association must cross them over
    v2 = seg.segment_batch([view], [[dets[1], dets[0]]])[0]
    ids = associate([view, view], [v1, v2], iou_threshold=0.6)
    assert ids[0][0] == ids[1][1] and ids[0][1] == ids[1][0] and ids[0][0] != ids[0][1]
    # the pipeline's stage: all views through the detector and SAM2 in one batch each
    det.box_threshold, det.max_detections = 0.0, 3
    both = detect_and_segment(det, seg, [view, _plane_view(rgb=np.zeros((240, 320, 3), np.uint8))])
    assert [len(d) for d in both] == [3, 3]
    assert all(d.mask.shape == (240, 320) and d.mask.any() for ds in both for d in ds)


# ---- image encoders ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("backend,model_cls", [("dinov2", "Dinov2Model"), ("beit", "BeitModel"), ("clip", "CLIPVisionModel")])
def test_image_encoder_shapes(weights, backend, model_cls):
    enc = make_image_encoder(_settings(weights, image_encoder=backend))
    assert isinstance(enc, HFImageEncoder) and type(enc.model).__name__ == model_cls
    assert enc.dim == 32 and enc.input_size == 224
    assert enc.interp == (cv2.INTER_CUBIC if backend == "dinov2" else None)  # from preprocessor_config.json
    rng = np.random.default_rng(3)
    rgb = (rng.random((60, 90, 3)) * 255).astype(np.uint8)
    mask = np.zeros((60, 90), bool)
    mask[10:50, 5:80] = True
    cls, patches = enc.encode(rgb, mask)
    assert cls.shape == (32,) and abs(np.linalg.norm(cls) - 1) < 1e-5
    assert patches.shape == (224, 224, 32) and np.all(np.isfinite(patches))
    other = (rng.random((40, 40, 3)) * 255).astype(np.uint8)
    batch = enc.encode_batch([rgb, other], [mask, np.ones((40, 40), bool)])
    np.testing.assert_allclose(batch[0][0], cls, atol=1e-4)
    np.testing.assert_allclose(batch[0][1], patches, atol=1e-3)
    # without fusion: same class token, patch tokens carry nothing
    nf = ClassTokenOnly(enc)
    c2, p2 = nf.encode(rgb, mask)
    np.testing.assert_allclose(c2, cls, atol=1e-5)
    assert p2.shape == (1, 1, 32) and np.ptp(p2) == 0 and nf.name != enc.name


def test_encoder_crops_to_the_mask_itself(weights):
    """A whole render with the object in a corner gives the same tokens as the tight crop around it."""
    enc = make_image_encoder(_settings(weights, image_encoder="dinov2"))
    rng = np.random.default_rng(5)
    full = (rng.random((160, 160, 3)) * 255).astype(np.uint8)
    mask = np.zeros((160, 160), bool)
    mask[20:80, 90:150] = True
    c_full, p_full = enc.encode(full, mask)
    c_crop, p_crop = enc.encode(full[20:80, 90:150], mask[20:80, 90:150])
    np.testing.assert_allclose(c_full, c_crop, atol=1e-5)
    # the token at a masked pixel, looked up as fuse_instance / the database do: pixel (50, 120) of the render
    # is pixel (30, 30) of the crop; grids of 224 cells over 160 resp. 60 pixels
    t_full = p_full[50 * 224 // 160, 120 * 224 // 160]
    t_crop = p_crop[30 * 224 // 60, 30 * 224 // 60]
    other = p_full[75 * 224 // 160, 95 * 224 // 160]  # another masked pixel, for scale
    same, diff = np.dot(l2n(t_full), l2n(t_crop)), np.dot(l2n(other), l2n(t_crop))
    assert same > 0.97 and diff < same - 0.1


def test_sampling_grid_covers_the_crop_inside_the_square():
    sq, m, (L, r0, c0) = pad_to_square(np.full((20, 60, 3), 200, np.uint8), np.ones((20, 60), bool))
    assert (L, r0, c0) == (60, 20, 0) and sq[:20].max() == 0 and sq[20:40].min() == 200
    g = crop_sampling_grid(20, 60, L, r0, c0, 4).numpy()[0]
    # first cell centre: crop pixel (2.5, 7.5) -> square (22.5, 7.5) -> normalised
    np.testing.assert_allclose(g[0, 0], [2 * 7.5 / 60 - 1, 2 * 22.5 / 60 - 1], atol=1e-6)
    np.testing.assert_allclose(g[-1, -1], [2 * 52.5 / 60 - 1, 2 * 37.5 / 60 - 1], atol=1e-6)


class _PatchColour(torch.nn.Module):
    """A stand-in ViT whose patch token is the mean normalised colour of its patch (+ a constant channel), so
    what a token says about the image is known; class token = mean of the patch tokens."""

    def __init__(self, config):
        super().__init__()
        self.config = config
        self.w = torch.nn.Parameter(torch.zeros(1))

    def forward(self, pixel_values):
        p = self.config.patch_size
        t = torch.nn.functional.avg_pool2d(pixel_values, p).flatten(2).transpose(1, 2)  # (B, g*g, 3)
        t = torch.cat([t, torch.full_like(t[..., :1], 3.0)], -1)
        t = torch.nn.functional.pad(t, (0, self.config.hidden_size - 4))
        tokens = torch.cat([t.mean(1, keepdim=True), t], 1)
        return transformers.modeling_outputs.BaseModelOutputWithPooling(last_hidden_state=tokens, pooler_output=None)


def test_patch_tokens_land_in_the_right_voxels(weights):
    """An object crop whose left 30 % is red and the rest blue: after the real preprocessing (background
    removal, square padding, resize), token resampling, PCA and back-projection through fuse_instance, the
    3D points from the red part carry the red token and those from the blue part the blue one."""
    enc = make_image_encoder(_settings(weights, image_encoder="dinov2"))
    enc.model = _PatchColour(enc.model.config)
    h, w = 240, 320
    rgb = np.zeros((h, w, 3), np.uint8)
    mask = np.zeros((h, w), bool)
    mask[100:150, 60:260] = True  # a wide, flat object: the square padding is mostly above and below
    split = 60 + 60  # columns 60..119 red, 120..259 blue
    rgb[:, :split] = (255, 0, 0)
    rgb[:, split:] = (0, 0, 255)
    view = _plane_view(rgb)
    pts, rc = backproject(view, mask)
    cloud = fuse_instance(pts, np.zeros(len(pts), int), rc, [rgb], [mask], np.zeros((1, 3)), 0.004, enc, FPFHEncoder())
    norm = lambda c: (np.asarray(c) / 255.0 - enc.mean.ravel()) / enc.std.ravel()  # noqa: E731
    red = l2n(np.r_[norm((255, 0, 0)), 3.0, np.zeros(enc.dim - 4)])
    blue = l2n(np.r_[norm((0, 0, 255)), 3.0, np.zeros(enc.dim - 4)])
    col = cloud.points[:, 0] / cloud.points[:, 2] * K[0, 0] + K[0, 2]  # image column of each voxel centre
    row = cloud.points[:, 1] / cloud.points[:, 2] * K[1, 1] + K[1, 2]
    tokens_px = 200 / (224 // 14)  # one token spans ~12.5 crop pixels; stay 2 tokens away from the boundary
    # rows within one token of the crop's top/bottom edge mix with the black padding (bilinear): leave them out
    inner = (row > 100 + tokens_px) & (row < 150 - tokens_px)
    is_red = inner & (col < split - 2 * tokens_px)
    is_blue = inner & (col > split + 2 * tokens_px)
    assert is_red.sum() > 20 and is_blue.sum() > 20
    assert np.all(cloud.img[is_red] @ red > 0.99) and np.all(cloud.img[is_red] @ blue < 0.9)
    assert np.all(cloud.img[is_blue] @ blue > 0.99) and np.all(cloud.img[is_blue] @ red < 0.9)
    # the boundary in 3D sits where it is in the image (within a token)
    mixed = inner & ((cloud.img @ red) > (cloud.img @ blue))
    edge = col[mixed].max()
    assert abs(edge - split) < tokens_px


def test_learned_backends_in_the_perceiver(weights, inventory):
    from kitchenbot.perception.pipeline import Perceiver

    p = Perceiver(_settings(weights, detector="llmdet", segmenter="sam2", image_encoder="clip", fusion=False), inventory,
                  use_cell=False)
    assert isinstance(p.detector, GroundedDetector) and isinstance(p.segmenter, Sam2Segmenter)
    assert isinstance(p.img_enc, ClassTokenOnly) and p.img_enc.inner.backend == "clip"
