"""nerfstudio-style world normalisation: centre on the cameras, scale them into [-1, 1].

x_norm = (x - center) * scale, with center the mean camera position and scale chosen so the
farthest camera sits at distance 1. Poses, points and depths (depth *= scale) all move
together, so the scene is the same scene in new units.
"""

from __future__ import annotations

from dataclasses import replace

from torch import Tensor

from splatu.camera import Camera


def normalization(centers: Tensor) -> tuple[Tensor, float]:
    """(center, scale) from camera centres (N, 3); scale is 1 when all cameras coincide (no baseline)."""
    center = centers.mean(dim=0)
    radius = float((centers - center).norm(dim=-1).max())
    return center, (1.0 / radius if radius > 1e-12 else 1.0)


def normalize_camera(camera: Camera, center: Tensor, scale: float) -> Camera:
    """The same camera in normalised world coordinates: rotation kept, centre moved and scaled."""
    rotation = camera.world_to_camera[:3, :3]
    new_center = (camera.center() - center.to(rotation)) * scale
    world_to_camera = camera.world_to_camera.clone()
    world_to_camera[:3, 3] = -rotation @ new_center
    return replace(camera, world_to_camera=world_to_camera)


def normalize_points(points: Tensor, center: Tensor, scale: float) -> Tensor:
    return (points - center.to(points)) * scale
