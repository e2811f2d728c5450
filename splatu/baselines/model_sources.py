"""Methods that render one trained model: ours, a per-Gaussian feature, and random noise."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import torch
from torch import Tensor

from splatu.baselines import UncertaintyRender
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
