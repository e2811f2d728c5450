"""Blinn-Phong shading under fixed directional lights: Lambert + ambient + a view-dependent highlight.

The highlight is what makes colour depend on the viewing direction, so colour SH matter. There
are no shadows: lights are directional and unoccluded (a documented simplification).
"""

from __future__ import annotations

import torch
from torch import Tensor

from splatu.data.poster.textures import Surface

AMBIENT = 0.35
LIGHTS = (
    ((0.5, 0.8, 1.2), 0.75),  # key light: from the front-right, above
    ((-0.8, -0.3, 0.6), 0.25),  # fill light: from the back-left
)
"""(direction towards the light, intensity) pairs; directions are normalised on use."""


def dot(a: Tensor, b: Tensor) -> Tensor:
    """Row-wise dot product of (N, 3) tensors (or with a (3,) vector), written out: cheaper than a sum over 3."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def shade(material: Surface, normal: Tensor, to_camera: Tensor) -> Tensor:
    """RGB (N, 3) in [0, 1] for unit normals facing the viewer and unit directions towards the camera.

    n.h is computed as (n.l + n.v) / |l + v| with |l + v| = sqrt(2 + 2 l.v), avoiding a normalised half vector.
    """
    diffuse = torch.full_like(material.ks, AMBIENT)
    specular = torch.zeros_like(material.ks)
    n_dot_v = dot(normal, to_camera)
    for direction, intensity in LIGHTS:
        light = torch.tensor(direction, dtype=normal.dtype)
        light = light / light.norm()
        n_dot_l = dot(normal, light)
        diffuse = diffuse + intensity * n_dot_l.clamp(min=0)
        half_length = (2.0 + 2.0 * dot(to_camera, light)).clamp(min=1e-12).sqrt()
        n_dot_h = ((n_dot_l + n_dot_v) / half_length).clamp(min=0)
        specular = specular + intensity * torch.where(n_dot_l > 0, n_dot_h**material.shininess, 0.0)
    rgb = material.albedo * diffuse[:, None] + (material.ks * specular)[:, None]
    return rgb.clamp(0.0, 1.0)
