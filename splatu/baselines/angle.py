"""The angular gap: how far a new viewpoint is from every training view that saw a Gaussian.

The paper's u-SH learns, per Gaussian, which directions it was seen from, through the u(d) / u(−d)
proxy and a smooth SH. The gap measures that directly: for a camera at c and a Gaussian at μ,

    g_i(c) = min over training cameras v that saw i of ∠(μ − c, μ − c_v) / π,

0 from a direction some training view saw it from, 1 from the exact opposite side or for a Gaussian no
training view saw. "Saw" is the supervision rule of the uncertainty loss: max blending weight ≥ T_thr. The
gap is composited like a colour (empty space reads 1); it needs one no-grad render per training view.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import torch
from torch import Tensor

from splatu.baselines import UncertaintyRender
from splatu.baselines.visibility import seen_in_views
from splatu.camera import Camera
from splatu.data.scene import PerView
from splatu.model import GaussianModel
from splatu.sh import safe_normalize

VIEW_CHUNK = 32
"""Training views compared at once: (N, VIEW_CHUNK, 3) temporaries instead of (N, V, 3)."""


@dataclass(frozen=True)
class ViewCoverage:
    """Which training cameras saw each Gaussian, and where those cameras stand."""

    seen: Tensor  # (N, V) bool: max weight ≥ T_thr in training view v
    centres: Tensor  # (V, 3) training camera centres


def view_coverage(model: GaussianModel, cameras: list[Camera], threshold: float, masks: PerView | None = None,
                  on_view: Callable[[], object] = lambda: None) -> ViewCoverage:
    """The coverage of `model` by the training `cameras` (with their mask files, if any) under the uncertainty
    loss's supervision rule (a threshold of 0 counts every Gaussian as seen by every camera, even one outside its
    image); `on_view` as in `seen_in_views`."""
    centres = torch.stack([c.center().to(model.means) for c in cameras]) if cameras else model.means.new_zeros(0, 3)
    return ViewCoverage(seen_in_views(model, cameras, threshold, masks, on_view), centres)


def view_cosines(means: Tensor, centres: Tensor, viewer: Tensor) -> Iterator[tuple[slice, Tensor]]:
    """Per chunk of training cameras: its slice of `centres`, and (N, chunk) cos ∠(μ − viewer, μ − c_v). A
    zero-length direction (the viewer or a camera on a mean) has cosine 0 with every other."""
    looking = safe_normalize(means - viewer.to(means))
    for start in range(0, centres.shape[0], VIEW_CHUNK):
        chunk = slice(start, start + VIEW_CHUNK)
        trained = safe_normalize(means[:, None, :] - centres[chunk].to(means)[None, :, :])  # (N, chunk, 3)
        yield chunk, (trained * looking[:, None, :]).sum(-1)


@torch.no_grad()
def angular_gap(means: Tensor, coverage: ViewCoverage, viewer: Tensor) -> Tensor:
    """(N,) g_i in [0, 1] for a camera centred at `viewer` (3,). A zero-length direction (the camera on the mean)
    has cosine 0 with every training direction, so a seen Gaussian reads ½ rather than NaN (an unseen one, 1).
    arccos in float32 resolves angles down to about 1e-4 of a half-turn: plenty for a map of uncertainty."""
    nearest = means.new_full((means.shape[0],), -1.0)  # cosine of the nearest seeing direction; -1: none yet
    for chunk, cosine in view_cosines(means, coverage.centres, viewer):
        cosine = cosine.masked_fill(~coverage.seen[:, chunk], -1.0)
        nearest = torch.maximum(nearest, cosine.max(dim=1).values)
    return torch.arccos(nearest.clamp(-1.0, 1.0)) / math.pi


@dataclass
class AngleSource:
    """The angular gap alone, composited: Σ_i w_i g_i(c) + (1 − Σ_i w_i)·1."""

    model: GaussianModel
    sh_degree: int
    background: Tensor
    coverage: ViewCoverage

    def render(self, camera: Camera) -> UncertaintyRender:
        gap = angular_gap(self.model.means, self.coverage, camera.center())
        out = self.model.render(camera, self.sh_degree, self.background, extra_features=gap[:, None])
        return UncertaintyRender(out.rgb, out.depth, out.alpha, out.extra[..., 0])
