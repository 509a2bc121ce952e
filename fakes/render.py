"""Render the SimWorld from a pinhole camera on the CPU: Open3D RaycastingScene, one ray per pixel.

`render()` gives the noise-free truth (RGB with simple shading, z-depth, instance labels); `stereo_noise()`
turns a true depth image into what a stereo camera like the OAK-D measures: error growing with z^2,
disparity quantisation, holes at depth edges and at grazing angles, and no data closer than its minimum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kitchenbot.fakes.geometry import build_scene
from kitchenbot.transforms import inv
from kitchenbot.world.cell import STYLE_COLOURS
from kitchenbot.world.raycast import pinhole_rays

# OAK-D-like colour camera at 640x480: ~66 deg horizontal field of view.
OAKD_FX = 497.0
OAKD_BASELINE = 0.075  # m
OAKD_MIN_DEPTH = 0.20  # m
OAKD_MAX_DEPTH = 3.0  # m


def oakd_intrinsics(width: int = 640, height: int = 480) -> np.ndarray:
    f = OAKD_FX * width / 640.0
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


@dataclass
class RenderResult:
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32, metres, 0 where nothing was hit
    labels: np.ndarray  # (H, W) int32: object uid, 0 for cell/background
    cos_incidence: np.ndarray  # (H, W) float32, |n . view ray|, 0 where nothing was hit


_LIGHT = np.array([0.25, -0.35, 1.0]) / np.linalg.norm([0.25, -0.35, 1.0])


@dataclass(frozen=True)
class Lighting:
    """One directional light (base frame, pointing from the scene towards the light) plus ambient, a colour
    tint of the light and an exposure gain. The defaults are the renderer's original fixed light."""

    direction: tuple[float, float, float] = tuple(_LIGHT)
    ambient: float = 0.45
    diffuse: float = 0.55
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    exposure: float = 1.0


def render(world, K: np.ndarray, T_base_cam: np.ndarray, width: int, height: int,
           lighting: Lighting | None = None) -> RenderResult:
    lighting = lighting or Lighting()
    scene, labelled = build_scene(world)
    T_cam_base = inv(T_base_cam)
    rays = pinhole_rays(K, T_cam_base, width, height)  # OpenCV pixel centres (see perception/raycast.py)
    ans = scene.cast_rays(rays)
    t = ans["t_hit"].numpy()  # z-depth (rays are not normalised)
    gid = ans["geometry_ids"].numpy().astype(np.int64)
    n = ans["primitive_normals"].numpy()
    hit = np.isfinite(t)
    dirs = rays.numpy()[..., 3:]
    dn = dirs / np.sqrt(np.einsum("...i,...i->...", dirs, dirs))[..., None]
    ndot = np.einsum("...i,...i->...", n, dn)
    cosv = np.abs(ndot)
    cosv[~hit] = 0.0
    n = n * np.where(ndot > 0, -1.0, 1.0).astype(np.float32)[..., None]  # face the camera

    # Albedo per geometry.
    n_geo = len(labelled.kinds)
    albedo = np.zeros((n_geo + 1, 3), np.float32)
    labels_of = np.zeros(n_geo + 1, np.int32)
    shiny = np.zeros(n_geo + 1)
    sink_style = world.cell.spec.sink.style
    for g, (kind, key) in enumerate(labelled.kinds):
        if kind == "cell":
            box = world.cell.boxes[key]
            albedo[g] = box.colour
            shiny[g] = 0.6 if (box.kind == "sink" and sink_style == "stainless") else 0.1
        elif kind == "obj":
            albedo[g] = world.objects[key].model.colour
            labels_of[g] = key
            shiny[g] = 0.35
        elif kind == "fixture":
            fx = world.fixtures[key]
            albedo[g] = fx.colour
            shiny[g] = fx.shiny
        else:
            albedo[g] = (1.0, 1.0, 1.0)
    albedo[n_geo] = (0.92, 0.92, 0.90)  # background (far wall)
    gidx = np.where(hit, gid, n_geo)
    col = albedo[gidx]

    # Textured planes: look the colour up from the image.
    pts = None
    for g, (kind, key) in enumerate(labelled.kinds):
        if kind != "plane":
            continue
        sel = gidx == g
        if not np.any(sel):
            continue
        if pts is None:
            pts = rays.numpy()[..., :3] + dirs * np.where(hit, t, 0)[..., None]
        p = world.planes[key]
        local = (pts[sel] - p.T_base_plane[:3, 3]) @ p.T_base_plane[:3, :3]
        H, W = p.image.shape[:2]
        u = np.clip(((local[:, 0] / p.width) + 0.5) * W, 0, W - 1).astype(int)
        v = np.clip((0.5 - (local[:, 1] / p.height)) * H, 0, H - 1).astype(int)
        col[sel] = p.image[v, u] / 255.0

    # Lambert + ambient + a little specular (headlight) for shiny surfaces.
    light = np.asarray(lighting.direction, float)
    light = (light / np.linalg.norm(light)).astype(np.float32)
    lam = np.clip(n @ light, 0, 1)
    half = light - dn
    half /= np.sqrt(np.einsum("...i,...i->...", half, half))[..., None]
    spec = np.clip(np.einsum("...i,...i->...", n, half), 0, 1) ** 40 * shiny[gidx].astype(np.float32)
    shade = lighting.ambient + lighting.diffuse * lam
    img = col * shade[..., None] + spec[..., None] * 0.8
    img = np.where(hit[..., None], img, albedo[n_geo] * 0.9)
    if lighting.tint != (1.0, 1.0, 1.0) or lighting.exposure != 1.0:
        img = img * (np.asarray(lighting.tint, np.float32) * lighting.exposure)
    rgb = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
    depth = np.where(hit, t, 0.0).astype(np.float32)
    labels = np.where(hit, labels_of[gidx], 0).astype(np.int32)
    return RenderResult(rgb, depth, labels, cosv.astype(np.float32))


