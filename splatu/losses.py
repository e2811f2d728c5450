"""Training losses and image metrics: L1, SSIM, PSNR, and the view-dependent uncertainty loss.

The uncertainty loss reads only `u_sh` (directions and visibility come in detached), so it can be
added to the photometric loss in the same step without moving geometry, opacity or colour; and
the photometric loss never reaches `u_sh`, because training renders without the uncertainty channel.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from splatu.errors import SplatuError
from splatu.model import head_coefficients
from splatu.rasterizer.kernels import ALPHA_MAX
from splatu.sh import MAX_SH_DEGREE, eval_sh, safe_normalize, sh_basis

if TYPE_CHECKING:
    from splatu.model import GaussianModel
    from splatu.rasterizer import RasterOutput

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2
PSNR_MSE_FLOOR = 1e-10
"""PSNR of a perfect match is reported as 100 dB instead of +inf."""
MIN_VISIBLE_WEIGHT = 1.0 / 255.0
"""The smallest α the rasterizer draws: a Gaussian whose blend weight T·α stays below it at every pixel gave no pixel
of this view a share 3DGS counts (behind other Gaussians, T can take a drawn one below it too)."""


def _check_pair(pred: Tensor, gt: Tensor) -> None:
    if pred.shape != gt.shape:
        raise ValueError(f"prediction {tuple(pred.shape)} and target {tuple(gt.shape)} differ in shape")


def l1(pred: Tensor, gt: Tensor) -> Tensor:
    """Mean absolute error over all pixels and channels."""
    _check_pair(pred, gt)
    return (pred - gt).abs().mean()


def _gaussian_kernel(dtype: torch.dtype, device: torch.device) -> Tensor:
    x = torch.arange(SSIM_WINDOW, dtype=dtype, device=device) - SSIM_WINDOW // 2
    g = torch.exp(-(x * x) / (2 * SSIM_SIGMA**2))
    return g / g.sum()


def ssim_map(pred: Tensor, gt: Tensor) -> Tensor:
    """Per-pixel SSIM (H, W, C) of images (H, W, C) in [0, 1], as in the original 3DGS.

    11×11 Gaussian window (σ = 1.5), zero padding so the map keeps the image size and works at any
    resolution; the 3DGS training loss and its reported metric use the same form. The window is separable,
    so the five local moments are blurred in one batch of two 1D convolutions (22 taps instead of 121).
    """
    _check_pair(pred, gt)
    c = pred.shape[-1]
    x = pred.permute(2, 0, 1)
    y = gt.permute(2, 0, 1)
    moments = torch.cat([x, y, x * x, y * y, x * y], dim=0).unsqueeze(0)  # (1, 5C, H, W)
    g = _gaussian_kernel(pred.dtype, pred.device)
    channels = 5 * c
    half = SSIM_WINDOW // 2
    blurred = F.conv2d(moments, g.view(1, 1, 1, -1).expand(channels, 1, 1, SSIM_WINDOW), padding=(0, half),
                       groups=channels)
    blurred = F.conv2d(blurred, g.view(1, 1, -1, 1).expand(channels, 1, SSIM_WINDOW, 1), padding=(half, 0),
                       groups=channels)
    mu_x, mu_y, xx, yy, xy = blurred[0].split(c, dim=0)
    var_x = xx - mu_x * mu_x
    var_y = yy - mu_y * mu_y
    cov = xy - mu_x * mu_y
    numerator = (2 * mu_x * mu_y + SSIM_C1) * (2 * cov + SSIM_C2)
    denominator = (mu_x * mu_x + mu_y * mu_y + SSIM_C1) * (var_x + var_y + SSIM_C2)
    return (numerator / denominator).permute(1, 2, 0)


def ssim(pred: Tensor, gt: Tensor) -> Tensor:
    """Mean SSIM of two images (H, W, 3) in [0, 1]; 1 means identical."""
    return ssim_map(pred, gt).mean()


def photometric_loss(pred: Tensor, gt: Tensor, ssim_lambda: float = 0.2) -> Tensor:
    """The 3DGS image loss: (1 − λ)·L1 + λ·(1 − SSIM), λ = 0.2."""
    return (1.0 - ssim_lambda) * l1(pred, gt) + ssim_lambda * (1.0 - ssim(pred, gt))


def psnr(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> float:
    """PSNR in dB for images in [0, 1], over all pixels or the pixels where `mask` (H, W) is true."""
    _check_pair(pred, gt)
    squared = (pred.detach() - gt.detach()) ** 2
    if mask is not None:
        if not mask.any():
            raise ValueError("psnr mask selects no pixels")
        squared = squared[mask.bool()]
    mse = float(squared.mean())
    if not math.isfinite(mse):
        raise ValueError("psnr of a non-finite image")
    return -10.0 * math.log10(max(mse, PSNR_MSE_FLOOR))


IGNORED_BECAUSE = {
    "threshold": "that loss weights each Gaussian the view sees by its max blend weight, instead of a hard "
                 "threshold",
    "num_dirs": "only the mean loss draws random directions",
}
USED_BY = {"threshold": "antipodal or mean", "num_dirs": "mean"}


def ignored_by(kind: str, key: str) -> bool:
    """Whether loss `kind` never reads setting `key`: weighted has no threshold, and only mean has random directions."""
    return (key == "threshold" and kind == "weighted") or (key == "num_dirs" and kind != "mean")


@dataclass
class UncertaintyLossConfig:
    off: bool = False
    """Train the plain model (no uncertainty loss), for comparison."""
    kind: Literal["antipodal", "mean", "weighted"] = "antipodal"
    """antipodal: the paper's own loss, u(d) and 1 − u(−d) over the Gaussians this view sees (max blend weight ≥
    `threshold`); mean: ū over random directions (the paper's variant); weighted: the u(d) term weighted by each
    Gaussian's max blend weight, no threshold (the paper's future work). At the default u-SH degree 3, heads of one
    `fast` training each (the loss never moves the Gaussians) read AUSE-MAE 0.330 antipodal, 0.338 weighted, 0.300
    mean on poster (AUROC-unobserved 0.905, 0.898, 0.813) and 0.410, 0.413, 0.440 on fox (docs/results.md), so the
    paper's loss is the default; weighted led at degree 1 on poster (0.421 against 0.450)."""
    lam: float = 0.3
    """λ in (1−λ)·u(d) + λ·(1−u(−d)); must be < 0.5 so that a Gaussian seen from opposite sides ends up certain
    from both (antipodal, mean). `weighted` scales the first term by the max blend weight w, so there this holds
    only where w > λ/(1−λ) (0.43 at λ = 0.3): seen from opposite sides (or at u-SH degree 0, where u has no
    direction), a Gaussian that never gives any pixel more than that ends up uncertain from both."""
    threshold: float = 0.05
    """Supervise Gaussians whose max blend weight T·α in this view is at least this (antipodal, mean; weighted has no
    threshold and refuses one); in (0, 0.99] (α is clamped at 0.99), though a run saved with 0 or above 0.99 still
    loads (see `validate`)."""
    num_dirs: int = 16
    """Number of random unit directions that estimate ū (kind = mean; the other kinds refuse one)."""
    weight: float = 1.0
    """Scale of the uncertainty loss in the total loss."""
    extra_heads: tuple[str, ...] = ()
    """More uncertainty heads trained in the same run, each these settings with overrides, e.g. "lam=0.1",
    "kind=antipodal,threshold=0.2" or "degree=0" (keys: kind, lam, threshold, num_dirs, degree ≤ the model's
    u_sh_degree). Each head is one more channel of u_sh. L_u never moves the geometry, so a head learns the u_sh
    a separate run with its settings would (to float32 rounding): an ablation costs one training, not one each.
    The logged uncertainty loss is then the sum over the heads."""

    def __post_init__(self) -> None:
        self.check_loadable()

    def validate(self) -> None:
        """`check_loadable`, and what a new run may not use (a saved run that used it still loads and resumes)."""
        self.check_loadable()
        heads = [("", self), *((f" in uncertainty head {spec!r}", parse_head(spec, self, MAX_SH_DEGREE).loss)
                               for spec in self.extra_heads)]
        for named, loss in heads:
            where = IN_HEADS if named else "in --uncertainty.threshold"
            if loss.threshold == 0.0:  # it would supervise Gaussians this view never drew as seen (19c6c8f)
                raise SplatuError(f"uncertainty threshold = {loss.threshold} is not a blend weight in "
                                  f"(0, {ALPHA_MAX}]{named}", where, "use e.g. 0.05")
            if loss.threshold > ALPHA_MAX:  # no blend weight reaches it: u_sh would silently never train
                raise SplatuError(f"uncertainty threshold = {loss.threshold} is above {ALPHA_MAX}, the largest blend"
                                  f" weight (α is clamped there), so it would supervise no Gaussian{named}", where,
                                  "use e.g. 0.05")
        self.refuse_settings_the_kind_ignores()

    def refuse_settings_the_kind_ignores(self) -> None:
        """A setting its loss kind never reads (`ignored_by`), set away from its default or typed in a head, would be
        recorded as if it had trained: `--uncertainty.kind weighted --uncertainty.threshold 0.2` trained as without
        the threshold (which then only set the visibility baselines' cutoff, splatu/baselines/load.py). A head's
        inherited values are not its own: only the keys its spec types are checked."""
        if self.off:  # a preset file may hold the loss's settings for the runs that train it
            return
        for key in ("threshold", "num_dirs"):
            value = getattr(self, key)
            if ignored_by(self.kind, key) and value != getattr(UncertaintyLossConfig, key):
                flag = f"--uncertainty.{key.replace('_', '-')}"
                raise SplatuError(f"{flag} {value} is not read by the loss --uncertainty.kind {self.kind} trains: "
                                  f"{IGNORED_BECAUSE[key]}", f"in {flag}",
                                  f"drop it, or use --uncertainty.kind {USED_BY[key]}")
        for spec in self.extra_heads:
            typed = _head_values(spec)
            kind = typed.get("kind", self.kind)
            for key in typed:
                if ignored_by(str(kind), key):
                    raise SplatuError(f"{key}={typed[key]} is not read by the loss of uncertainty head {spec!r}, "
                                      f"whose kind is {kind}: {IGNORED_BECAUSE[key]}", IN_HEADS,
                                      f"drop {key}, or give the head kind {USED_BY[key].replace(' or ', ' or kind ')}")

    def check_loadable(self) -> None:
        """Raise a one-line SplatuError for settings the loss cannot use. Threshold 0 passes: runs trained with it
        before it was refused (it supervises every Gaussian, finitely) must load for render, eval and resume."""
        if not 0.0 <= self.lam < 0.5:
            raise SplatuError(f"uncertainty λ = {self.lam} is not in [0, 0.5)", "in --uncertainty.lam",
                              "use λ < 0.5 (the paper's condition), e.g. 0.3")
        if not 0.0 <= self.threshold <= 1.0:
            raise SplatuError(f"uncertainty threshold = {self.threshold} is not a blend weight in (0, 1]",
                              "in --uncertainty.threshold", "use e.g. 0.05")
        if self.num_dirs < 1:
            raise SplatuError(f"uncertainty num_dirs = {self.num_dirs} is below 1", "in --uncertainty.num-dirs",
                              "use e.g. 16")
        if not (math.isfinite(self.weight) and self.weight >= 0.0):
            raise SplatuError(f"uncertainty weight = {self.weight} is not a finite non-negative number",
                              "in --uncertainty.weight", "use e.g. 1.0")
        if self.extra_heads and self.off:
            raise SplatuError("extra uncertainty heads with the uncertainty loss off would never train",
                              "in --uncertainty.extra-heads", "drop them, or train with the loss on")
        parsed = [parse_head(spec, self, MAX_SH_DEGREE) for spec in self.extra_heads]
        settings = [(h.loss, h.degree) for h in parsed]
        for head, setting in zip(parsed, settings, strict=True):
            if settings.count(setting) > 1:
                raise SplatuError(f"uncertainty head {head.name!r} repeats another head's settings",
                                  "in --uncertainty.extra-heads", "give each extra head different settings")


