"""The view-independent visibility-count baseline (REFERENCE §5).

A Gaussian counts a training view when its maximum blending weight there reaches T_thr, the
same rule that decides which Gaussians the uncertainty loss supervises, so the two methods
differ only in being view-dependent or not.
"""

from __future__ import annotations

import torch
from torch import Tensor

from splatu.camera import Camera
from splatu.model import GaussianModel


@torch.no_grad()
def visibility_counts(model: GaussianModel, cameras: list[Camera], threshold: float, sh_degree: int = 0) -> Tensor:
    """(N,) number of `cameras` in which each Gaussian's max weight w = T·α is ≥ `threshold`."""
    counts = torch.zeros(len(model))
    background = torch.zeros(3)
    for camera in cameras:
        raster = model.render(camera, sh_degree, background).raster
        counts += (raster.contrib_max >= threshold).float()
    return counts


def visibility_feature(counts: Tensor) -> Tensor:
    """1 / (1 + count): 1 for a Gaussian no training view saw, → 0 for well-seen ones."""
    return 1.0 / (1.0 + counts)
