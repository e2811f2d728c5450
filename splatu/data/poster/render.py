"""The stand-in's exact renderer: cast pixel rays, shade the first hit, keep depth and hit points.

Depth is camera-space z (OpenCV +z), not ray length: primary ray directions are scaled to
camera z = 1, so the hit parameter t is the depth.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from splatu.camera import Camera
from splatu.data.poster.geometry import PosterScene
from splatu.data.poster.raycast import Hits, cast, to_local
from splatu.data.poster.shading import dot, shade
from splatu.data.poster.textures import surface


@dataclass(frozen=True)
class Rendering:
    """One view: RGB in [0, 1] (H, W, 3), camera-z depth (H, W), and the first-hit points (H*W, 3)."""

    rgb: Tensor
    depth: Tensor
    points: Tensor
    box: Tensor  # (H, W) index of the box each pixel-centre ray hits


def pixel_rays(camera: Camera, offset_x: float = 0.5, offset_y: float = 0.5) -> Tensor:
    """World directions (H*W, 3) through (j + offset_x, i + offset_y), scaled to camera z = 1."""
    K = camera.K.double()
    ys = torch.arange(camera.height, dtype=torch.float64) + offset_y
    xs = torch.arange(camera.width, dtype=torch.float64) + offset_x
    v, u = torch.meshgrid(ys, xs, indexing="ij")
    d_cam = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], dim=-1)
    return to_local(d_cam.reshape(-1, 3), camera.world_to_camera[:3, :3].double())  # R^T d


def facing_normals(scene: PosterScene, hits: Hits, directions: Tensor) -> Tensor:
    """World normals of the hit faces, turned towards the incoming ray (room walls are seen from inside)."""
    axes = scene.rotations.transpose(1, 2)  # (B, 3 local axes, 3 world coordinates)
    normal = axes[hits.box.clamp(min=0), hits.axis] * hits.side[:, None]
    return torch.where((dot(normal, directions) > 0)[:, None], -normal, normal)


def shade_rays(scene: PosterScene, origin: Tensor, directions: Tensor, specular: bool = True) -> tuple[Tensor, Hits]:
    """Colour (N, 3) of the first hit along each ray, and the hits; `specular=False` drops the highlights (the
    view-independent part of the colour, which `benchmarks/unseen_error.py` compares against)."""
    hits = cast(scene, origin, directions)
    to_camera = -directions / dot(directions, directions).sqrt()[:, None]
    material = surface(scene, hits)
    if not specular:
        material = replace(material, ks=torch.zeros_like(material.ks))
    rgb = shade(material, facing_normals(scene, hits, directions), to_camera)
    return rgb, hits


def render(scene: PosterScene, camera: Camera, supersample: int = 1, specular: bool = True) -> Rendering:
    """Render one camera; RGB averages supersample^2 stratified rays per pixel, depth uses the centre ray.

    Depth and hit points are float64; the anti-aliasing samples are cast and shaded in float32
    (their error, ~1e-7 relative, is far below 8-bit quantisation) for speed.
    """
    origin = camera.center().double()
    h, w = camera.height, camera.width
    centre_dirs = pixel_rays(camera)
    if supersample == 1:
        rgb, hits = shade_rays(scene, origin, centre_dirs, specular)
    else:
        hits = cast(scene, origin, centre_dirs)
        offsets = [(sx + 0.5) / supersample for sx in range(supersample)]
        dirs = torch.cat([pixel_rays(camera, ox, oy) for oy in offsets for ox in offsets]).float()
        samples = shade_rays(scene.to(torch.float32), origin.float(), dirs, specular)[0]
        samples = samples.reshape(supersample**2, h * w, 3)
        rgb = samples[0]
        for sample in samples[1:]:
            rgb = rgb + sample
        rgb = rgb.double() / supersample**2
    points = origin + hits.t[:, None] * centre_dirs
    return Rendering(rgb=rgb.reshape(h, w, 3), depth=hits.t.reshape(h, w), points=points, box=hits.box.reshape(h, w))
