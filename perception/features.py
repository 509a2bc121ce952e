"""2D-3D feature fusion for one instance (paper Alg. 1).

For each view: crop the instance (background removed), run the image encoder Phi -> class token + patch
tokens, lift the patch tokens to 3D through the depth and camera pose. Pool per voxel (size v), compute point
features Psi on the voxel centres, L2-normalise both and concatenate: F = [F_img/|F_img| || F_pts/|F_pts|].

Default encoders need no weights: ``ColourEncoder`` (soft hue/saturation/value histogram per pixel, class
token = the histogram of the whole masked crop) and ``FPFHEncoder`` (Open3D FPFH). Learned encoders
(DINOv2, GeoTransformer-like plug-ins) implement the same two protocols and register by name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol, runtime_checkable

import cv2
import numpy as np
import open3d as o3d

reg = o3d.pipelines.registration


@runtime_checkable
class ImageEncoder(Protocol):
    name: str
    dim: int

    def encode(self, rgb: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(class token (D,), patch tokens (h, w, D)) of a crop whose background is `~mask`.
        Patch (i, j) covers crop pixels [i*H/h, (i+1)*H/h) x [j*W/w, (j+1)*W/w)."""
        ...


@runtime_checkable
class PointEncoder(Protocol):
    name: str
    dim: int

    def encode(self, points: np.ndarray, normals: np.ndarray, voxel: float) -> np.ndarray:
        """(M, D) features of voxel-centre points with normals (facing the viewer)."""
        ...


def l2n(x: np.ndarray, axis: int = -1) -> np.ndarray:
    n = np.linalg.norm(x, axis=axis, keepdims=True)
    return x / np.maximum(n, 1e-12)


