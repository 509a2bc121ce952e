"""Open-vocabulary detectors through `transformers`: LLMDet (``MMGroundingDinoForObjectDetection``, e.g.
iSEE-Laboratory/llmdet_tiny) and GroundingDINO (``GroundingDinoForObjectDetection``, IDEA-Research/
grounding-dino-tiny), prompted with one phrase (settings.prompt, "dishware" by default). Boxes only: the
segmenter (SAM2, or the geometric masks filtered by the boxes) makes the masks.

Preprocessing as the checkpoint's processor does it (shortest edge 800, longest at most 1333, ImageNet
mean/std, unless its preprocessor_config.json says otherwise), written with OpenCV because the default image
processors need torchvision. Post-processing: score of a query = max sigmoid logit over the prompt's
phrase tokens (special tokens and the final "." excluded), boxes (cx, cy, w, h normalised to the unpadded
image) to pixels, then score threshold, too-large boxes dropped and OpenCV NMS.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from kitchenbot.perception.backends import checkpoint_dir
from kitchenbot.perception.detect import Detection, box_of
from kitchenbot.perception.hf_common import load_model, load_tokenizer, mean_std, preprocessor_config, to_chw
from kitchenbot.perception.types import View


def resized_hw(h: int, w: int, shortest: int, longest: int) -> tuple[int, int]:
    """DETR-style resize: shortest edge to `shortest` unless the longest would pass `longest`."""
    s = shortest / min(h, w)
    if max(h, w) * s > longest:
        s = longest / max(h, w)
    return max(1, int(round(h * s))), max(1, int(round(w * s)))


def boxes_to_pixels(boxes_cxcywh: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N, 4) normalised (cx, cy, w, h) -> (N, 4) pixel (x0, y0, x1, y1), clipped to the image."""
    b = np.asarray(boxes_cxcywh, np.float64).reshape(-1, 4)
    cx, cy, bw, bh = b[:, 0] * width, b[:, 1] * height, b[:, 2] * width, b[:, 3] * height
    out = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], axis=1)
    out[:, [0, 2]] = out[:, [0, 2]].clip(0, width)
    out[:, [1, 3]] = out[:, [1, 3]].clip(0, height)
    return out


def select_boxes(scores: np.ndarray, boxes: np.ndarray, width: int, height: int, threshold: float, nms_iou: float,
                 max_detections: int, max_box_fraction: float, min_side: float = 4.0) -> list[int]:
    """Indices of the kept boxes (pixel xyxy), best first: threshold, size limits, NMS."""
    w = boxes[:, 2] - boxes[:, 0]
    h = boxes[:, 3] - boxes[:, 1]
    ok = (scores >= threshold) & (w >= min_side) & (h >= min_side) & (w * h <= max_box_fraction * width * height)
    idx = np.nonzero(ok)[0]
    if len(idx) == 0:
        return []
    xywh = [[float(boxes[i, 0]), float(boxes[i, 1]), float(w[i]), float(h[i])] for i in idx]
    keep = cv2.dnn.NMSBoxes(xywh, [float(scores[i]) for i in idx], float(threshold), float(nms_iou))
    keep = [int(idx[k]) for k in np.asarray(keep).reshape(-1)]
    keep.sort(key=lambda i: -scores[i])
    return keep[:max_detections]


