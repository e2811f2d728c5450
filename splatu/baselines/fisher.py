"""A FisherRF-like baseline: the diagonal Fisher information of each Gaussian's parameters.

For a Gaussian likelihood on rendered colour the Fisher information is JᵀJ, J the Jacobian of
every rendered pixel colour with respect to the parameters. Its diagonal Σ_p (∂c_p/∂θ)² needs
one backward per pixel if done naively; instead we use Rademacher probes z (±1 per pixel and
channel): E[(∂(z·c)/∂θ)²] = Σ_p (∂c_p/∂θ)² exactly, so a few backward passes per training view
give an unbiased estimate. No ground truth image is needed, as in FisherRF.

Choices (ours): the parameters are the means (3), the colour DC (3) and the opacity logit (1),
the ones that decide what a pixel shows; F_i is their summed diagonal. The map renders
f_i = log(1 + 1/(F_i/max F + ε)) / log(1 + 1/ε), ε = 1e-6: scale-free, 1 for a Gaussian no
view constrains, small for well-constrained ones; empty pixels read 1.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from splatu.camera import Camera
from splatu.errors import require_at_least
from splatu.model import GaussianModel
from splatu.rasterizer.kernels import kernels_compiled

FISHER_PARAMS = ("means", "sh_dc", "opacity_logits")
EPSILON = 1e-6


def fisher_diagonal(model: GaussianModel, cameras: list[Camera], sh_degree: int, probes: int,
                    generator: torch.Generator, on_view: Callable[[], object] = lambda: None) -> Tensor:
    """(N,) Σ over `cameras` and FISHER_PARAMS of the Rademacher estimate of diag(JᵀJ); `on_view` is called after
    each camera (a progress bar's tick: `probes` backward passes per view take a while)."""
    require_at_least(probes, 1, "--fisher-probes")  # the estimate divides by it
    params = [getattr(model, name) for name in FISHER_PARAMS]
    information = torch.zeros(len(model))
    background = torch.zeros(3)
    # a torch.compile'd backward frees (donates) its saved buffers, so its graph cannot be run twice: with compiled
    # kernels each probe renders the view again (the same image, as rendering is deterministic)
    fresh_graph = kernels_compiled()
    with torch.enable_grad():
        for camera in cameras:
            for probe in range(probes):
                if probe == 0 or fresh_graph:
                    rgb = model.render(camera, sh_degree, background).rgb
                signs = torch.randint(0, 2, rgb.shape, generator=generator).float() * 2.0 - 1.0
                grads = torch.autograd.grad((rgb * signs).sum(), params,
                                            retain_graph=not fresh_graph and probe < probes - 1)
                for grad in grads:
                    information += grad.detach().reshape(len(model), -1).square().sum(dim=1)
            on_view()
    return information / probes


def fisher_feature(information: Tensor) -> Tensor:
    """Normalised log inverse information in [0, 1]; all-zero information maps to 1 everywhere."""
    if not torch.isfinite(information).all():
        raise ValueError("the Fisher information has non-finite entries: the model's gradients are not finite")
    top = float(information.max()) if information.numel() else 0.0
    if top <= 0.0:
        return torch.ones_like(information)
    relative = information / top
    return torch.log1p(1.0 / (relative + EPSILON)) / math.log1p(1.0 / EPSILON)