def stereo_noise(
    depth: np.ndarray,
    cos_incidence: np.ndarray,
    K: np.ndarray,
    rng: np.random.Generator,
    disparity_sigma_px: float = 0.12,
    edge_jump: float = 0.02,
    grazing_cos: float = 0.12,
    dropout: float = 0.003,
    baseline: float = OAKD_BASELINE,
    min_depth: float = OAKD_MIN_DEPTH,
    max_depth: float = OAKD_MAX_DEPTH,
) -> np.ndarray:
    """Depth as a stereo camera measures it (metres, 0 = no data).

    sigma_z = z^2 * sigma_d / (f * B): the standard stereo error model; depth is also quantised to 1 mm
    (the OAK-D streams uint16 millimetres). The defaults are the OAK-D's (fakes/cameras.py has others).
    """
    f = K[0, 0]
    z = depth.astype(np.float64)
    valid = (z >= min_depth) & (z <= max_depth)
    sigma = z**2 * disparity_sigma_px / (f * baseline)
    noisy = z + rng.standard_normal(z.shape) * sigma
    # Holes at depth discontinuities (the stereo matcher fails across occlusion boundaries), 1-2 px wide.
    zp = np.pad(z, 1, mode="edge")
    jump = np.zeros_like(z, bool)
    for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        nb = zp[1 + dy : 1 + dy + z.shape[0], 1 + dx : 1 + dx + z.shape[1]]
        jump |= np.abs(nb - z) > edge_jump * np.maximum(z, 0.1)
    jump &= rng.random(z.shape) < 0.8
    holes = jump | (cos_incidence < grazing_cos) | (rng.random(z.shape) < dropout)
    out = np.where(valid & ~holes, np.round(noisy * 1000.0) / 1000.0, 0.0)
    return out.astype(np.float32)


def rgb_noise(rgb: np.ndarray, rng: np.random.Generator, sigma: float = 2.0) -> np.ndarray:
    return np.clip(rgb.astype(np.float32) + rng.normal(0, sigma, rgb.shape), 0, 255).astype(np.uint8)


__all__ = ["Lighting", "RenderResult", "oakd_intrinsics", "render", "rgb_noise", "stereo_noise", "STYLE_COLOURS"]
