"""Sparsification curves, AUSE and AUROC-unobserved, exactly as REFERENCE.md §4 defines them.

Why the extras: joint-max-normalised AUSE can score an *anti-correlated* uncertainty better
than a random one on heavy-tailed errors (the worst pixels inflate the normaliser M). So every
score here is reported beside the random baseline (mean over seeds) and the start-normalised
variant (curves divided by O(0) = S(0)), which does expose anti-correlation. The oracle's AUSE
is 0 by construction, so what is reported for it is its AUSC, the area under its curve (the
lowest mean error any ordering can leave), beside ours and random's: AUSC - oracle AUSC is the
un-normalised gap that AUSE divides by M.

Grid: r_k = k/100, k = 0..99, n_k = floor((1 - r_k)·N) pixels kept (at least 1).
Per-pixel error e_p sums over RGB: |Î - I| for MAE, (Î - I)² for MSE and RMSE. A curve value
is the mean of the kept e_p (MAE, MSE) or the square root of that mean (RMSE).
Degenerate images are defined, never divided by zero: when every kept error is 0 the
normaliser is 0 and AUSE is 0 (every ordering is perfect).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np

Metric = Literal["mae", "rmse", "mse"]
FRACTIONS = np.arange(100) / 100.0
"""The removal grid r_k = k/100, k = 0..99 (FisherRF uses 0..0.999: not comparable)."""
RANDOM_SEEDS = (0, 1, 2, 3, 4)
"""Seeds of the random-uncertainty baseline; its AUSE is the mean over them."""
RANDOM_STREAM = 0x5A5E
"""Stream key mixed into the baseline seeds, so the noise never replays a user's own seeded draws."""
TIE_SEED = 0
"""Seed of the fixed permutation that breaks ties in u, so equal u never follows pixel order."""
CAPTION = "per-pixel error summed over RGB, grid r=k/100 k=0..99, joint-max normalisation, mean over images"


@dataclass(frozen=True)
class Curves:
    """Oracle and sparsification curves of one image on the grid `FRACTIONS`."""

    oracle: np.ndarray
    sparsification: np.ndarray


def pixel_errors(rendered: np.ndarray, target: np.ndarray, metric: Metric = "mae") -> np.ndarray:
    """Per-pixel error summed over channels: absolute for MAE, squared for MSE/RMSE, (H, W)."""
    if rendered.shape != target.shape:
        raise ValueError(f"rendered {rendered.shape} and target {target.shape} differ in shape")
    diff = rendered.astype(np.float64) - target.astype(np.float64)
    per_channel = np.abs(diff) if metric == "mae" else diff**2
    return per_channel.sum(axis=-1) if per_channel.ndim == 3 else per_channel