class ColourEncoder:
    """Per-pixel soft colour histogram: 12 circular hue bins weighted by saturation, 4 value bins weighted by
    (1 - saturation). Robust to shading (hue/saturation), no weights. Patches are 4x4-pixel averages."""

    name = "colour"
    dim = 16
    patch = 4

    def pixel_features(self, rgb: np.ndarray) -> np.ndarray:
        hsv = cv2.cvtColor(np.ascontiguousarray(rgb, np.uint8), cv2.COLOR_RGB2HSV_FULL).astype(np.float32) / 255.0
        h, s, v = hsv[..., 0] * 12.0, hsv[..., 1], hsv[..., 2]
        # Saturation below ~0.15 is mostly sensor noise on grey/white surfaces: fade hue in smoothly.
        sw = np.clip((s - 0.08) / 0.25, 0.0, 1.0)
        out = np.zeros(rgb.shape[:2] + (16,), np.float32)
        lo = np.floor(h).astype(int) % 12
        fr = h - np.floor(h)
        hi = (lo + 1) % 12
        rr, cc = np.indices(lo.shape)
        out[rr, cc, lo] += sw * (1 - fr)
        out[rr, cc, hi] += sw * fr
        vb = np.clip(v * 4.0 - 0.5, 0.0, 3.0)
        vlo = np.floor(vb).astype(int)
        vfr = vb - vlo
        vhi = np.minimum(vlo + 1, 3)
        out[rr, cc, 12 + vlo] += (1 - sw) * (1 - vfr)
        out[rr, cc, 12 + vhi] += (1 - sw) * vfr
        return out

    def encode(self, rgb: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f = self.pixel_features(rgb) * mask[..., None]
        cls = f[mask].mean(axis=0) if mask.any() else np.zeros(self.dim, np.float32)
        H, W = mask.shape
        p = self.patch
        h, w = -(-H // p), -(-W // p)
        f = np.pad(f, ((0, h * p - H), (0, w * p - W), (0, 0))).reshape(h, p, w, p, self.dim).sum(axis=(1, 3))
        cnt = np.pad(mask, ((0, h * p - H), (0, w * p - W))).reshape(h, p, w, p).sum(axis=(1, 3))[..., None]
        return l2n(cls), f / np.maximum(cnt, 1)


class FPFHEncoder:
    name = "fpfh"
    dim = 33

    def encode(self, points: np.ndarray, normals: np.ndarray, voxel: float) -> np.ndarray:
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        pc.normals = o3d.utility.Vector3dVector(normals)
        f = reg.compute_fpfh_feature(pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
        return np.asarray(f.data).T.astype(np.float32)


IMAGE_ENCODERS: dict[str, Callable[[], ImageEncoder]] = {"colour": ColourEncoder}
POINT_ENCODERS: dict[str, Callable[[], PointEncoder]] = {"fpfh": FPFHEncoder}


def make_image_encoder(name: str) -> ImageEncoder | None:
    if name == "none":
        return None
    if name not in IMAGE_ENCODERS:
        raise ValueError(f"perception.image_encoder: {name!r} is not available here (have {sorted(IMAGE_ENCODERS)} "
                         "and 'none'; learned encoders need the 'learned' extra and local weights)")
    return IMAGE_ENCODERS[name]()


def make_point_encoder(name: str) -> PointEncoder:
    if name not in POINT_ENCODERS:
        raise ValueError(f"perception.point_encoder: {name!r} is not registered (have {sorted(POINT_ENCODERS)}); "
                         "register a plug-in with kitchenbot.perception.features.POINT_ENCODERS[name] = factory")
    return POINT_ENCODERS[name]()


@dataclass
class FusedCloud:
    """An instance (or a CAD model) as voxel-centre points with normals and fused features."""

    points: np.ndarray  # (M, 3)
    normals: np.ndarray  # (M, 3)
    img: np.ndarray  # (M, Di) L2-normalised per point (zeros when no image encoder)
    pts: np.ndarray  # (M, Dp) L2-normalised per point
    cls_token: np.ndarray  # (Di,) image class token (L2-normalised)
    geo_token: np.ndarray  # (Dp,) mean point feature (L2-normalised)

    @property
    def fused(self) -> np.ndarray:
        """F = [F_img/|F_img| || F_pts/|F_pts|] (paper eq. fused_feat)."""
        return np.concatenate([self.img, self.pts], axis=1) if self.img.shape[1] else self.pts


def voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """One int64 per voxel (21 bits per axis: +-1 km at 1 mm), so that np.unique runs on 1-D keys (fast)."""
    k = np.floor(points / voxel).astype(np.int64) + (1 << 20)
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


def voxel_pool(points: np.ndarray, feats: np.ndarray | None, voxel: float) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Mean point and mean feature per occupied voxel; also the voxel index of every input point."""
    _, inv_, cnt = np.unique(voxel_keys(points, voxel), return_inverse=True, return_counts=True)
    inv_ = inv_.reshape(-1)
    n = len(cnt)
    P = np.zeros((n, 3))
    np.add.at(P, inv_, points)
    P /= cnt[:, None]
    F = None
    if feats is not None:
        F = np.zeros((n, feats.shape[1]), np.float64)
        np.add.at(F, inv_, feats)
        F /= cnt[:, None]
    return P, F, inv_


def oriented_normals(points: np.ndarray, viewpoints: np.ndarray, voxel: float) -> np.ndarray:
    """Normals from local PCA, flipped to face the viewpoint given per point (or one viewpoint)."""
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=30))
    n = np.asarray(pc.normals)
    if len(n) != len(points):  # too few points for Open3D to estimate any
        n = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    flip = np.einsum("ij,ij->i", n, np.broadcast_to(viewpoints, points.shape) - points) < 0
    n[flip] *= -1
    return n


def fuse_instance(points: np.ndarray, view_idx: np.ndarray, pixel: np.ndarray, rgbs: list[np.ndarray],
                  masks: list[np.ndarray | None], cam_centres: np.ndarray, voxel: float,
                  img_enc: ImageEncoder | None, pt_enc: PointEncoder, point_features: bool = True) -> FusedCloud:
    """Alg. 1 for one instance: `points` (base frame) seen at `pixel` (row, col) of view `view_idx`;
    `masks[k]` is the instance's mask in view k (None where it was not seen). `point_features=False`: no point
    features (`pts` (M, 0), `geo_token` empty): for a query that only registers and scores (pose tracking,
    perception/track.py), where FPFH was most of the query's cost and never read."""
    dim_i = img_enc.dim if img_enc else 0
    img = np.zeros((len(points), dim_i))
    cls_tokens = []
    if img_enc is not None:
        for k, (rgb, mask) in enumerate(zip(rgbs, masks)):
            sel = view_idx == k
            if mask is None or not sel.any() or not mask.any():
                continue
            rows, cols = np.nonzero(mask)
            r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
            # Every 2nd pixel is enough (the map samples the same grid) and halves the encoder's work.
            cls, patches = img_enc.encode(rgb[r0:r1:2, c0:c1:2], mask[r0:r1:2, c0:c1:2])
            # (patch tokens cover the crop evenly; map each point's pixel to its patch)
            cls_tokens.append(cls * np.sqrt(mask.sum()))  # weight views by how much they saw
            h, w = patches.shape[:2]
            pr = np.clip(((pixel[sel, 0] - r0) * h) // max(r1 - r0, 1), 0, h - 1)
            pc = np.clip(((pixel[sel, 1] - c0) * w) // max(c1 - c0, 1), 0, w - 1)
            img[sel] = patches[pr, pc]
    P, F, inv_ = voxel_pool(points, img if dim_i else None, voxel)
    # Each voxel is seen from (one of) the cameras that saw its points: orient normals towards it.
    vp = np.zeros((len(P), 3))
    vp[inv_] = cam_centres[view_idx] if len(cam_centres) else 0.0
    N = oriented_normals(P, vp, voxel)
    if not point_features:
        Fp = np.zeros((len(P), 0))
    else:
        Fp = l2n(pt_enc.encode(P, N, voxel))
    cls_token = l2n(np.sum(cls_tokens, axis=0)) if cls_tokens else np.zeros(dim_i)
    if F is not None:
        # Voxels whose pixels fell on empty patches (mask edges) take the instance's class token.
        F[np.linalg.norm(F, axis=1) < 1e-9] = cls_token
        Fi = l2n(F)
    else:
        Fi = np.zeros((len(P), 0))
    geo = l2n(Fp.mean(axis=0)) if len(Fp) and Fp.shape[1] else np.zeros(pt_enc.dim if point_features else 0)
    return FusedCloud(P, N, Fi, Fp, cls_token, geo)


def with_point_features(cloud: FusedCloud, pt_enc: PointEncoder, voxel: float) -> FusedCloud:
    """A cloud that `fuse_instance(..., point_features=False)` made, with the point features it left out: what
    `fuse_instance(..., point_features=True)` gives for the same instance (the points, normals and image features
    do not depend on the point features; these are computed from the points and normals alone)."""
    Fp = l2n(pt_enc.encode(cloud.points, cloud.normals, voxel))
    geo = l2n(Fp.mean(axis=0)) if len(Fp) and Fp.shape[1] else np.zeros(pt_enc.dim)
    return FusedCloud(cloud.points, cloud.normals, cloud.img, Fp, cloud.cls_token, geo)
