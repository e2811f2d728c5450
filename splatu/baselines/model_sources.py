"""Methods that render one trained model: ours, a per-Gaussian feature, and random noise."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import torch
from torch import Tensor

from splatu.baselines import UncertaintyRender, or_combine
from splatu.camera import Camera
from splatu.model import GaussianModel


@dataclass
class OursSource:
    """The paper's map: U = Σ w_i u_i(d_i) + (1 − Σ w_i)·1, composited like colour."""

    model: GaussianModel
    sh_degree: int
    background: Tensor

    def render(self, camera: Camera) -> UncertaintyRender:
        out = self.model.render(camera, self.sh_degree, self.background, with_uncertainty=True)
        return UncertaintyRender(out.rgb, out.depth, out.alpha, out.uncertainty)


SPREAD_SCALE = 0.1
"""RGB std of a pixel's blended colours that maps to spread 0.5 (s / (s + SPREAD_SCALE)). AUSE depends only on
each map's ranking, so the scale matters only where the spread is combined with U; in a one-off check (not a
script in benchmarks/, figures not recorded), scales from 0.03 to 0.3 changed the combination's AUSE-MAE only
slightly on poster and fox."""


VARIANCE_ROUNDING = 1e-5
"""Relative float32 rounding of the composited E|c|² (many blended layers, ~100 ulp): variances below it read 0."""


def colour_spread(rgb_and_square: Tensor, alpha: Tensor) -> Tensor:
    """(H, W) spread in [0, 1] from the composited features [c (3), |c|² (1)] on feature background 1.

    A pixel blends the colours c_i of the Gaussians its ray meets with weights w_i; read as a distribution
    with probabilities w_i / α, its standard deviation s says how much the pixel's colour depends on WHICH
    Gaussians a ray meets, which is what changes from a new viewpoint. Empty pixels (α → 0) read 1.
    """
    empty = 1.0 - alpha
    coverage = alpha.clamp_min(1e-6)
    mean = (rgb_and_square[..., :3] - empty[..., None]) / coverage[..., None]
    second = (rgb_and_square[..., 3] - empty) / coverage
    # E|c|² − |E c|² cancels in float32: a variance within rounding of E|c|² is no spread at all
    variance = second - (mean * mean).sum(-1) - VARIANCE_ROUNDING * second.abs()
    std = variance.clamp_min(0.0).sqrt()
    return alpha * std / (std + SPREAD_SCALE) + empty


@dataclass
class SpreadSource:
    """Colour spread along each ray (see `colour_spread`), alone or OR-combined with ours:
    1 − (1 − U)·(1 − S), uncertain where the view-dependent SH says so or where the blended colours disagree."""

    model: GaussianModel
    sh_degree: int
    background: Tensor
    with_ours: bool

    def render(self, camera: Camera) -> UncertaintyRender:
        colours = self.model.colors(self.model.view_dirs(camera), self.sh_degree)
        features = torch.cat([colours, (colours * colours).sum(-1, keepdim=True)], dim=-1)
        out = self.model.render(camera, self.sh_degree, self.background, with_uncertainty=self.with_ours,
                                extra_features=features)
        spread = colour_spread(out.extra, out.alpha)
        uncertainty = spread if out.uncertainty is None else or_combine(out.uncertainty, spread)
        return UncertaintyRender(out.rgb, out.depth, out.alpha, uncertainty)


@dataclass
class FeatureSource:
    """A per-Gaussian scalar in [0, 1] composited as a feature; empty pixels read 1 (unseen)."""

    model: GaussianModel
    sh_degree: int
    background: Tensor
    feature: Tensor  # (N,)

    def render(self, camera: Camera) -> UncertaintyRender:
        out = self.model.render(camera, self.sh_degree, self.background, extra_features=self.feature[:, None])
        return UncertaintyRender(out.rgb, out.depth, out.alpha, out.extra[..., 0])


@dataclass
class RandomSource:
    """Uniform noise, seeded by the view's name and `seed`, beside the model's own render."""

    model: GaussianModel
    sh_degree: int
    background: Tensor
    seed: int = 0

    def render(self, camera: Camera) -> UncertaintyRender:
        out = self.model.render(camera, self.sh_degree, self.background)
        generator = torch.Generator().manual_seed(self.seed * 1_000_003 + zlib.crc32(camera.name.encode()))
        noise = torch.rand(camera.height, camera.width, generator=generator)
        return UncertaintyRender(out.rgb, out.depth, out.alpha, noise)