def kept_counts(n_pixels: int) -> np.ndarray:
    """n_k = floor((1 - k/100)·N) in exact integer arithmetic, never below one pixel."""
    return np.maximum(((100 - np.arange(100)) * n_pixels) // 100, 1)


def _curve_of_order(errors_in_order: np.ndarray, metric: Metric) -> np.ndarray:
    """Mean of the first n_k errors of an ordering, for every k (sqrt of it for RMSE)."""
    counts = kept_counts(errors_in_order.size)
    means = np.cumsum(errors_in_order)[counts - 1] / counts
    return np.sqrt(means) if metric == "rmse" else means


def uncertainty_order(uncertainty: np.ndarray, tie_seed: int) -> np.ndarray:
    """Pixel indices by increasing u; equal u keep the order of a fixed random permutation."""
    flat = uncertainty.reshape(-1)
    permutation = np.random.default_rng(tie_seed).permutation(flat.size)
    return permutation[np.argsort(flat[permutation], kind="stable")]


def sparsification_curves(errors: np.ndarray, uncertainty: np.ndarray, metric: Metric = "mae",
                          tie_seed: int = TIE_SEED) -> Curves:
    """Oracle O(r_k) (keep the smallest errors) and sparsification S(r_k) (keep the smallest u)."""
    e = errors.reshape(-1).astype(np.float64)
    u = uncertainty.reshape(-1).astype(np.float64)
    if e.size != u.size or e.size == 0:
        raise ValueError(f"errors ({e.size}) and uncertainty ({u.size}) need the same non-zero size")
    if not (np.isfinite(e).all() and np.isfinite(u).all()):
        raise ValueError("errors and uncertainty must be finite")
    oracle = _curve_of_order(np.sort(e), metric)
    sparsification = _curve_of_order(e[uncertainty_order(u, tie_seed)], metric)
    return Curves(oracle=oracle, sparsification=sparsification)


def ause(curves: Curves) -> float:
    """np.trapezoid((S - O)/M, r) over [0, 0.99] with M = max(max O, max S); 0 when M is 0."""
    normaliser = max(curves.oracle.max(), curves.sparsification.max())
    if normaliser <= 0.0:
        return 0.0
    return float(np.trapezoid((curves.sparsification - curves.oracle) / normaliser, FRACTIONS))


def ausc(curve: np.ndarray) -> float:
    """np.trapezoid(curve, r) over [0, 0.99]: the area under one curve, in the metric's own error units."""
    return float(np.trapezoid(curve, FRACTIONS))


def start_normalised(curves: Curves) -> Curves:
    """Both curves divided by O(0) = S(0), the mean error. When every error is 0, kept pixels err exactly as much
    as all of them, so both curves are 1: zeros would pull a mean over views below 1 at r = 0, where it is 1."""
    if curves.oracle[0] <= 0.0:
        return Curves(np.ones_like(curves.oracle), np.ones_like(curves.sparsification))
    return Curves(curves.oracle / curves.oracle[0], curves.sparsification / curves.oracle[0])


def ause_start_normalised(curves: Curves) -> float:
    """The same area with both curves divided by O(0) = S(0); 0 when every error is 0."""
    normalised = start_normalised(curves)
    return float(np.trapezoid(normalised.sparsification - normalised.oracle, FRACTIONS))


def random_curves(errors: np.ndarray, metric: Metric, seed: int) -> Curves:
    """Curves of uniform-noise uncertainty: draw `seed` of the random baseline (ties broken by the same seed)."""
    noise = np.random.default_rng((RANDOM_STREAM, seed)).random(errors.size)
    return sparsification_curves(errors, noise, metric, tie_seed=seed)


class RandomScores(NamedTuple):
    """The random baseline's numbers, each the mean over its seeds."""

    ause: float
    ause_start_norm: float
    ausc: float


def random_baseline(errors: np.ndarray) -> RandomScores:
    """AUSE, start-normalised AUSE and AUSC (MAE) of uniform-noise uncertainty, each the mean over `RANDOM_SEEDS`."""
    return random_scores([random_curves(errors, "mae", seed) for seed in RANDOM_SEEDS])


def random_scores(curves: Sequence[Curves]) -> RandomScores:
    """The random baseline's numbers from its curves, one per seed: each the mean over the seeds."""
    scores = [(ause(c), ause_start_normalised(c), ausc(c.sparsification)) for c in curves]
    return RandomScores(*(float(v) for v in np.mean(scores, axis=0)))


class ImageCurves(NamedTuple):
    """One image's curves for one metric: what its scores are computed from, and what eval-ause plots."""

    ours: Curves
    random: list[Curves]
    """One per `RANDOM_SEEDS`."""


def auroc(scores: np.ndarray, positives: np.ndarray) -> float | None:
    """Rank-based (Mann-Whitney) area under the ROC curve; ties get average ranks.

    None when either class is empty: the AUROC is then undefined, not 0.5.
    """
    s = scores.reshape(-1).astype(np.float64)
    pos = positives.reshape(-1).astype(bool)
    n_pos = int(pos.sum())
    n_neg = pos.size - n_pos
    if n_pos == 0 or n_neg == 0:
        return None
    _, inverse, counts = np.unique(s, return_inverse=True, return_counts=True)
    first_rank = np.cumsum(counts) - counts + 1  # 1-based rank of each distinct value's first member
    average_rank = first_rank + (counts - 1) / 2.0
    rank_sum = average_rank[inverse][pos].sum()
    return float((rank_sum - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


def score_image(rendered: np.ndarray, target: np.ndarray, uncertainty: np.ndarray,
                valid: np.ndarray | None = None, unobserved: np.ndarray | None = None,
                metrics: Sequence[Metric] = ("mae", "rmse")
                ) -> tuple[dict[str, float | None], dict[Metric, ImageCurves]]:
    """Every number one image contributes: AUSE, random, start-normalised, AUSC (ours, random, oracle), AUROC; and
    per metric the curves they come from, so that a plot shows the very curves the numbers measure.

    `valid` (H, W) restricts the pixels scored (e.g. a blender alpha mask); `unobserved`
    (H, W) marks pixels no training camera saw, for AUROC-unobserved.
    """
    if uncertainty.shape != rendered.shape[:2]:
        raise ValueError(f"uncertainty {uncertainty.shape} does not match image {rendered.shape[:2]}")
    keep = np.ones(uncertainty.shape, bool) if valid is None else valid.astype(bool)
    result: dict[str, float | None] = {}
    all_curves: dict[Metric, ImageCurves] = {}
    for metric in metrics:
        errors = pixel_errors(rendered, target, metric)[keep]
        all_curves[metric] = ImageCurves(sparsification_curves(errors, uncertainty[keep], metric),
                                         [random_curves(errors, metric, seed) for seed in RANDOM_SEEDS])
        curves, random = all_curves[metric].ours, random_scores(all_curves[metric].random)
        result[f"ause_{metric}"] = ause(curves)
        result[f"random_ause_{metric}"] = random.ause
        result[f"ause_{metric}_start_norm"] = ause_start_normalised(curves)
        result[f"random_ause_{metric}_start_norm"] = random.ause_start_norm
        result[f"ausc_{metric}"] = ausc(curves.sparsification)
        result[f"random_ausc_{metric}"] = random.ausc
        result[f"oracle_ausc_{metric}"] = ausc(curves.oracle)
    result["auroc_unobserved"] = None if unobserved is None else auroc(uncertainty[keep], unobserved[keep])
    return result, all_curves


def mean_scores(per_image: Mapping[str, Mapping[str, float | None]]) -> dict[str, float | None]:
    """Mean of each number over images; a number undefined on every image stays None."""
    keys = next(iter(per_image.values())).keys() if per_image else ()
    means: dict[str, float | None] = {}
    for key in keys:
        values = [v[key] for v in per_image.values() if v[key] is not None]
        means[key] = float(np.mean(values)) if values else None
    return means
