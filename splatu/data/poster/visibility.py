"""Ground-truth observation: is a surface point seen, unoccluded, by at least one training camera?

A point counts as seen by a camera when it is in front of it, projects inside its image, and
the segment from the camera centre to it meets no surface before it (an exact visibility ray,
not a depth-map comparison, so thin parts and silhouettes are right).
"""

from __future__ import annotations

import torch
from torch import Tensor

from splatu.camera import Camera
from splatu.data.poster.geometry import PosterScene
from splatu.data.poster.raycast import blocked


def in_view(cameras: list[Camera], points: Tensor) -> Tensor:
    """(C, N): which points are in front of each camera and project inside its image."""
    w2c = torch.stack([cam.world_to_camera for cam in cameras]).double()
    K = torch.stack([cam.K for cam in cameras]).double()
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    p_cam = [w2c[:, row, 0, None] * x + w2c[:, row, 1, None] * y + w2c[:, row, 2, None] * z + w2c[:, row, 3, None]
             for row in range(3)]
    near = torch.tensor([cam.near for cam in cameras], dtype=torch.float64)[:, None]
    in_front = p_cam[2] > near
    z = torch.where(in_front, p_cam[2], torch.ones_like(p_cam[2]))
    u = K[:, 0, 0, None] * p_cam[0] / z + K[:, 0, 2, None]
    v = K[:, 1, 1, None] * p_cam[1] / z + K[:, 1, 2, None]
    width = torch.tensor([cam.width for cam in cameras], dtype=torch.float64)[:, None]
    height = torch.tensor([cam.height for cam in cameras], dtype=torch.float64)[:, None]
    return in_front & (u >= 0) & (u < width) & (v >= 0) & (v < height)


def observed_mask(scene: PosterScene, points: Tensor, train_cameras: list[Camera], viewer: Tensor) -> Tensor:
    """Boolean (N,): which points (N, 3) some training camera sees.

    Cameras are tried nearest to `viewer` first, in groups of doubling size (1, 2, 4, ...), and
    only still-unseen points are tested: a view on the training path is settled by its first
    group, and the loop runs only a few times in Python.
    """
    observed = torch.zeros(points.shape[0], dtype=torch.bool)
    centers = torch.stack([cam.center() for cam in train_cameras]).double()
    distance = (centers - viewer).norm(dim=1)
    order = sorted(range(len(train_cameras)), key=lambda k: (float(distance[k]), k))
    start, size = 0, 1
    while start < len(order):
        group = order[start : start + size]
        start, size = start + size, 2 * size
        pending = (~observed).nonzero()[:, 0]
        if pending.numel() == 0:
            break
        cam_index, point_index = in_view([train_cameras[k] for k in group], points[pending]).nonzero(as_tuple=True)
        if point_index.numel() == 0:
            continue
        rows = pending[point_index]
        origins = centers[torch.tensor(group)[cam_index]]
        clear = ~blocked(scene, origins, points[rows])
        observed[rows[clear]] = True
    return observed