@dataclass(frozen=True)
class UncertaintyHead:
    """One channel of u_sh and the loss settings that train it."""

    name: str
    loss: UncertaintyLossConfig
    degree: int


HEAD_KEYS = ("kind", "lam", "threshold", "num_dirs", "degree")
IN_HEADS = "in --uncertainty.extra-heads"


def _head_values(spec: str) -> dict[str, str | int | float]:
    """The typed key=value pairs of head `spec` ("key=value,key=value"), or a one-line error."""
    values: dict[str, str] = {}
    for item in spec.split(","):
        key, sep, value = (part.strip() for part in item.partition("="))
        problem = ("not key=value" if not sep else f"unknown key {key!r}" if key not in HEAD_KEYS
                   else f"{key!r} given twice" if key in values else None)
        if problem is not None:
            raise SplatuError(f"bad uncertainty head {spec!r}: {problem}", IN_HEADS,
                              f"write key=value pairs joined by commas, keys from {', '.join(HEAD_KEYS)}")
        values[key] = value
    typed: dict[str, str | int | float] = {}
    for key, value in values.items():
        try:
            typed[key] = value if key == "kind" else int(value) if key in ("num_dirs", "degree") else float(value)
        except ValueError:
            raise SplatuError(f"{key}={value!r} is not a number in uncertainty head {spec!r}", IN_HEADS,
                              "e.g. lam=0.1,degree=2") from None
    return typed


