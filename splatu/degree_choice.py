"""Choose the colour and uncertainty SH degrees per scene, from views the model has not yet seen.

A degree is only worth its coefficients if it helps on views the model was not fitted to: on the poster
stand-in colour degree 3 buys about 1 dB over degree 0, on fox it buys nothing measurable, and the same holds
for the u-SH degree. So with `--degree-choice.on` the trainer holds a contiguous block of training views out
(a contiguous block, because an unseen *angle* is what higher SH bands extrapolate to, and what the
uncertainty must flag), trains colour at the configured degree and one uncertainty head per u-SH degree
(L_u never moves the geometry, so the heads cost almost nothing), and at step `at · steps` scores every
degree on the held-out block:

- colour: PSNR of the render with the colour SH refitted to each lower degree (see `refit_colour`);
- uncertainty: AUSE-MAE of each head's map against the error of the render at the chosen colour degree.

It keeps the smallest degree within tolerance of the best (cheaper to store and to render, and no less
accurate on unseen views; the colour tolerance is 0, so a tie), gives the model that colour, drops the other
coefficients and heads together with their Adam moments, and trains on every view, the held-out block
included, for the remaining steps.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import torch

from splatu.ause import ause, pixel_errors, random_baseline, sparsification_curves
from splatu.camera import Camera
from splatu.data.scene import PerView, Views
from splatu.errors import SplatuError
from splatu.losses import UncertaintyHead, psnr, uncertainty_heads
from splatu.model import GaussianModel, head_coefficients
from splatu.optim import Optimizers
from splatu.sh import num_sh_bases, safe_normalize, sh_basis, sh_degree_of

if TYPE_CHECKING:
    from splatu.train_config import TrainConfig

MIN_HELD_OUT = 2
"""Fewer held-out views than this would score degrees on one viewpoint."""


@dataclass
class DegreeChoiceConfig:
    on: bool = False
    """Choose the colour and u-SH degrees for this scene (up to --model.sh-degree and --model.u-sh-degree): hold
    a contiguous block of training views out until step at·steps, score each degree there, keep the smallest
    within tolerance of the best, then train on every view."""
    held_out: float = 0.125
    """Fraction of the training views held out (a contiguous block from the middle of the sequence)."""
    at: float = 0.4
    """Decide after this fraction of the steps: late enough that colour has reached its full degree and the
    scores settle, early enough that the held-out views still take part in densification."""
    psnr_tolerance: float = 0.0
    """Keep a lower colour degree if its held-out PSNR is within this many dB of the best degree's. 0: a higher
    degree's lead measured at `at` grows later (poster: degree 3 led degree 2 by 0.02 dB at 40%, and the run that
    kept degree 2 ended 0.23 dB below the fixed degree-3 run on the observed unseen pixels, 0.29 dB on the path
    frames), so any lead counts; a tie still goes to the lower degree."""
    ause_tolerance: float = 0.02
    """Keep a lower u-SH degree if its held-out AUSE-MAE is within this fraction of the best degree's."""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise a one-line SplatuError for settings that hold out nothing, or everything, or never decide."""
        if not 0.0 < self.held_out < 1.0 or not 0.0 < self.at < 1.0:
            raise SplatuError(f"held_out = {self.held_out} and at = {self.at} must both be in (0, 1)",
                              "in --degree-choice.held-out / --degree-choice.at", "use e.g. 0.125 and 0.4")
        if not (math.isfinite(self.psnr_tolerance) and self.psnr_tolerance >= 0
                and math.isfinite(self.ause_tolerance) and self.ause_tolerance >= 0):
            raise SplatuError("degree-choice tolerances must be finite and non-negative",
                              "in --degree-choice.psnr-tolerance / --degree-choice.ause-tolerance",
                              "use e.g. 0 and 0.02")


def held_out_block(num_views: int, fraction: float) -> list[int]:
    """Indices of the contiguous middle block of `fraction` of the views (at least MIN_HELD_OUT)."""
    count = max(MIN_HELD_OUT, round(fraction * num_views))
    if count >= num_views:
        raise SplatuError(f"choosing degrees holds out {count} of only {num_views} training views",
                          "in --degree-choice.on", "train with fixed degrees (drop --degree-choice.on) on so few views")
    start = (num_views - count) // 2
    return list(range(start, start + count))


def decision_step(cfg: DegreeChoiceConfig, steps: int) -> int:
    """The number of completed steps at which the degrees are chosen: at least 1, and before the last step
    whenever there are two or more."""
    return min(max(1, round(cfg.at * steps)), max(1, steps - 1))


