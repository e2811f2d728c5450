"""benchmarks/view_ranking.py's statistics: Spearman's ρ with ties, and the first pick's error rank."""

from __future__ import annotations

import numpy as np
import pytest

from tests.benchmark_scripts import benchmark_script


@pytest.fixture(scope="module")
def ranking():
    yield from benchmark_script("view_ranking")


def test_spearman_is_one_for_any_increasing_map_minus_one_for_a_decreasing_one(ranking) -> None:
    x = np.array([0.3, 0.1, 0.7, 0.2, 0.9])
    assert ranking.spearman(x, np.exp(5 * x)) == pytest.approx(1.0)
    assert ranking.spearman(x, -x**3) == pytest.approx(-1.0)
    assert ranking.spearman(x, np.full(5, 0.4)) == 0.0  # no order to agree with


def test_spearman_gives_tied_values_their_mean_rank(ranking) -> None:
    assert ranking.ranks(np.array([2.0, 1.0, 2.0, 3.0])).tolist() == [2.5, 1.0, 2.5, 4.0]
    # the Pearson correlation of the ranks [1, 2.5, 2.5, 4] and [1, 2, 3, 4] (by hand: 4.5 / sqrt(4.5 * 5))
    assert ranking.spearman(np.array([1.0, 2.0, 2.0, 3.0]), np.arange(4.0)) == pytest.approx(np.sqrt(0.9))


def test_the_first_pick_is_the_most_uncertain_view_ranked_by_its_error(ranking) -> None:
    error = np.array([0.5, 0.9, 0.1, 0.7])
    assert ranking.first_pick_rank(np.array([0.2, 0.8, 0.1, 0.3]), error) == 1  # picks the worst view
    assert ranking.first_pick_rank(np.array([0.2, 0.1, 0.1, 0.3]), error) == 2
    assert ranking.first_pick_rank(np.array([0.2, 0.1, 0.9, 0.3]), error) == 4  # the best view


def test_a_views_error_is_over_the_pixels_ause_scores(ranking) -> None:
    """A scene's object masks (an RGBA image's alpha, its mask files) leave pixels out of AUSE's error; the
    ranking's error left them in, so a masked-out background could decide a view's rank."""
    from splatu.render_uncertainty import RenderedView

    rgb, gt = np.zeros((2, 2, 3)), np.zeros((2, 2, 3))
    gt[0, 0] = 1.0  # wrong by 3 (summed over RGB) at one pixel, which the mask leaves out
    mask = np.array([[False, True], [True, True]])
    view = RenderedView("v", {"rgb": rgb, "uncertainty": np.zeros((2, 2))}, gt=gt)
    assert ranking.view_error(view) == pytest.approx(0.75)  # unmasked: every pixel counts
    view.mask = mask
    assert ranking.view_error(view) == 0.0
    view.mask = np.zeros((2, 2), bool)
    assert ranking.view_error(view) is None  # nothing to score: the view is left out, as eval-ause leaves it out