def canonical_head(spec: str) -> str:
    """One spelling per head: its pairs in `HEAD_KEYS` order, numbers as Python prints them, so that
    "degree=1,lam=0.10" and "lam=0.1,degree=1" name the same output files."""
    values = _head_values(spec)
    return ",".join(f"{key}={values[key]}" for key in HEAD_KEYS if key in values)


def parse_head(spec: str, base: UncertaintyLossConfig, max_degree: int) -> UncertaintyHead:
    """The head `spec` ("key=value,key=value") describes: `base` with those values replaced."""
    typed = _head_values(spec)
    degree = int(typed.pop("degree", max_degree))
    if typed.get("kind", base.kind) not in ("antipodal", "mean", "weighted"):
        raise SplatuError(f"unknown loss kind in uncertainty head {spec!r}", IN_HEADS,
                          "use antipodal, mean or weighted")
    if not 0 <= degree <= max_degree:
        more = "" if max_degree == MAX_SH_DEGREE else " (raise --model.u-sh-degree for more)"
        raise SplatuError(f"uncertainty head {spec!r} asks for degree {degree}, above the u-SH degree {max_degree}"
                          if degree > 0 else f"uncertainty head {spec!r} asks for a negative degree", IN_HEADS,
                          f"use a degree from 0 to {max_degree}{more}")
    try:
        loss = dataclasses.replace(base, extra_heads=(), **typed)
    except SplatuError as err:  # name the head, not the run's own flag
        raise SplatuError(f"{err.what} in uncertainty head {spec!r}", IN_HEADS, err.fix) from None
    return UncertaintyHead(spec, loss, degree)