def with_choice_heads(config: TrainConfig) -> TrainConfig:
    """A TrainConfig that also trains one uncertainty head per lower u-SH degree, for the choice to compare
    (unchanged when it already does); refuses settings the choice cannot work with."""
    if config.ensemble > 1:
        raise SplatuError("an ensemble's members must differ only in seed, but each would choose its own degrees",
                          "in --degree-choice.on with --ensemble", "choose the degrees with one run, then train the "
                          "ensemble with --model.sh-degree and --model.u-sh-degree set to what it chose")
    full_colour_at = config.model.sh_degree * config.model.sh_degree_interval
    if decision_step(config.degree_choice, config.steps) <= full_colour_at:
        raise SplatuError(f"the degrees would be chosen at step {decision_step(config.degree_choice, config.steps)}, "
                          f"before colour SH reaches degree {config.model.sh_degree} (step {full_colour_at})",
                          "in --degree-choice.at", "raise --degree-choice.at or --steps, or lower "
                          "--model.sh-degree-interval")
    if config.uncertainty.off:
        return config
    heads = tuple(f"degree={d}" for d in range(config.model.u_sh_degree))
    if config.uncertainty.extra_heads == heads:
        return config
    if config.uncertainty.extra_heads:
        raise SplatuError("--degree-choice.on trains its own uncertainty heads, one per u-SH degree",
                          "in --uncertainty.extra-heads", "drop --uncertainty.extra-heads, or --degree-choice.on")
    return dataclasses.replace(config, uncertainty=dataclasses.replace(config.uncertainty, extra_heads=heads))


def split_for_choice(train: Views, fraction: float) -> tuple[Views, Views]:
    """The training views the model is fitted on until the choice, and the held-out block it is scored on."""
    held = held_out_block(len(train), fraction)
    return train.subset([i for i in range(len(train)) if i not in held]), train.subset(held)


def training_views(train: Views, config: TrainConfig, step: int) -> Views:
    """The views a step at `step` trains on: all of them, except the held-out block until the choice is made."""
    if not config.degree_choice.on or step >= decision_step(config.degree_choice, config.steps):
        return train
    return split_for_choice(train, config.degree_choice.held_out)[0]


def smallest_within(scores: dict[int, float], tolerance: float, higher_is_better: bool) -> int:
    """The smallest degree whose score is within `tolerance` of the best (absolute for higher-is-better PSNR,
    relative for lower-is-better AUSE)."""
    if higher_is_better:
        best = max(scores.values())
        return min(d for d, s in scores.items() if s >= best - tolerance)
    best = min(scores.values())
    return min(d for d, s in scores.items() if s <= best * (1.0 + tolerance))


FIT_RIDGE = 1e-4
"""Pull of a refitted colour towards the cut one (the view weights of a Gaussian sum to 1). It decides the
coefficients the fitted views leave undetermined: all of them for a Gaussian no fitted view sees, which keeps
its cut colour, and the unseen directions of one seen from too few. Elsewhere it is small beside the view
weights, so it barely shifts the fit."""


def normal_equations(dirs: torch.Tensor, weights: torch.Tensor, coeffs: torch.Tensor) -> tuple[torch.Tensor,
                                                                                                torch.Tensor]:
    """Σ_v w_v·Y(d_v)ᵀY(d_v) (N, K, K) and Σ_v w_v·Y(d_v)ᵀf(d_v) (N, K, 3) for unit directions `dirs` (N, V, 3),
    weights (N, V) and the colour function f given by `coeffs` (N, K, 3). Any lower degree's least-squares fit
    reads the leading block of these, so they are built once, at the full degree."""
    basis = sh_basis(dirs, sh_degree_of(coeffs.shape[1])).to(coeffs)  # (N, V, K)
    weighted = basis.transpose(1, 2) * weights.unsqueeze(1)  # (N, K, V)
    return weighted @ basis, weighted @ (basis @ coeffs)


