"""The one camera model every part of splatu uses.

Pinhole intrinsics K, image size, and a world-to-camera transform in OpenCV axes
(+x right, +y down, +z forward). Pixel (i, j) has its centre at (j + 0.5, i + 0.5).
Lens distortion never reaches this class: loaders undistort images and adjust K first.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor


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
        R = self.world_to_camera[:3, :3]
        t = self.world_to_camera[:3, 3]
        return -R.T @ t

    def ray_directions(self) -> Tensor:
        """Unit world-space ray directions through every pixel centre, (H, W, 3)."""
        dtype, device = self.K.dtype, self.K.device
        ys = torch.arange(self.height, dtype=dtype, device=device) + 0.5
        xs = torch.arange(self.width, dtype=dtype, device=device) + 0.5
        v, u = torch.meshgrid(ys, xs, indexing="ij")
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        d_cam = torch.stack([(u - cx) / fx, (v - cy) / fy, torch.ones_like(u)], dim=-1)
        d_world = d_cam @ self.world_to_camera[:3, :3]  # R^T d for each row vector d
        return d_world / d_world.norm(dim=-1, keepdim=True)

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
