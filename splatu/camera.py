"""The one camera model every part of splatu uses.

Pinhole intrinsics K, image size, and a world-to-camera transform in OpenCV axes
(+x right, +y down, +z forward). Pixel (i, j) has its centre at (j + 0.5, i + 0.5).
Lens distortion never reaches this class: loaders undistort images and adjust K first.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor


def camera_center(world_to_camera: Tensor) -> Tensor:
    """The centre −Rᵀt of world-to-camera poses (..., 4, 4), in world coordinates (..., 3)."""
    R, t = world_to_camera[..., :3, :3], world_to_camera[..., :3, 3:]
    return -(R.transpose(-1, -2) @ t).squeeze(-1)


@dataclass(frozen=True)
class Camera:
    K: Tensor  # (3, 3)
    world_to_camera: Tensor  # (4, 4), OpenCV axes
    width: int
    height: int
    near: float = 0.01
    far: float = 1e10
    name: str = ""

    def center(self) -> Tensor:
        """Camera centre in world coordinates, (3,)."""
        return camera_center(self.world_to_camera)

    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """Project world points (M, 3) to pixel coordinates (M, 2) and camera depth (M,)."""
        p_cam = points @ self.world_to_camera[:3, :3].T + self.world_to_camera[:3, 3]
        z = p_cam[:, 2]
        uv = (p_cam @ self.K.T)[:, :2] / z.unsqueeze(-1)
        return uv, z

    def scaled(self, factor: float) -> Camera:
        """The same camera at `factor` times the resolution (factor < 1 downsamples)."""
        width = max(1, round(self.width * factor))
        height = max(1, round(self.height * factor))
        K = self.K.clone()
        K[0] *= width / self.width
        K[1] *= height / self.height
        return replace(self, K=K, width=width, height=height)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> Camera:
        return replace(
            self,
            K=self.K.to(device=device, dtype=dtype),
            world_to_camera=self.world_to_camera.to(device=device, dtype=dtype),
        )


def look_at(position: Tensor, target: Tensor, up: Tensor) -> Tensor:
    """World-to-camera 4x4 (float64) in OpenCV axes: +z from `position` towards `target`, +x right and +y down,
    with the world's `up` pointing up in the image."""
    forward = unit_vector(target - position)
    right = unit_vector(torch.linalg.cross(forward, up))
    down = torch.linalg.cross(forward, right)
    rotation = torch.stack([right, down, forward])
    world_to_camera = torch.eye(4, dtype=torch.float64)
    world_to_camera[:3, :3] = rotation
    world_to_camera[:3, 3] = -rotation @ position
    return world_to_camera


def unit_vector(v: Tensor) -> Tensor:
    """v / |v| for one vector of camera geometry, which needs no gradient (sh.safe_normalize is for those that do)."""
    return v / v.norm().clamp_min(1e-12)
