"""Uncertainty methods that `render-uncertainty` and `eval-ause` understand, ours and the baselines.

Every method turns a camera into the same four maps (`UncertaintyRender`), so the maps layout
and AUSE treat them identically:

- ours: the view-dependent SH uncertainty, U = Σ w_i u_i(d_i) + (1 − Σ w_i)·1;
- ensemble: per-pixel std of RGB across the members of an ensemble run (REFERENCE §5);
- visibility: view-independent 1/(1 + #training views where a Gaussian's max weight ≥ T_thr);
- fisher: a FisherRF-like diagonal Fisher information per Gaussian, rendered as a feature;
- random: seeded uniform noise, the floor any method must beat;
- spread: the std of the colours each pixel blends, training-free (`model_sources.colour_spread`);
- ours-spread: ours OR spread, 1 − (1 − U)(1 − S).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

from torch import Tensor

from splatu.camera import Camera

UncertaintyMethod = Literal["ours", "ensemble", "visibility", "fisher", "random", "spread", "ours-spread"]


@dataclass
class UncertaintyRender:
    """One view as every method renders it, all float (H, W[, 3]) on the CPU."""

    rgb: Tensor
    depth: Tensor
    alpha: Tensor
    uncertainty: Tensor


class UncertaintySource(Protocol):
    """Anything that renders a camera into an `UncertaintyRender` on `background` (targets with alpha are
    composited on the same colour before they are compared)."""

    background: Tensor

    def render(self, camera: Camera) -> UncertaintyRender: ...
