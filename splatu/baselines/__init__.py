"""Uncertainty methods that `render-uncertainty` and `eval-ause` understand, ours and the baselines.

Every method turns a camera into the same four maps (`UncertaintyRender`), so the maps layout
and AUSE treat them identically:

- ours: the view-dependent SH uncertainty, U = Σ w_i u_i(d_i) + (1 − Σ w_i)·1;
- ensemble: per-pixel std of RGB across the members of an ensemble run (REFERENCE §5);
- visibility: view-independent 1/(1 + #training views where a Gaussian's max weight ≥ T_thr);
- fisher: a FisherRF-like diagonal Fisher information per Gaussian, rendered as a feature;
- random: seeded uniform noise, the floor any method must beat;
- spread: the std of the colours each pixel blends, training-free (`model_sources.colour_spread`);
- ours-spread: ours OR spread, 1 − (1 − U)(1 − S);
- residual: how badly each Gaussian fits the training views it shows up in (`residual.training_residuals`);
- ours-residual: ours OR residual, 1 − (1 − U)(1 − R);
- angle: the angle from a view to the nearest training view that saw each Gaussian (`angle.angular_gap`);
- ours-residual-angle: ours OR residual OR angle, 1 − (1 − U)(1 − R)(1 − G);
- ours-view-residual-angle: the same with the residual read from each view's direction, R(d)
  (`residual.directional_residuals`): the training views that saw a Gaussian from near d weigh most.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol, get_args

from torch import Tensor

from splatu.camera import Camera

UncertaintyMethod = Literal["ours", "ensemble", "visibility", "fisher", "random", "spread", "ours-spread", "residual",
                            "ours-residual", "angle", "ours-residual-angle", "ours-view-residual-angle"]

UNCERTAINTY_METHODS: tuple[str, ...] = get_args(UncertaintyMethod)
METHODS_WITH_OURS: tuple[UncertaintyMethod, ...] = ("ours", "ours-spread", "ours-residual", "ours-residual-angle",
                                                    "ours-view-residual-angle")
"""The methods that read the run's uncertainty SH, so they need a run trained with the loss and accept --head."""
METHODS_FOR_PLAIN_RUNS: tuple[UncertaintyMethod, ...] = tuple(
    method for method in get_args(UncertaintyMethod) if method not in (*METHODS_WITH_OURS, "ensemble"))
"""The methods that render a single run trained without the uncertainty loss (splatfacto): none reads its u_sh."""
METHODS_FROM_TRAINING_VIEWS: tuple[UncertaintyMethod, ...] = ("visibility", "fisher", "angle", "residual",
                                                              "ours-residual", "ours-residual-angle",
                                                              "ours-view-residual-angle")
"""The methods that look at the scene's training views before they render (so they need the scene loaded)."""
METHODS_FROM_TRAINING_IMAGES: tuple[UncertaintyMethod, ...] = ("residual", "ours-residual", "ours-residual-angle",
                                                               "ours-view-residual-angle")
"""Those of them that compare renders with the training images; the others need only the training cameras (and
mask files), so a render that needs no ground truth decodes no image for them (`CameraScene`)."""


def own_method(ensemble: bool) -> UncertaintyMethod:
    """The uncertainty a run renders when no method is named: an ensemble run's std, a single run's ours."""
    return "ensemble" if ensemble else "ours"


def method_list(methods: tuple[str, ...] = UNCERTAINTY_METHODS) -> str:
    """'a, b or c', for messages and help texts."""
    return ", ".join(methods[:-1]) + " or " + methods[-1]


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


def or_combine(ours: Tensor, other: Tensor) -> Tensor:
    """1 − (1 − U)(1 − X): uncertain where either map says so, for maps in [0, 1]."""
    return 1.0 - (1.0 - ours) * (1.0 - other)