def uncertainty_heads(cfg: UncertaintyLossConfig, model_degree: int) -> list[UncertaintyHead]:
    """Channel 0 is the run's own settings at the model's degree; then one per extra head, in order."""
    own = UncertaintyHead("own", dataclasses.replace(cfg, extra_heads=()), model_degree)
    return [own, *(parse_head(spec, cfg, model_degree) for spec in cfg.extra_heads)]


def refuse_copies_of_the_own_head(cfg: UncertaintyLossConfig, model_degree: int) -> None:
    """An extra head with the run's own settings at the model's degree would train a second copy of channel 0 under
    another name (`validate` compares the extra heads with each other only: it does not know the model's degree)."""
    own, *extra = uncertainty_heads(cfg, model_degree)
    for head in extra:
        if (head.loss, head.degree) == (own.loss, own.degree):
            raise SplatuError(f"uncertainty head {head.name!r} repeats the run's own settings", IN_HEADS,
                              "drop it (the run's own head already trains them), or change a setting")


def uncertainty_loss(model: GaussianModel, camera_center: Tensor, raster: RasterOutput, cfg: UncertaintyLossConfig,
                     generators: Sequence[torch.Generator] | None = None) -> Tensor:
    """L_u for one training view (REFERENCE §1), summed over the uncertainty heads, each scaled by its weight.

    antipodal: mean over supervised i of (1−λ)·u_i(d) + λ·(1 − u_i(−d)).
    mean:      u_i(−d) replaced by ū_i, the mean of u_i over `num_dirs` random unit directions (shared by all
               Gaussians in this step, drawn from the head's own generator in `generators`, seeded alike, so
               each head draws what it would draw alone).
    weighted:  over every Gaussian seen in this view (max weight ≥ 1/255), (1−λ)·w_i·u_i(d) + λ·(1 − u_i(−d))
               with w_i = its max blend weight in [0, 1] (contrib_max: bounded, and unlike the summed weight it
               does not grow with the Gaussian's screen size). A faint Gaussian is pulled towards certain only
               faintly, so it stays uncertain; no hard threshold.
    d = normalize(mean − camera centre) is detached, so only `u_sh` receives gradient; head h reads only
    channel h, so the heads never mix. With nothing supervised the result is 0 but still connected to `u_sh`,
    so callers can add it unconditionally.
    """
    cfg.check_loadable()
    heads = uncertainty_heads(cfg, model.cfg.u_sh_degree)
    if model.u_sh.shape[-1] != len(heads) or (generators is not None and len(generators) != len(heads)):
        raise ValueError(f"{len(heads)} uncertainty heads, but u_sh has {model.u_sh.shape[-1]} channels"
                         f" and {'no' if generators is None else len(generators)} generators were given")
    total = model.u_sh.sum() * 0.0
    for channel, head in enumerate(heads):
        u_sh = head_coefficients(model.u_sh, channel, head.degree)
        generator = None if generators is None else generators[channel]
        total = total + _head_loss(u_sh, head, model.means.detach(), camera_center, raster, generator)
    return total


