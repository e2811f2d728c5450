"""The speed-against-error figure: budgets as markers, methods as colours, partial data tolerated."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg

from splatu.figures import SpeedPoint, method_lines, plot_speed_against_error

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
