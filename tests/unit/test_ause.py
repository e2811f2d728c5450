"""AUSE and AUROC on constructed inputs whose answers are known in closed form."""

import numpy as np
import pytest

from splatu import ause as A


def _rng(seed: int = 123) -> np.random.Generator:
    return np.random.default_rng(seed)


def test_oracle_uncertainty_scores_zero():
    errors = _rng().exponential(size=20_000)
    curves = A.sparsification_curves(errors, errors)
    assert A.ause(curves) == pytest.approx(0.0, abs=1e-12)
    assert A.ause_start_normalised(curves) == pytest.approx(0.0, abs=1e-12)
    # a monotone transform of the error is just as perfect
    assert A.ause(A.sparsification_curves(errors, np.log1p(errors))) == pytest.approx(0.0, abs=1e-12)


def test_random_uncertainty_matches_closed_form_on_uniform_errors():
    # e ~ U(0,1): O(r) = (1-r)/2 and E[S(r)] = 1/2, so (S-O)/M ≈ r and AUSE ≈ ∫_0^0.99 r dr = 0.49005
    errors = _rng().random(50_000)
    joint, start, _ = A.random_baseline(errors)
    assert joint == pytest.approx(0.49005, abs=0.02)
    assert start == pytest.approx(0.49005, abs=0.02)


def test_curves_follow_the_grid_definition():
    errors = np.arange(10, dtype=float)  # N = 10: n_k = floor((100-k)·10/100), at least 1
    curves = A.sparsification_curves(errors, errors)
    assert A.kept_counts(10)[[0, 10, 11, 95, 99]].tolist() == [10, 9, 8, 1, 1]
    assert curves.oracle[0] == pytest.approx(4.5)  # mean of 0..9
    assert curves.oracle[10] == pytest.approx(4.0)  # mean of 0..8
    reversed_curves = A.sparsification_curves(errors, -errors)
    assert reversed_curves.sparsification[10] == pytest.approx(5.0)  # mean of 1..9


def test_a_six_pixel_image_by_hand():
    """u orders the errors 0, 5, 1, 2, 4, 3, so the kept means are 2.5, 2.4, 2, 2, 2.5, 0 against the oracle's 2.5,
    2, 1.5, 1, 0.5, 0; n_k = floor((100 - k)·6/100) keeps 6 pixels at k = 0, 5 for k ≤ 16, 4 to 33, 3 to 50, 2 to
    66, then 1. M = 2.5, and the trapezoid over the 0.01 grid (both ends 0) is 0.01·Σ(S - O)/M
    = 0.01·(16·0.4 + 17·0.5 + 17·1 + 16·2)/2.5 = 0.2556."""
    errors = np.array([5.0, 0.0, 3.0, 1.0, 4.0, 2.0])
    uncertainty = np.array([0.2, 0.1, 0.9, 0.3, 0.8, 0.4])
    curves = A.sparsification_curves(errors, uncertainty)
    steps = [0, 1, 16, 17, 33, 34, 50, 51, 66, 67, 99]
    np.testing.assert_allclose(curves.sparsification[steps], [2.5, 2.4, 2.4, 2, 2, 2, 2, 2.5, 2.5, 0, 0])
    np.testing.assert_allclose(curves.oracle[steps], [2.5, 2, 2, 1.5, 1.5, 1, 1, 0.5, 0.5, 0, 0])
    assert A.ause(curves) == pytest.approx(0.2556, abs=1e-12)
    assert A.ause_start_normalised(curves) == pytest.approx(0.2556, abs=1e-12)