def _head_loss(u_sh: Tensor, head: UncertaintyHead, means: Tensor, camera_center: Tensor, raster: RasterOutput,
               generator: torch.Generator | None) -> Tensor:
    """One head's L_u (see `uncertainty_loss`), scaled by its weight; 0 when it supervises nothing."""
    cfg, degree = head.loss, head.degree
    weights = raster.contrib_max.detach()
    cutoff = MIN_VISIBLE_WEIGHT if cfg.kind == "weighted" else cfg.threshold
    selected = torch.nonzero(weights >= cutoff).squeeze(-1)
    if selected.numel() == 0:
        return u_sh.sum() * 0.0
    u_sh = u_sh[selected]
    dirs = safe_normalize(means[selected] - camera_center.detach().to(means))

    if cfg.kind == "mean":
        seen = torch.sigmoid(eval_sh(u_sh, dirs, degree)).squeeze(-1)
        random_dirs = torch.randn(cfg.num_dirs, 3, generator=generator).to(u_sh)
        other = torch.sigmoid(eval_sh(u_sh.unsqueeze(1), safe_normalize(random_dirs), degree)).squeeze(-1).mean(1)
    else:  # Y_l(−d) = (−1)^l·Y_l(d): one basis evaluation gives u(d) and u(−d), from the even and odd bands
        terms = sh_basis(dirs, degree).to(u_sh) * u_sh[..., 0]
        parity = 1.0 - 2.0 * (torch.arange(terms.shape[-1]).sqrt().floor() % 2)  # (−1)^l per coefficient
        seen, other = torch.sigmoid(terms.sum(-1)), torch.sigmoid(terms @ parity.to(terms))
    first = seen * weights[selected] if cfg.kind == "weighted" else seen
    # λ·(1 − u(−d)), as REFERENCE §1: the paper prints λ·(u(−x) − 1), which minimised would push u(−x) down,
    # against its stated intent that the directions opposite a view stay uncertain
    loss = ((1.0 - cfg.lam) * first + cfg.lam * (1.0 - other)).mean()
    return cfg.weight * loss
