"""nerfstudio-style world normalisation: centre on the cameras, scale them into [-1, 1].

x_norm = (x - center) * scale, with center the mean camera position and scale chosen so the
farthest camera sits at distance 1. Poses, points and depths (depth *= scale) all move
together, so the scene is the same scene in new units.
"""

from __future__ import annotations

from dataclasses import replace

from torch import Tensor

from splatu.camera import Camera

COINCIDENT = 1e-12
"""Camera centres closer than this, relative to their coordinates' size (at least 1), coincide: float64's rounding of
a pose's R^T t spreads the centres of cameras turning on one spot by about 1e-16 of their coordinates, so a capture
at 3e6 (geo-referenced) had a "baseline" of 4e-10 and took a scale of 1e9 from rounding noise alone."""


def coordinate_size(centers: Tensor) -> float:
    """The size of camera centres' (N, 3) coordinates: their median position's largest, at least 1 (not the largest
    centre's, which one broken pose at 1e20 would make)."""
    return max(1.0, float(centers.median(dim=0).values.abs().max()))


def coincident_within(centers: Tensor) -> float:
    """The distance under which camera centres `centers` (N, 3) coincide: COINCIDENT of their coordinates' size."""
    return COINCIDENT * coordinate_size(centers)


def normalization(centers: Tensor) -> tuple[Tensor, float]:
    """(center, scale) from camera centres (N, 3); scale is 1 when all cameras coincide (no baseline)."""
    center = centers.mean(dim=0)
    radius = float((centers - center).norm(dim=-1).max())
    return center, (1.0 / radius if radius > coincident_within(centers) else 1.0)


def normalize_camera(camera: Camera, center: Tensor, scale: float) -> Camera:
    """The same camera in normalised world coordinates: rotation kept, p_cam = scale · (R·x_world + t) for
    x_world = x_norm / scale + center, so every pixel stays and depths scale. The translation is moved directly,
    not through the centre −Rᵀt: a file's rotation (few decimals, float32) is orthonormal only to ~1e-4 to 1e-7,
    and R·Rᵀ ≠ I shifted every point in the camera's frame by (R·Rᵀ − I)·t, pixels at map coordinates."""
    rotation = camera.world_to_camera[:3, :3]
    world_to_camera = camera.world_to_camera.clone()
    world_to_camera[:3, 3] = (camera.world_to_camera[:3, 3] + rotation @ center.to(rotation)) * scale
    return replace(camera, world_to_camera=world_to_camera)


def normalize_points(points: Tensor, center: Tensor, scale: float) -> Tensor:
    return (points - center.to(points)) * scale