class GroundedDetector:
    """A grounded (text-prompted) DETR detector from a local checkpoint folder; `detect_batch` runs all views
    of a scan in one forward pass."""

    def __init__(self, backend: str, folder: str | Path, prompt: str = "dishware", box_threshold: float = 0.3,
                 nms_iou: float = 0.5, max_detections: int = 30, max_box_fraction: float = 0.6,
                 device: str | None = None):
        import torch

        if backend not in ("llmdet", "grounding-dino"):
            raise ValueError(f"GroundedDetector: backend {backend!r} is not a detector (llmdet | grounding-dino)")
        if not prompt.strip():
            raise ValueError("perception.prompt: expected a phrase such as 'dishware', got an empty string")
        folder = Path(folder)
        self.backend = backend
        self.model = load_model(backend, folder, device)
        self.tokenizer = load_tokenizer(backend, folder)
        self.device = next(self.model.parameters()).device
        self.dtype = next(self.model.parameters()).dtype
        pp = preprocessor_config(folder)
        self.mean, self.std = mean_std(pp)
        size = pp.get("size") or {}
        self.shortest = int(size.get("shortest_edge", 800))
        self.longest = int(size.get("longest_edge", pp.get("max_size", 1333)))
        self.box_threshold, self.nms_iou = box_threshold, nms_iou
        self.max_detections, self.max_box_fraction = max_detections, max_box_fraction
        # GroundingDINO convention: lower case, phrases end with "."
        text = prompt.strip().lower()
        self.prompt = text if text.endswith(".") else text + "."
        self.text = self.tokenizer([self.prompt], return_tensors="pt")
        ids = self.text["input_ids"][0].tolist()
        special = set(self.tokenizer.all_special_ids)
        dot = self.tokenizer.convert_tokens_to_ids(".")
        self.phrase_tokens = np.array([i for i, t in enumerate(ids) if t not in special and t != dot], int)
        if len(self.phrase_tokens) == 0:
            raise ValueError(f"perception.prompt {prompt!r}: the tokenizer of {folder} gives no phrase tokens for it")
        self._torch = torch

    @classmethod
    def from_settings(cls, backend: str, settings) -> "GroundedDetector":
        return cls(backend, checkpoint_dir(backend, settings.weights_dir), prompt=settings.prompt)

    def detect(self, view: View) -> list[Detection]:
        return self.detect_batch([view])[0]

    def detect_batch(self, views: list[View]) -> list[list[Detection]]:
        torch = self._torch
        if not views:
            return []
        sizes = [resized_hw(v.rgb.shape[0], v.rgb.shape[1], self.shortest, self.longest) for v in views]
        Hm, Wm = max(s[0] for s in sizes), max(s[1] for s in sizes)
        px = np.zeros((len(views), 3, Hm, Wm), np.float32)
        pmask = np.zeros((len(views), Hm, Wm), np.int64)
        for k, (v, (h, w)) in enumerate(zip(views, sizes)):
            px[k, :, :h, :w] = to_chw(v.rgb, (h, w), self.mean, self.std)
            pmask[k, :h, :w] = 1
        text = {k: t.repeat(len(views), 1).to(self.device) for k, t in self.text.items()}
        with torch.inference_mode():
            out = self.model(pixel_values=torch.from_numpy(px).to(self.device, self.dtype),
                             pixel_mask=torch.from_numpy(pmask).to(self.device), **text)
            logits = out.logits.float().sigmoid().cpu().numpy()  # (B, Q, max_text_len)
            boxes = out.pred_boxes.float().cpu().numpy()  # (B, Q, 4) normalised to each unpadded image
        res = []
        for k, v in enumerate(views):
            H, W = v.rgb.shape[:2]
            scores = logits[k][:, self.phrase_tokens].max(axis=1)
            bx = boxes_to_pixels(boxes[k], W, H)
            keep = select_boxes(scores, bx, W, H, self.box_threshold, self.nms_iou, self.max_detections,
                                self.max_box_fraction)
            res.append([Detection(box=bx[i], score=float(scores[i]), mask=None, label=self.prompt.rstrip("."))
                        for i in keep])
        return res


class BoxFilteredGeometric:
    """Segmenter for a learned detector without SAM2: the geometric instance masks of the view, kept where at
    least `min_inside` of a mask lies in one detected box (that box's score is kept)."""

    def __init__(self, geometric, min_inside: float = 0.5):
        self.geometric = geometric
        self.min_inside = min_inside

    def segment(self, view: View, detections: list[Detection]) -> list[Detection]:
        if not detections:
            return []
        out = []
        for g in self.geometric.detect(view):
            if g.mask is None or not g.mask.any():
                continue
            area = g.mask.sum()
            best, score = 0.0, 0.0
            for d in detections:
                x0, y0, x1, y1 = np.round(d.box).astype(int)
                frac = g.mask[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)].sum() / area
                if frac > best:
                    best, score = frac, d.score
            if best >= self.min_inside:
                out.append(Detection(box=box_of(g.mask), score=score, mask=g.mask, label=detections[0].label))
        return out
