"""The eval-ause score table, as it lands in a log file or a CI job's output (no terminal)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from splatu.eval_ause import print_report, render_psnr, score_entries
from splatu.maps import MapEntry

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


def _entry(name: str, left_error: float, right_error: float, mask=None, unobserved=None) -> MapEntry:
    """A 4×6 view whose render is off by `left_error` on its left half and `right_error` on its right half."""
    gt = np.full((4, 6, 3), 0.5)
    rgb = gt.copy()
    rgb[:, :3] += left_error
    rgb[:, 3:] += right_error
    return MapEntry(name, rgb, gt, np.linspace(0, 1, 24).reshape(4, 6), mask, unobserved)


def _db(mse: float) -> float:
    return -10 * math.log10(mse)


def test_the_render_psnr_is_taken_on_the_scored_and_on_the_observed_pixels():
    """Each method's AUSE ranks its own render's error (an ensemble's mean render is better than one model's), so the
    report gives the PSNR of the render it scored, as the trainer gives psnr and psnr_observed."""
    left_unseen = np.zeros((4, 6), bool)
    left_unseen[:, :3] = True
    scores = render_psnr(_entry("v", 0.1, 0.02, unobserved=left_unseen))
    assert scores["psnr"] == pytest.approx(_db((0.01 + 0.0004) / 2))
    assert scores["psnr_observed"] == pytest.approx(_db(0.0004))
    right_only = ~left_unseen
    masked = render_psnr(_entry("v", 0.1, 0.02, mask=right_only, unobserved=right_only))
    assert masked["psnr"] == pytest.approx(_db(0.0004))
    assert masked["psnr_observed"] is None  # every scored pixel is unobserved
    assert render_psnr(_entry("v", 0.1, 0.02))["psnr_observed"] is None  # no unobserved map: no observed figure
    # a render past white is scored as its stored map holds it, clipped: 0.5 + 0.6 reads 1.0, off by 0.5
    assert render_psnr(_entry("v", 0.6, 0.6))["psnr"] == pytest.approx(_db(0.25))


def test_the_report_gives_the_mean_of_each_image_s_psnr(capsys):
    """The mean of each image's own PSNR, as nerfstudio and 3DGS report it, not the PSNR of the pooled pixels."""
    report, _ = score_entries([_entry("a", 0.1, 0.1), _entry("b", 0.01, 0.01)], "mae")
    assert report["per_image"]["a"]["psnr"] == pytest.approx(20.0)
    assert report["mean"]["psnr"] == pytest.approx(30.0)  # pooled: 10·log10(2 / 0.0101) = 22.97
    assert report["mean"]["psnr_observed"] is None
    report |= {"method": "ours"}
    print_report(report, "mae")
    out = capsys.readouterr().out
    assert "PSNR of the render scored: 30.00 dB on the scored pixels (the mean of each image's own)" in out
    report["mean"]["psnr"] = None  # a report written before PSNR was scored prints none
    print_report(report, "mae")
    assert "PSNR" not in capsys.readouterr().out
