"""The view-independent visibility-count baseline (REFERENCE §5).

A Gaussian counts a training view when its maximum blending weight there reaches T_thr, the
same rule that decides which Gaussians the uncertainty loss supervises, so the two methods
differ only in being view-dependent or not.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from splatu.camera import Camera
from splatu.data.scene import PerView
from splatu.model import GaussianModel


@torch.no_grad()
def seen_in_views(model: GaussianModel, cameras: list[Camera], threshold: float, masks: PerView | None,
                  on_view: Callable[[], object]) -> Tensor:
    """(N, len(cameras)) bool: whether each Gaussian's max weight w = T·α in each camera is ≥ `threshold`, over the
    pixels of its mask (H, W per view; > 0 counts) when the views have mask files, as the training loss counts them.
    Weights do not depend on colour, so the views render at colour-SH degree 0. `on_view` is called after each
    view (a progress bar's tick: a full scene's views take a while)."""
    background = torch.zeros(3)
    columns = []
    for v, camera in enumerate(cameras):
        mask = None if masks is None else masks[v] > 0
        columns.append(model.render(camera, 0, background, contribution_mask=mask).raster.contrib_max >= threshold)
        on_view()
    return torch.stack(columns, dim=1) if columns else torch.zeros(len(model), 0, dtype=torch.bool)


def visibility_counts(model: GaussianModel, cameras: list[Camera], threshold: float, masks: PerView | None = None,
                      on_view: Callable[[], object] = lambda: None) -> Tensor:
    """(N,) number of `cameras` in which each Gaussian's max weight w = T·α is ≥ `threshold` (see seen_in_views)."""
    return seen_in_views(model, cameras, threshold, masks, on_view).sum(dim=1).float()


def visibility_feature(counts: Tensor) -> Tensor:
    """1 / (1 + count): 1 for a Gaussian no training view saw, → 0 for well-seen ones."""
    return 1.0 / (1.0 + counts)
