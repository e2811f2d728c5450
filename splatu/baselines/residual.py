"""The training residual: how badly each Gaussian fits the training views it contributes to.

A Gaussian whose pixels a trained model still gets wrong in the training views (fur, fine texture,
hard view-dependence, geometry that no view pins down) is likely wrong from a new viewpoint too. Its
residual is the contribution-weighted mean of the per-pixel error over the training views,

    r_i = Σ_views Σ_p w_i(p)·e(p) / Σ_views Σ_p w_i(p),   e(p) = mean over channels of |render − target|,

with w_i(p) = T·α the blending weight. The numerator needs no per-pair bookkeeping: a probe feature f
rendered as an extra channel gives image(p) = Σ_i w_i(p) f_i + …, so ∂/∂f_i Σ_p e(p)·image(p) is
exactly Σ_p w_i(p)·e(p), one backward per view; a second probe channel gives the denominator, both
over the valid pixels only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from splatu.baselines import UncertaintyRender, or_combine
from splatu.baselines.angle import ViewCoverage, angular_gap
from splatu.camera import Camera
from splatu.data.scene import Views, on_background
from splatu.model import GaussianModel


def training_residuals(model: GaussianModel, views: Views, sh_degree: int, background: Tensor) -> Tensor:
    """(N,) r_i over `views` (targets on `background`, invalid pixels of `views.masks` ignored); NaN for a
    Gaussian that contributes to no training pixel (unseen: `ResidualSource` gives it the worst error, 1)."""
    sums = torch.zeros(len(model), 2, dtype=torch.float64)  # Σ w·e and Σ w over the valid pixels
    for i, camera in enumerate(views.cameras):
        target = views.images[i]
        if views.alphas is not None:
            target = on_background(target, views.alphas[i], views.alpha_background, background)
        # as eval-ause scores: a pixel counts fully where the mask is non-zero (an RGBA alpha is a mask too)
        valid = torch.ones(target.shape[:2]) if views.masks is None else (views.masks[i] > 0).reshape(target.shape[:2])
        valid = valid.to(target.dtype)
        probe = torch.zeros(len(model), 2, requires_grad=True)
        with torch.enable_grad():
            out = model.render(camera, sh_degree, background, extra_features=probe)
            error = (out.rgb.detach().clamp(0.0, 1.0) - target).abs().mean(-1)
            (per_gaussian,) = torch.autograd.grad((out.extra * torch.stack([error * valid, valid], -1)).sum(),
                                                  [probe])
        sums += per_gaussian.double()
    weighted_error, weight = sums.unbind(1)
    seen = weight > 0
    return torch.where(seen, weighted_error / torch.where(seen, weight, 1.0), torch.nan).float()


RESIDUAL_FLOOR = 0.5 / 255.0
"""Half an 8-bit code value: residuals below it are below what 8-bit targets can resolve, so a near-perfect
fit does not make the typical residual ~0 and turn every trace of error into a map value near 1."""


def typical_residual(residuals: Tensor) -> float:
    """The median residual of the Gaussians some training pixel saw, at least RESIDUAL_FLOOR (1 when none did)."""
    seen = residuals[torch.isfinite(residuals)]
    return max(float(seen.median()), RESIDUAL_FLOOR) if seen.numel() else 1.0


def residual_map(expected_residual: Tensor, typical: float) -> Tensor:
    """x / (x + typical) of the composited residual x = Σ_i w_i r_i + (1 − Σ_i w_i)·1 (empty space reads the
    worst error, 1): ½ where a ray sees the scene's typical residual, so the map needs no scale of its own and
    OR-combines with ours on an even footing; monotone, so the map alone ranks pixels exactly as x does."""
    return expected_residual / (expected_residual + typical)


@dataclass
class ResidualSource:
    """The residual map, alone or OR-combined with ours: 1 − (1 − U)·(1 − R); with `coverage`, also with the
    angular gap G (`splatu.baselines.angle`): 1 − (1 − U)·(1 − R)·(1 − G)."""

    model: GaussianModel
    sh_degree: int
    background: Tensor
    residuals: Tensor  # (N,) from training_residuals
    with_ours: bool
    coverage: ViewCoverage | None = None
    typical: float = field(init=False)
    feature: Tensor = field(init=False)  # (N, 1) the residuals, 1 for unseen Gaussians

    def __post_init__(self) -> None:
        self.typical = typical_residual(self.residuals)
        self.feature = torch.where(torch.isfinite(self.residuals), self.residuals, 1.0).clamp(0.0, 1.0)[:, None]

    def render(self, camera: Camera) -> UncertaintyRender:
        features = self.feature
        if self.coverage is not None:
            features = torch.cat([features, angular_gap(self.model.means, self.coverage, camera.center())[:, None]], 1)
        out = self.model.render(camera, self.sh_degree, self.background, with_uncertainty=self.with_ours,
                                extra_features=features)
        uncertainty = residual_map(out.extra[..., 0], self.typical)
        if self.coverage is not None:
            uncertainty = or_combine(uncertainty, out.extra[..., 1])
        if out.uncertainty is not None:
            uncertainty = or_combine(out.uncertainty, uncertainty)
        return UncertaintyRender(out.rgb, out.depth, out.alpha, uncertainty)
