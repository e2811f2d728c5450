"""A few overlapping Gaussians in front of two nearby cameras, with noise targets: the per-Gaussian uncertainty
baselines' tests (residual, angle) share them."""

from __future__ import annotations

import torch

from splatu.camera import Camera
from splatu.data.scene import Views
from splatu.model import GaussianModel, ModelConfig
from splatu.sh import rgb_to_sh

SIZE = 12


def overlapping_gaussians(n: int = 6, seed: int = 0) -> GaussianModel:
    """n overlapping Gaussians in front of the camera, plus one far off to the side that no camera sees."""
    g = torch.Generator().manual_seed(seed)
    means = torch.cat([torch.randn(n, 3, generator=g) * torch.tensor([0.3, 0.3, 0.2]) + torch.tensor([0, 0, 3.0]),
                       torch.tensor([[50.0, 0.0, 3.0]])])
    quats = torch.randn(n + 1, 4, generator=g)
    log_scales = torch.log(torch.rand(n + 1, 3, generator=g) * 0.3 + 0.1)
    logits = torch.logit(torch.rand(n + 1, generator=g) * 0.8 + 0.1)
    sh_dc = rgb_to_sh(torch.rand(n + 1, 3, generator=g)).unsqueeze(1)
    cfg = ModelConfig(sh_degree=0, u_sh_degree=0)
    return GaussianModel(means, quats, log_scales, logits, sh_dc, torch.zeros(n + 1, 0, 3), torch.zeros(n + 1, 1, 1),
                         cfg)


def two_cameras() -> list[Camera]:
    K = torch.tensor([[12.0, 0.0, SIZE / 2], [0.0, 12.0, SIZE / 2], [0.0, 0.0, 1.0]])
    shifted = torch.eye(4)
    shifted[0, 3] = 0.2
    return [Camera(K, torch.eye(4), SIZE, SIZE, name="a"), Camera(K, shifted, SIZE, SIZE, name="b")]


def noise_views(masks: torch.Tensor | None = None) -> Views:
    g = torch.Generator().manual_seed(1)
    cameras = two_cameras()
    return Views(cameras, torch.rand(len(cameras), SIZE, SIZE, 3, generator=g), [c.name for c in cameras],
                 object_masks=masks)