@torch.no_grad()
def seen_normal_equations(model: GaussianModel, views: Views, background: torch.Tensor) -> tuple[torch.Tensor,
                                                                                                   torch.Tensor]:
    """`normal_equations` of the model's colour over the directions `views` see each Gaussian from, weighted by
    how much each view sees it (its blend weight summed over the view's pixels) and normalised per Gaussian.
    Summed one view at a time, so memory stays O(N·K²) whatever the number of views; in float64, because a
    Gaussian seen from a narrow cone of directions makes these nearly singular."""
    coeffs = torch.cat([model.sh_dc, model.sh_rest], dim=1).detach().double()
    normal = coeffs.new_zeros(len(model), coeffs.shape[1], coeffs.shape[1])
    rhs = torch.zeros_like(coeffs)
    total = coeffs.new_zeros(len(model))
    for v, camera in enumerate(views.cameras):
        counted = None if views.mask_files is None else views.mask_files[v] > 0  # what training saw of it
        weight = model.render(camera, 0, background, contribution_mask=counted).raster.contrib_sum.double()
        dirs = safe_normalize(model.view_dirs(camera).double())
        m, r = normal_equations(dirs.unsqueeze(1), weight.unsqueeze(1), coeffs)
        normal += m
        rhs += r
        total += weight
    scale = (1.0 / total.clamp_min(1e-12)).view(-1, 1, 1)
    return normal * scale, rhs * scale


def refit_colour(normal: torch.Tensor, rhs: torch.Tensor, coeffs: torch.Tensor, degree: int) -> torch.Tensor:
    """(N, K_degree, 3) colour SH of `degree` closest, over the directions each Gaussian was trained from, to
    the full `coeffs` (N, K, 3): the colour a model trained at that degree would have learnt, near enough.

    Merely cutting the higher bands off would not be: the DC term of a degree-3 model was learnt together with
    them, so a cut model is worse than one trained at the lower degree, and the choice would never go lower.
    Weighted least squares per Gaussian, min Σ_v w_v |Y(d_v)·c − f(d_v)|² + ridge·|c − c_cut|², from the
    leading block of the full-degree `normal_equations`.
    """
    k = num_sh_bases(degree)
    ridge = FIT_RIDGE * torch.eye(k, dtype=normal.dtype)
    cut = coeffs[:, :k].to(normal)
    return torch.linalg.solve(normal[:, :k, :k] + ridge, rhs[:, :k] + FIT_RIDGE * cut).to(coeffs)


def with_colour(model: GaussianModel, coeffs: torch.Tensor) -> GaussianModel:
    """The same Gaussians (shared, not copied) with colour SH `coeffs` (N, K, 3) and the degree K implies."""
    return GaussianModel(model.means.detach(), model.quats.detach(), model.log_scales.detach(),
                         model.opacity_logits.detach(), coeffs[:, :1], coeffs[:, 1:], model.u_sh.detach(),
                         dataclasses.replace(model.cfg, sh_degree=sh_degree_of(coeffs.shape[1])))


class DegreeScores(NamedTuple):
    record: dict[str, Any]
    """What was measured and chosen (JSON-ready)."""
    colour: torch.Tensor
    """(N, K, 3) colour SH of the chosen degree: refitted, or the model's own at its full degree."""


def head_maps(model: GaussianModel, heads: list[UncertaintyHead], camera: Camera) -> torch.Tensor:
    """(N, heads) u of every uncertainty head along this camera's view directions."""
    dirs = model.view_dirs(camera)
    return torch.stack([model.uncertainty(dirs, c, h.degree) for c, h in enumerate(heads)], dim=-1)


def _nothing_to_score() -> SplatuError:
    return SplatuError("every held-out view's mask excludes all of its pixels", "in the scene's mask files",
                       "train with fixed degrees (drop --degree-choice.on), or fix the masks")


def head_ause(renders: list[torch.Tensor], targets: list[torch.Tensor], maps: list[np.ndarray],
              heads: list[UncertaintyHead], masks: PerView | None) -> tuple[dict[int, float], float]:
    """Mean AUSE-MAE per head's degree over the views, and the random baseline's, on the same errors."""
    per_head: dict[int, list[float]] = {h.degree: [] for h in heads}
    randoms = []
    for i, (rgb, gt) in enumerate(zip(renders, targets, strict=True)):
        keep = np.ones(maps[i].shape[:2], bool) if masks is None else masks[i].numpy() > 0
        if not keep.any():
            continue  # its mask file excludes the whole view: nothing to rank
        errors = pixel_errors(rgb.numpy(), gt.numpy())[keep]  # one ranking target for every head, as eval-ause's
        for c, head in enumerate(heads):
            per_head[head.degree].append(ause(sparsification_curves(errors, maps[i][..., c][keep])))
        randoms.append(random_baseline(errors).ause)
    if not randoms:
        raise _nothing_to_score()
    return {d: float(np.mean(per_head[d])) for d in sorted(per_head)}, float(np.mean(randoms))


