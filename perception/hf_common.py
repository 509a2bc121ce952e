"""Shared plumbing for the `transformers` backends: device and precision, loading a model from a local folder
with a clear error, reading the checkpoint's preprocessing numbers, and image -> tensor.

The default `transformers` image processors need torchvision, which has no usable CPU build here, so the
preprocessing (resize, rescale, normalise) is done with OpenCV/NumPy from the numbers in the checkpoint's
``preprocessor_config.json`` (with each model family's published defaults when that file is absent).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from kitchenbot.perception.backends import CHECKPOINTS, MissingWeightsError, weights_error

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def device_and_dtype(device: str | None = None):
    """CUDA in half precision when available, else CPU in float32."""
    import torch

    if device is None:
        device = "cuda" if torch.cuda.is_available() else "cpu"
    dtype = torch.float16 if str(device).startswith("cuda") else torch.float32
    return torch.device(device), dtype


def load_model(backend: str, folder: Path, device: str | None = None):
    """`<model_class>.from_pretrained(folder)` in eval mode on the chosen device; errors name the checkpoint."""
    import transformers

    ck = CHECKPOINTS[backend]
    cls = getattr(transformers, ck.model_class)
    dev, dtype = device_and_dtype(device)
    try:
        model = cls.from_pretrained(str(folder), local_files_only=True, dtype=dtype)
    except Exception as e:  # noqa: BLE001 - safetensors/torch raise their own types for broken files
        raise weights_error(ck, folder.parent, f"{ck.model_class}.from_pretrained failed: {type(e).__name__}: {e}") from e
    return model.to(dev).eval()


def load_tokenizer(backend: str, folder: Path):
    from transformers import AutoTokenizer

    ck = CHECKPOINTS[backend]
    try:
        return AutoTokenizer.from_pretrained(str(folder), local_files_only=True)
    except Exception as e:  # noqa: BLE001 - tokenizers raise their own types for broken files
        raise weights_error(ck, folder.parent, f"the tokenizer did not load: {type(e).__name__}: {e}") from e


def preprocessor_config(folder: Path) -> dict[str, Any]:
    p = folder / "preprocessor_config.json"
    if not p.is_file():
        return {}
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise MissingWeightsError(f"{p}: not valid JSON ({e})") from e


def mean_std(pp: dict[str, Any], default=(IMAGENET_MEAN, IMAGENET_STD)) -> tuple[np.ndarray, np.ndarray]:
    mean = np.asarray(pp.get("image_mean", default[0]), np.float32).reshape(1, 1, 3)
    std = np.asarray(pp.get("image_std", default[1]), np.float32).reshape(1, 1, 3)
    return mean, std


# PIL resample codes in preprocessor_config.json -> OpenCV flags
_RESAMPLE = {0: cv2.INTER_NEAREST, 1: cv2.INTER_LANCZOS4, 2: cv2.INTER_LINEAR, 3: cv2.INTER_CUBIC}


def resample_flag(pp: dict[str, Any]) -> int | None:
    """The OpenCV interpolation matching the checkpoint's `resample` (None: bilinear / area)."""
    return _RESAMPLE.get(pp.get("resample")) if isinstance(pp.get("resample"), int) else None


def to_chw(rgb: np.ndarray, size_hw: tuple[int, int], mean: np.ndarray, std: np.ndarray,
           interp: int | None = None) -> np.ndarray:
    """uint8 (H, W, 3) -> float32 (3, h, w): resize (`interp`, default bilinear or area when shrinking), /255,
    normalise."""
    h, w = size_hw
    if interp is None:
        interp = cv2.INTER_AREA if (h < rgb.shape[0] and w < rgb.shape[1]) else cv2.INTER_LINEAR
    x = cv2.resize(np.ascontiguousarray(rgb, np.uint8), (w, h), interpolation=interp).astype(np.float32) / 255.0
    return ((x - mean) / std).transpose(2, 0, 1)
