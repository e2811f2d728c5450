"""The study's figures: the speed-against-error figure (budgets as markers, methods as colours, partial data
tolerated) and the sparsification figure's oracles."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest

from splatu import figures
from splatu.ause import FRACTIONS, Curves
from splatu.errors import SplatuError
from splatu.figures import (
    ColourScale,
    SpeedPoint,
    distinct_oracles,
    method_lines,
    plot_sparsification,
    plot_speed_against_error,
)

# as the study writes them: a method measured in one budget only, baselines with no PSNR of their own
BUDGETS = {
    "fast": {"ours": SpeedPoint(220.0, 0.45, 23.1), "ensemble-10": SpeedPoint(2187.0, 0.20, 23.7),
             "random": SpeedPoint(220.0, 1.01, None)},
    "quick": {"ours": SpeedPoint(1.2, 0.42, 16.2), "random": SpeedPoint(1.0, 0.99, None)},
}


def test_method_lines_join_budgets_cheapest_first_and_skip_missing_values() -> None:
    ause = method_lines(BUDGETS, "ause_ratio")
    assert ause == {"ours": [(1.2, 0.42), (220.0, 0.45)], "ensemble-10": [(2187.0, 0.20)],
                    "random": [(1.0, 0.99), (220.0, 1.01)]}
    assert "random" not in method_lines(BUDGETS, "psnr")  # no PSNR of its own: no point, no line


def test_speed_figure_is_written(tmp_path: Path) -> None:
    path = tmp_path / "speed.png"
    plot_speed_against_error(path, BUDGETS, "poster: a title long enough to be wrapped " * 4)
    assert min(mpimg.imread(path).shape[:2]) > 100
    single = tmp_path / "one.png"
    plot_speed_against_error(single, {"fast": {"ours": SpeedPoint(220.0, 0.45, None)}}, "one point")
    assert single.stat().st_size > 0


def test_a_method_scored_on_its_own_renders_gets_its_own_oracle(tmp_path: Path) -> None:
    shared = 1.0 - FRACTIONS
    own = (1.0 - FRACTIONS) ** 2
    curves = {"ours": Curves(shared, shared * 0.9), "fisher": Curves(shared.copy(), shared * 0.95),
              "ensemble-10": Curves(own, own * 1.1)}
    oracles = distinct_oracles(curves)
    assert [label for label, _ in oracles] == ["oracle", "oracle (ensemble-10's renders)"]
    np.testing.assert_array_equal(oracles[1][1], own)
    assert [label for label, _ in distinct_oracles({"ours": curves["ours"]})] == ["oracle"]
    path = tmp_path / "curves.png"
    plot_sparsification(path, curves, "poster", "mae")
    assert min(mpimg.imread(path).shape[:2]) > 100


def test_every_figure_is_closed_once_written_or_refused(tmp_path: Path) -> None:
    """pyplot keeps a figure it is not told to close: the study plots one per method and budget, and each held on
    to its memory (matplotlib warns past 20 open figures)."""
    plt.close("all")
    curves = {"ours": Curves(1.0 - FRACTIONS, 0.9 * (1.0 - FRACTIONS))}
    plot_sparsification(tmp_path / "curves.png", curves, "poster", "mae")
    (tmp_path / "taken.png").mkdir()  # a folder where the plot goes: the write is refused
    with pytest.raises(SplatuError):
        plot_sparsification(tmp_path / "taken.png", curves, "poster", "mae")
    assert plt.get_fignums() == []


def test_a_panel_shows_the_ground_truth_beside_the_render_and_its_error_only_when_there_is_one(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    titles: list[str] = []
    monkeypatch.setattr(figures, "_image_axes", lambda ax, title: titles.append(title))
    rgb, gt = np.full((8, 12, 3), 0.25), np.full((8, 12, 3), 0.75)
    uncertainty, error = np.linspace(0.0, 1.0, 96).reshape(8, 12), np.abs(rgb - gt).sum(-1)
    u_scale, e_scale = ColourScale(0.0, 1.0, "viridis", "U"), ColourScale(0.0, 3.0, "magma", "|error|")
    figures.save_panel(tmp_path / "gt.png", rgb, uncertainty, u_scale, gt, error, e_scale)
    assert titles == ["ground truth", "render", "U", "|error|"]
    titles.clear()
    figures.save_panel(tmp_path / "none.png", rgb, uncertainty, u_scale)
    assert titles == ["render", "U"]
    with_gt, without = mpimg.imread(tmp_path / "gt.png"), mpimg.imread(tmp_path / "none.png")
    assert with_gt.shape[1] > 1.8 * without.shape[1]  # four columns against two
