"""The eval-ause score table, as it lands in a log file or a CI job's output (no terminal)."""

from __future__ import annotations

import re

import pytest

from splatu.eval_ause import print_report

SCORES = ("ause", "random_ause", "ause_start_norm", "random_ause_start_norm", "ausc", "random_ausc", "oracle_ausc")


def _key(score: str, metric: str) -> str:
    return score.replace("ause", f"ause_{metric}") if "ause" in score else f"{score}_{metric}"


def _report(names: list[str]) -> dict:
    """Scores that differ per image, metric and column, so a number shown in the wrong place is caught."""
    per_image = {name: {**{_key(score, metric): 0.1 + 0.01 * i + 0.001 * j + 0.0001 * m
                           for j, score in enumerate(SCORES) for m, metric in enumerate(("mae", "rmse"))},
                        "auroc_unobserved": 0.9 - 0.001 * i}
                 for i, name in enumerate(names)}
    per_image[names[0]]["auroc_unobserved"] = None
    mean = {key: 0.2 + 0.01 * k for k, key in enumerate(per_image[names[1]])}
    return {"method": "ours", "caption": "grid r=k/100", "per_image": per_image, "mean": mean}


def _rows(out: str) -> dict[str, str]:
    return {line.split("│")[1].strip(): line for line in out.splitlines() if line.startswith("│")}


@pytest.fixture(autouse=True)
def _no_terminal(monkeypatch):
    for variable in ("FORCE_COLOR", "TTY_COMPATIBLE", "COLUMNS"):
        monkeypatch.delenv(variable, raising=False)


def test_the_summary_is_the_mean_of_each_error_with_ours_divided_by_random(capsys):
    """The README quotes AUSE as ours ÷ random: the mean table prints that ratio, for MAE and RMSE, and leaves the
    per-image rows (a 33-row table) to --per-image."""
    report = _report([f"images_frame_{i:05d}" for i in range(100, 133)])
    print_report(report, "rmse")
    out = capsys.readouterr().out
    rows, mean = _rows(out), report["mean"]
    assert list(rows) == ["RMSE", "MAE"]  # the chosen metric leads
    for metric in ("mae", "rmse"):
        shown = re.findall(r"\d\.\d{2,4}", rows[metric.upper()])
        ratio = f"{mean[f'ause_{metric}'] / mean[f'random_ause_{metric}']:.2f}"
        expected = [f"{mean[_key(score, metric)]:.4f}" for score in SCORES]
        assert shown == [*expected[:2], ratio, *expected[2:]]
    assert f"AUROC of U for the unobserved pixels: {mean['auroc_unobserved']:.4f}" in out
    assert "images_frame" not in out and "mean over 33 images" in out


def test_per_image_rows_keep_every_name_and_score_whole_when_piped(capsys):
    """rich assumes 80 columns off a terminal, which cut the scores to "0.05…" and folded the image names."""
    names = [f"images_frame_{i:05d}_of_a_long_capture_name" for i in range(100, 133)]
    report = _report(names)
    print_report(report, "mae", per_image=True)
    out = capsys.readouterr().out
    assert "…" not in out
    rows = _rows(out)
    for name, scores in report["per_image"].items():
        shown = re.findall(r"\d\.\d{2,4}|n/a", rows[name].split("│", 2)[2])
        assert shown == [f"{scores['ause_mae']:.4f}", f"{scores['random_ause_mae']:.4f}",
                         f"{scores['ause_mae'] / scores['random_ause_mae']:.2f}",
                         f"{scores['ause_mae_start_norm']:.4f}",
                         "n/a" if scores["auroc_unobserved"] is None else f"{scores['auroc_unobserved']:.4f}"]
    assert {"MAE", "RMSE"} <= set(rows)  # the means follow