def _brute_force_ause(errors: np.ndarray, uncertainty: np.ndarray, metric: A.Metric) -> float:
    """REFERENCE §4 step by step in plain Python: ties in u go by each pixel's place in the fixed permutation."""
    place = {int(p): i for i, p in enumerate(np.random.default_rng(A.TIE_SEED).permutation(errors.size))}
    by_u = sorted(range(errors.size), key=lambda p: (uncertainty[p], place[p]))
    by_e = sorted(range(errors.size), key=lambda p: errors[p])

    def value(kept: list[int]) -> float:
        mean = sum(errors[p] for p in kept) / len(kept)
        return mean**0.5 if metric == "rmse" else mean

    n = [max((100 - k) * errors.size // 100, 1) for k in range(100)]
    oracle = [value(by_e[:n_k]) for n_k in n]
    sparsification = [value(by_u[:n_k]) for n_k in n]
    top = max(max(oracle), max(sparsification))
    gap = [(s - o) / top for s, o in zip(sparsification, oracle, strict=True)] if top > 0 else [0.0] * 100
    return sum((gap[k] + gap[k + 1]) / 2 * 0.01 for k in range(99))


@pytest.mark.parametrize("metric", ["mae", "mse", "rmse"])
def test_ause_agrees_with_a_brute_force_on_small_images_with_ties(metric):
    rng = _rng(5)
    for size in (1, 2, 7, 99, 101, 257):
        errors = rng.integers(0, 4, size).astype(float)  # tied errors
        uncertainty = rng.integers(0, 3, size).astype(float)  # tied uncertainties
        curves = A.sparsification_curves(errors, uncertainty, metric)
        assert A.ause(curves) == pytest.approx(_brute_force_ause(errors, uncertainty, metric), abs=1e-12)


def test_rmse_and_mse_curves():
    rendered = np.zeros((1, 4, 3))
    target = np.zeros((1, 4, 3))
    target[0, :, 0] = [1.0, 2.0, 3.0, 4.0]  # squared error per pixel: 1, 4, 9, 16
    squared = A.pixel_errors(rendered, target, "mse")
    assert squared.ravel().tolist() == [1.0, 4.0, 9.0, 16.0]
    mse = A.sparsification_curves(squared, squared, "mse")
    rmse = A.sparsification_curves(squared, squared, "rmse")
    assert mse.oracle[0] == pytest.approx(7.5)
    assert rmse.oracle[0] == pytest.approx(np.sqrt(7.5))
    assert rmse.oracle[50] == pytest.approx(np.sqrt(2.5))  # keeps the 2 smallest: 1 and 4


def test_anti_correlated_beats_random_under_joint_max_on_heavy_tails_but_not_start_normalised():
    """The documented pitfall (REFERENCE §4): on heavy-tailed errors the worst pixels inflate M.

    Measured here on 50k log-normal(σ=1.5) errors: anti ≈ 0.13 vs random ≈ 0.73 (joint max),
    but anti ≈ 2.6 vs random ≈ 0.79 start-normalised, which exposes it.
    """
    errors = _rng().lognormal(0.0, 1.5, 50_000)
    anti = A.sparsification_curves(errors, -errors)
    random_joint, random_start, _ = A.random_baseline(errors)
    assert A.ause(anti) < 0.5 * random_joint
    assert A.ause_start_normalised(anti) > 2.0 * random_start


def test_anti_correlated_is_no_better_than_random_on_light_tails():
    errors = _rng().random(50_000)
    anti = A.sparsification_curves(errors, -errors)
    random_joint = A.random_baseline(errors).ause
    assert A.ause(anti) >= random_joint - 0.01


def test_ties_are_deterministic_and_constant_u_is_defined():
    errors = _rng().exponential(size=5_000)
    constant = np.full_like(errors, 0.3)
    first = A.ause(A.sparsification_curves(errors, constant))
    second = A.ause(A.sparsification_curves(errors, constant))
    assert first == second
    # a constant u keeps pixels in a fixed random order: it scores like a random uncertainty
    random_joint = A.random_baseline(errors).ause
    assert first == pytest.approx(random_joint, abs=0.05)
    # ties are not broken by pixel order: sorted errors with constant u must not look like the oracle
    ordered = np.sort(errors)
    assert A.ause(A.sparsification_curves(ordered, np.zeros_like(ordered))) > 0.3


def test_constant_error_does_not_divide_by_zero():
    for value in (0.0, 0.25):
        errors = np.full(1_000, value)
        curves = A.sparsification_curves(errors, _rng().random(1_000))
        assert A.ause(curves) == 0.0
        assert A.ause_start_normalised(curves) == 0.0
        joint, start, _ = A.random_baseline(errors)
        assert (joint, start) == (0.0, 0.0)


def test_non_finite_inputs_are_refused():
    with pytest.raises(ValueError):
        A.sparsification_curves(np.array([1.0, np.nan]), np.array([0.0, 1.0]))
    with pytest.raises(ValueError):
        A.sparsification_curves(np.ones(3), np.ones(4))


def test_auroc_perfect_inverted_random_and_ties():
    positives = np.zeros(10_000, bool)
    positives[:3_000] = True
    scores = positives.astype(float) + 0.1 * _rng().random(10_000)
    assert A.auroc(scores, positives) == pytest.approx(1.0)
    assert A.auroc(-scores, positives) == pytest.approx(0.0)
    assert A.auroc(_rng(7).random(10_000), positives) == pytest.approx(0.5, abs=0.02)
    assert A.auroc(np.ones(10_000), positives) == pytest.approx(0.5)  # all tied: chance
    # small case by hand: pos {2, 1}, neg {1, 0}: pairs (2>1),(2>0),(1=1 → ½),(1>0) = 3.5/4
    assert A.auroc(np.array([2.0, 1.0, 1.0, 0.0]), np.array([1, 1, 0, 0], bool)) == pytest.approx(0.875)
    assert A.auroc(scores, np.zeros(10_000, bool)) is None


def test_auroc_agrees_with_counting_pairs():
    """AUROC = P(u of an unobserved pixel > u of an observed one) + ½ P(equal), over every pair."""
    rng = _rng(9)
    for _ in range(20):
        scores = rng.integers(0, 4, 40).astype(float)
        positives = rng.random(40) < 0.3
        pairs = [(1.0 if a > b else 0.5 if a == b else 0.0) for a in scores[positives] for b in scores[~positives]]
        assert A.auroc(scores, positives) == pytest.approx(float(np.mean(pairs)), abs=1e-12)


def test_score_image_and_mean():
    rng = _rng()
    target = rng.random((32, 40, 3))
    rendered = target + rng.normal(0.0, 0.1, target.shape)
    errors = A.pixel_errors(rendered, target)
    unobserved = errors > np.median(errors)
    scores = A.score_image(rendered, target, errors / errors.max(), unobserved=unobserved)[0]
    assert scores["ause_mae"] == pytest.approx(0.0, abs=1e-12)
    # the MAE error orders pixels almost, not exactly, like the squared error
    assert 0.0 < scores["ause_rmse"] < 0.2 * scores["random_ause_rmse"]
    assert scores["random_ause_mae"] > 0.2
    assert "oracle_ause_mae" not in scores  # 0 by definition: the oracle is reported by its AUSC instead
    assert scores["ausc_mae"] == pytest.approx(scores["oracle_ausc_mae"])
    assert scores["oracle_ausc_mae"] < 0.7 * scores["random_ausc_mae"]
    assert scores["auroc_unobserved"] == pytest.approx(1.0)
    other = dict(scores, ause_mae=0.5, auroc_unobserved=None)
    means = A.mean_scores({"a": scores, "b": other})
    assert means["ause_mae"] == pytest.approx(0.25)
    assert means["auroc_unobserved"] == pytest.approx(1.0)
    valid = np.zeros((32, 40), bool)
    valid[:, :20] = True
    masked, _ = A.score_image(rendered, target, rng.random((32, 40)), valid=valid)
    assert masked["ause_mae"] > 0.1


def test_ausc_is_the_area_under_each_curve_and_its_gap_is_the_unnormalised_ause():
    # e = 0..9 (N = 10): O(r_k) is the mean of the floor((1 - k/100)·10) smallest errors, in closed form
    errors = np.arange(10.0)
    counts = np.maximum(((100 - np.arange(100)) * 10) // 100, 1)
    expected_oracle = np.trapezoid((counts - 1) / 2.0, A.FRACTIONS)
    curves = A.sparsification_curves(errors, -errors)  # worst first: S keeps the largest errors
    scores, _ = A.score_image(errors[:, None, None] * np.ones((10, 1, 3)) / 3.0, np.zeros((10, 1, 3)),
                              -errors[:, None], metrics=("mae",))
    assert A.ausc(curves.oracle) == pytest.approx(expected_oracle)
    assert scores["oracle_ausc_mae"] == pytest.approx(expected_oracle)
    assert scores["ausc_mae"] == pytest.approx(np.trapezoid(9.0 - (counts - 1) / 2.0, A.FRACTIONS))
    normaliser = max(curves.oracle.max(), curves.sparsification.max())
    assert (scores["ausc_mae"] - scores["oracle_ausc_mae"]) / normaliser == pytest.approx(scores["ause_mae"])
    # uniform errors: E[S(r)] = mean error, so random's AUSC is about 0.99 · mean
    uniform = _rng().random(50_000)
    assert A.random_baseline(uniform).ausc == pytest.approx(0.99 * uniform.mean(), rel=0.01)


def test_start_normalised_curves_start_at_one_and_random_baseline_averages_its_seeds():
    errors = np.random.default_rng(3).lognormal(0.0, 1.0, 2000)
    curves = A.start_normalised(A.random_curves(errors, "mae", A.RANDOM_SEEDS[0]))
    assert curves.oracle[0] == pytest.approx(1.0) and curves.sparsification[0] == pytest.approx(1.0)
    zero = A.start_normalised(A.random_curves(np.zeros(50), "mae", 0))
    assert np.all(zero.oracle == 1.0) and np.all(zero.sparsification == 1.0)  # no error: kept err as all do
    per_seed = [A.ause(A.random_curves(errors, "mae", s)) for s in A.RANDOM_SEEDS]
    assert A.random_baseline(errors)[0] == pytest.approx(np.mean(per_seed))


def test_pixels_outside_the_valid_mask_change_no_score():
    """Scoring with a mask equals scoring the valid pixels alone, whatever the masked pixels hold."""
    rng = _rng()
    target = rng.random((32, 40, 3))
    rendered = target + rng.normal(0.0, 0.1, target.shape)
    uncertainty = rng.random((32, 40))
    unobserved = rng.random((32, 40)) < 0.3
    valid = rng.random((32, 40)) < 0.6
    alone = A.score_image(rendered[valid][:, None], target[valid][:, None], uncertainty[valid][:, None],
                          unobserved=unobserved[valid][:, None])[0]  # an N×1 image, in the mask's row-major order
    rendered[~valid] = 5.0  # far worse than any valid pixel, and ranked the most certain
    uncertainty[~valid] = -1.0
    assert A.score_image(rendered, target, uncertainty, valid=valid, unobserved=unobserved)[0] == alone


def test_the_random_baseline_draws_a_different_uncertainty_for_each_seed():
    """Random's scores are means over RANDOM_SEEDS: seeds that replayed one draw would average nothing."""
    errors = _rng().exponential(size=2_000)
    draws = [A.random_curves(errors, "mae", seed).sparsification for seed in A.RANDOM_SEEDS]
    assert len({curve.tobytes() for curve in draws}) == len(A.RANDOM_SEEDS)
    assert len({A.ause(A.random_curves(errors, "mae", seed)) for seed in A.RANDOM_SEEDS}) == len(A.RANDOM_SEEDS)