@torch.no_grad()
def score_degrees(model: GaussianModel, held_out: Views, fitted_on: Views, config: TrainConfig,
                  background: torch.Tensor) -> DegreeScores:
    """Held-out PSNR per colour degree, and AUSE-MAE (with its random baseline) per u-SH degree.

    Each lower colour degree is refitted on the directions the `fitted_on` views see each Gaussian from (see
    `refit_colour`). The uncertainty heads are scored against the error of the render at the chosen colour
    degree, the model that training continues with.
    """
    full = config.model.sh_degree
    coeffs = torch.cat([model.sh_dc, model.sh_rest], dim=1).detach()
    colours = {full: coeffs}
    if full > 0:
        normal, rhs = seen_normal_equations(model, fitted_on, background)
        colours.update({d: refit_colour(normal, rhs, coeffs, d) for d in range(full)})
    models = {d: with_colour(model, colours[d]) for d in sorted(colours)}
    heads = [] if config.uncertainty.off else uncertainty_heads(config.uncertainty, config.model.u_sh_degree)
    targets = [held_out.target(i, background) for i in range(len(held_out))]
    renders: dict[int, list[torch.Tensor]] = {d: [] for d in models}
    maps: list[np.ndarray] = []
    for camera in held_out.cameras:
        for degree, degree_model in models.items():
            extra = head_maps(model, heads, camera) if heads and degree == 0 else None
            render = degree_model.render(camera, degree, background, extra_features=extra)
            renders[degree].append(render.rgb.clamp(0, 1))
            if render.extra is not None:
                maps.append(render.extra.numpy())
    kept = [None if held_out.mask_files is None else held_out.mask_files[i] > 0 for i in range(len(held_out))]
    scored = [i for i, k in enumerate(kept) if k is None or bool(k.any())]  # as evaluation: mask files leave out
    if not scored:
        raise _nothing_to_score()
    colour = {d: float(np.mean([psnr(renders[d][i], targets[i], mask=kept[i]) for i in scored])) for d in renders}
    chosen = smallest_within(colour, config.degree_choice.psnr_tolerance, higher_is_better=True)
    record: dict[str, Any] = {"held_out_views": held_out.names, "colour_psnr": colour, "sh_degree": chosen}
    if heads:
        ause, random = head_ause(renders[chosen], targets, maps, heads, held_out.object_masks)
        record.update(u_ause_mae=ause, random_ause_mae=random,
                      u_sh_degree=smallest_within(ause, config.degree_choice.ause_tolerance, higher_is_better=False))
    return DegreeScores(record, colours[chosen])


def apply_choice(model: GaussianModel, optimizers: Optimizers, generators: list[torch.Generator],
                 config: TrainConfig, scores: DegreeScores) -> tuple[TrainConfig, list[torch.Generator]]:
    """Give the model the chosen colour (and cut its Adam moments to match) and keep only the chosen uncertainty
    head; returns the config that matches, with the choice turned off (made), and the kept head's random stream.

    The kept uncertainty head becomes the run's own (channel 0), with its settings; the rest are dropped.
    """
    choice, colour = scores.record, scores.colour
    keep = num_sh_bases(int(choice["sh_degree"])) - 1
    optimizers.edit_parameter(model, "sh_dc", lambda t: colour[:, :1].to(t), lambda moment: moment)
    optimizers.edit_parameter(model, "sh_rest", lambda t: colour[:, 1:].to(t), lambda moment: moment[:, :keep])
    model_cfg = dataclasses.replace(config.model, sh_degree=int(choice["sh_degree"]))
    uncertainty = config.uncertainty
    if "u_sh_degree" in choice:
        u_degree = int(choice["u_sh_degree"])
        heads = uncertainty_heads(config.uncertainty, config.model.u_sh_degree)
        channel = next(c for c, h in enumerate(heads) if h.degree == u_degree)

        def cut(t: torch.Tensor) -> torch.Tensor:
            return head_coefficients(t, channel, u_degree)

        optimizers.edit_parameter(model, "u_sh", cut, cut)
        model_cfg = dataclasses.replace(model_cfg, u_sh_degree=u_degree)
        uncertainty = heads[channel].loss
        generators = [generators[channel]]
    model.cfg = model_cfg
    made = dataclasses.replace(config.degree_choice, on=False)
    return dataclasses.replace(config, model=model_cfg, uncertainty=uncertainty, degree_choice=made), generators
