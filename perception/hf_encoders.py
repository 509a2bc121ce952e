"""Learned image encoders Phi (paper Alg. 1): DINOv2, BEiT, CLIP through `transformers`, giving a class token
and patch tokens of an instance crop, in the ``ImageEncoder`` protocol of features.py.

Per crop (Alg. 1 lines 3-6): background removed (pixels outside the mask set to black), the crop padded to a
square (so the model sees the object undistorted) and resized straight to the model's input size (no centre
crop, which would cut the object; interpolation and mean/std from the checkpoint), one batched forward
pass, then the patch-token grid is resampled onto a 224 x 224 grid covering exactly the crop (bilinear,
`torch.nn.functional.grid_sample`), so patch (i, j) of the result covers crop pixels
[i*H/224, (i+1)*H/224) x [j*W/224, (j+1)*W/224) as the protocol says, and reduced by PCA.

PCA: the principal axes of one crop's tokens differ from crop to crop (order and sign are arbitrary), so
PCA *coordinates* of a query crop could not be compared with those of a CAD render. We therefore keep the
rank-k PCA *reconstruction* (mean + projection onto the top k axes of the object's own tokens): the same
denoising, in a feature space shared by every crop.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from kitchenbot.perception.features import ImageEncoder, l2n
from kitchenbot.perception.hf_common import (IMAGENET_MEAN, IMAGENET_STD, load_model, mean_std, preprocessor_config,
                                             resample_flag, to_chw)

CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
FAMILY_NORM = {"dinov2": (IMAGENET_MEAN, IMAGENET_STD), "beit": ((0.5,) * 3, (0.5,) * 3), "clip": (CLIP_MEAN, CLIP_STD)}


def pad_to_square(rgb: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    """Background-removed crop centred in a black square; also the mask there and (side, row0, col0)."""
    H, W = mask.shape
    L = max(H, W)
    r0, c0 = (L - H) // 2, (L - W) // 2
    sq = np.zeros((L, L, 3), np.uint8)
    sq[r0:r0 + H, c0:c0 + W] = np.where(mask[..., None], rgb, 0)
    m = np.zeros((L, L), bool)
    m[r0:r0 + H, c0:c0 + W] = mask
    return sq, m, (L, r0, c0)


def crop_sampling_grid(H: int, W: int, side: int, r0: int, c0: int, out: int):
    """grid_sample coordinates ((1, out, out, 2), x then y in [-1, 1] of the padded square) at the centres of
    an out x out grid of cells covering the H x W input whose pixel (0, 0) lands at (r0, c0) of the square
    (negative when the square holds only a crop of the input)."""
    import torch

    ys = (np.arange(out) + 0.5) * H / out + r0
    xs = (np.arange(out) + 0.5) * W / out + c0
    gy, gx = np.meshgrid(2 * ys / side - 1, 2 * xs / side - 1, indexing="ij")
    return torch.from_numpy(np.stack([gx, gy], -1)[None].astype(np.float32))


def pca_reconstruct(tokens: np.ndarray, weights: np.ndarray, rank: int) -> np.ndarray:
    """Rank-`rank` PCA reconstruction of (N, D) tokens; axes fitted on the tokens with weight > 0 (weighted)."""
    fit = weights > 0
    if rank <= 0 or fit.sum() <= rank:
        return tokens
    X = tokens[fit]
    w = weights[fit, None] / weights[fit].sum()
    mu = (X * w).sum(axis=0)
    Xw = (X - mu) * np.sqrt(w)  # (n, D), n = patches (256) < D (384-1024)
    # Principal axes from the small n x n Gram matrix (eigh) instead of an SVD of the n x D matrix: same axes,
    # ~50x cheaper here. Axes with (numerically) zero variance are dropped.
    lam, U = np.linalg.eigh(Xw @ Xw.T)
    top = np.argsort(lam)[::-1][:rank]
    top = top[lam[top] > 1e-12 * max(lam.max(), 1e-300)]
    V = (Xw.T @ U[:, top]) / np.sqrt(lam[top])  # (D, k) orthonormal
    return mu + ((tokens - mu) @ V) @ V.T


class HFImageEncoder:
    """DINOv2 / BEiT / CLIP vision tower from a local checkpoint folder."""

    def __init__(self, backend: str, folder: str | Path, device: str | None = None, pca_rank: int = 32,
                 out_size: int = 224, input_size: int | None = None):
        import torch

        if backend not in FAMILY_NORM:
            raise ValueError(f"HFImageEncoder: backend {backend!r} is not an image encoder (have {sorted(FAMILY_NORM)})")
        folder = Path(folder)
        self.backend = backend
        self.model = load_model(backend, folder, device)
        self.device = next(self.model.parameters()).device
        self.dtype = next(self.model.parameters()).dtype
        cfg = self.model.config
        pp = preprocessor_config(folder)
        self.mean, self.std = mean_std(pp, FAMILY_NORM[backend])
        self.interp = resample_flag(pp)  # e.g. bicubic for DINOv2 and CLIP
        self.patch = int(cfg.patch_size)
        size = input_size or _pp_size(pp) or 224
        self.input_size = max(self.patch, (size // self.patch) * self.patch)
        self.prefix = 1 + int(getattr(cfg, "num_register_tokens", 0) or 0)  # class token (+ registers)
        self.dim = int(cfg.hidden_size)
        self.pca_rank = pca_rank
        self.out_size = out_size
        digest = hashlib.sha1((folder / "config.json").read_bytes()).hexdigest()[:8]
        # The CAD database cache is keyed by this name: it changes with the checkpoint and the settings.
        self.name = f"{backend}:{folder.name}:{digest}:pca{pca_rank}:{self.input_size}"
        self._torch = torch

    def encode(self, rgb: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.encode_batch([rgb], [mask])[0]

    def encode_batch(self, rgbs: list[np.ndarray], masks: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
        """(class token (D,) L2-normalised, patch tokens (224, 224, D)) per crop; one forward pass for all."""
        torch = self._torch
        if not rgbs:
            return []
        S, g = self.input_size, self.input_size // self.patch
        batch, geo, pmask = [], [], []
        for k, (rgb, mask) in enumerate(zip(rgbs, masks)):
            mask = np.asarray(mask, bool)
            if rgb.shape[:2] != mask.shape:
                raise ValueError(f"encode: crop {k} rgb {rgb.shape[:2]} and mask {mask.shape} differ in size")
            # Tight crop around the mask whatever the caller passed (a crop, or a whole CAD render), so query
            # crops and database renders show the object at the same scale.
            rows, cols = np.nonzero(mask)
            r0, r1, c0, c1 = (rows.min(), rows.max() + 1, cols.min(), cols.max() + 1) if len(rows) else \
                (0, mask.shape[0], 0, mask.shape[1])
            sq, m, (L, pr, pc) = pad_to_square(rgb[r0:r1, c0:c1], mask[r0:r1, c0:c1])
            batch.append(to_chw(sq, (S, S), self.mean, self.std, self.interp))
            geo.append((mask.shape, (L, pr - r0, pc - c0)))  # input pixel (y, x) -> square (y + pr - r0, ...)
            # fraction of each patch inside the mask: weights for the PCA fit
            pmask.append(cv2_area(m.astype(np.float32), g))
        x = torch.from_numpy(np.stack(batch)).to(self.device, self.dtype)
        with torch.inference_mode():
            out = self.model(pixel_values=x)
            tokens = out.last_hidden_state
            pooled = getattr(out, "pooler_output", None)
            cls = pooled if pooled is not None and pooled.shape[-1] == tokens.shape[-1] else tokens[:, 0]
            patches = tokens[:, self.prefix:self.prefix + g * g].float().cpu().numpy()
        cls = cls.float().cpu().numpy()
        results = []
        for k in range(len(rgbs)):
            P = pca_reconstruct(patches[k].astype(np.float64), pmask[k].reshape(-1), self.pca_rank)
            grid = torch.from_numpy(P.reshape(g, g, -1).transpose(2, 0, 1)[None].astype(np.float32))
            (H, W), (L, r0, c0) = geo[k]
            samp = crop_sampling_grid(H, W, L, r0, c0, self.out_size)
            up = torch.nn.functional.grid_sample(grid, samp, mode="bilinear", padding_mode="border", align_corners=False)
            results.append((l2n(cls[k]), up[0].permute(1, 2, 0).numpy()))
        return results


def cv2_area(m: np.ndarray, g: int) -> np.ndarray:
    import cv2

    return cv2.resize(m, (g, g), interpolation=cv2.INTER_AREA)


def _pp_size(pp: dict) -> int | None:
    """Model input side from a preprocessor config: crop_size, else size (height / shortest_edge)."""
    for key in ("crop_size", "size"):
        v = pp.get(key)
        if isinstance(v, int):
            return v
        if isinstance(v, dict):
            for k in ("height", "shortest_edge"):
                if isinstance(v.get(k), int):
                    return v[k]
    return None


class ClassTokenOnly:
    """An image encoder used for candidate proposal only (the paper's "without fusion"): class tokens as the
    wrapped encoder gives them, patch tokens one constant vector. The image block of every fused feature is
    then the same, which leaves every feature distance unchanged (|[c, a] - [c, b]| = |a - b|): registration
    matches on point features alone while the proposal still uses the image class tokens."""

    def __init__(self, inner: ImageEncoder):
        self.inner = inner
        self.dim = inner.dim
        self.name = f"{inner.name}+no-fusion"

    def encode(self, rgb: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cls, _ = self.inner.encode(rgb, mask)
        return cls, np.full((1, 1, self.dim), 1.0 / np.sqrt(self.dim), np.float32)
