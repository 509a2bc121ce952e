"""SAM2 (``Sam2Model``, e.g. facebook/sam2.1-hiera-tiny) prompted with the detector's boxes -> instance masks.

`transformers` has no PIL/NumPy processor for SAM2, so the preprocessing is written here, following
``Sam2ImageProcessor`` / ``Sam2Processor`` exactly (unlike SAM 1, SAM2 does *not* keep the aspect ratio: the
image is resized to the model's square input, 1024 x 1024 for the released checkpoints):
  image  -> resize to S x S (bilinear), /255, ImageNet mean/std;
  boxes  -> x * S / W, y * S / H (pixel xyxy in the resized image);
  masks  <- low-resolution mask logits (S/4 square) bilinearly resized straight to H x W, threshold 0.
Each mask is then clipped to its prompt box (grown by a margin): SAM answers for the box it was given, and
pixels far outside it are leakage into neighbouring dishes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kitchenbot.perception.detect import Detection, box_of
from kitchenbot.perception.hf_common import load_model, mean_std, preprocessor_config, to_chw
from kitchenbot.perception.types import View


def sam2_boxes(boxes_xyxy: np.ndarray, image_hw: tuple[int, int], size: int) -> np.ndarray:
    """Pixel boxes of the original image -> pixel boxes of the S x S model input."""
    H, W = image_hw
    b = np.asarray(boxes_xyxy, np.float64).reshape(-1, 4).copy()
    b[:, [0, 2]] *= size / W
    b[:, [1, 3]] *= size / H
    return b


def upsample_masks(logits: np.ndarray, image_hw: tuple[int, int], threshold: float = 0.0) -> np.ndarray:
    """(N, h, w) mask logits -> (N, H, W) bool masks of the original image."""
    import torch

    t = torch.from_numpy(np.asarray(logits, np.float32))[:, None]
    up = torch.nn.functional.interpolate(t, size=tuple(image_hw), mode="bilinear", align_corners=False)
    return (up[:, 0] > threshold).numpy()


def clip_to_boxes(masks: np.ndarray, boxes_xyxy: np.ndarray, margin: float) -> np.ndarray:
    """Masks with everything outside their box (grown by `margin` x its size on each side) removed."""
    out = np.zeros_like(masks)
    H, W = masks.shape[1:]
    for k, (x0, y0, x1, y1) in enumerate(np.asarray(boxes_xyxy, float)):
        mx, my = margin * (x1 - x0), margin * (y1 - y0)
        c0, c1 = int(max(0, np.floor(x0 - mx))), int(min(W, np.ceil(x1 + mx)))
        r0, r1 = int(max(0, np.floor(y0 - my))), int(min(H, np.ceil(y1 + my)))
        out[k, r0:r1, c0:c1] = masks[k, r0:r1, c0:c1]
    return out


class Sam2Segmenter:
    """Box-prompted SAM2 from a local checkpoint folder: all boxes of a view in one decoder pass, the image
    encoder batched over views in `segment_batch`."""

    def __init__(self, folder: str | Path, device: str | None = None, mask_threshold: float = 0.0,
                 box_margin: float = 0.1, min_pixels: int = 50):
        import torch

        folder = Path(folder)
        self.model = load_model("sam2", folder, device)
        self.device = next(self.model.parameters()).device
        self.dtype = next(self.model.parameters()).dtype
        self.size = int(np.ravel(self.model.config.prompt_encoder_config.image_size)[0])
        self.mean, self.std = mean_std(preprocessor_config(folder))
        self.mask_threshold, self.box_margin, self.min_pixels = mask_threshold, box_margin, min_pixels
        self._torch = torch

    def segment(self, view: View, detections: list[Detection]) -> list[Detection]:
        return self.segment_batch([view], [detections])[0]

    def segment_batch(self, views: list[View], detections: list[list[Detection]]) -> list[list[Detection]]:
        torch = self._torch
        todo = [k for k, d in enumerate(detections) if d]
        out: list[list[Detection]] = [[] for _ in views]
        if not todo:
            return out
        S = self.size
        x = np.stack([to_chw(views[k].rgb, (S, S), self.mean, self.std) for k in todo])
        with torch.inference_mode():
            emb = self.model.get_image_embeddings(torch.from_numpy(x).to(self.device, self.dtype))
            for j, k in enumerate(todo):
                v, dets = views[k], detections[k]
                hw = v.rgb.shape[:2]
                boxes = sam2_boxes(np.stack([d.box for d in dets]), hw, S)
                res = self.model(image_embeddings=[e[j:j + 1] for e in emb],
                                 input_boxes=torch.from_numpy(boxes[None]).to(self.device, self.dtype),
                                 multimask_output=False)
                logits = res.pred_masks[0, :, 0].float().cpu().numpy()  # (N, S/4, S/4)
                masks = clip_to_boxes(upsample_masks(logits, hw, self.mask_threshold), np.stack([d.box for d in dets]),
                                      self.box_margin)
                for d, m in zip(dets, masks):
                    if m.sum() >= self.min_pixels:
                        out[k].append(Detection(box=box_of(m), score=d.score, mask=m, label=d.label))
        return out
