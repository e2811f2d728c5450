"""The study's bookkeeping (benchmarks/uncertainty_study.py): budgets' files, kept scenes, speed points.

No training here: small made-up rows stand in for a study's scored methods.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from splatu.errors import SplatuError
from tests.benchmark_scripts import benchmark_script


@pytest.fixture(scope="module")
def study():
    yield from benchmark_script("uncertainty_study")


def row(ause: float, random: float, train_seconds: float, psnr: float = 23.0, method: str = "ours") -> dict:
    mean = {"ause_mae": ause, "random_ause_mae": random, "ause_rmse": ause, "oracle_ausc_mae": 0.03,
            "ause_mae_start_norm": ause, "random_ause_mae_start_norm": random, "auroc_unobserved": 0.9}
    return {"mean": mean, "psnr": psnr, "train_seconds": train_seconds, "render_seconds_per_view": 0.05,
            "method": method}


def scene(date: str) -> dict:
    rows = {"ours-antipodal": row(0.45, 0.69, 220.0), "ablation-u-degree-0": row(0.43, 0.69, 291.0),
            "ensemble-4": row(0.20, 0.70, 880.0, 23.7, "ensemble"), "random": row(0.69, 0.69, 220.0, method="random")}
    return {"rows": rows, "kernel_warm_up_seconds": None, "trained_before": ["ensemble-4"],
            "measured": {"date": date, "cpu": "test CPU", "command": "python benchmarks/uncertainty_study.py"},
            "views": {"train": 10, "eval": 3}, "size": [48, 80]}


def test_speed_points_are_ratios_to_random_and_leave_out_ablations(study) -> None:
    points = study.speed_points(scene("2026-01-01")["rows"])
    assert set(points) == {"ours-antipodal", "ensemble-4", "random"}
    assert points["ours-antipodal"].ause_ratio == pytest.approx(0.45 / 0.69)
    assert points["random"].psnr is None and points["ensemble-4"].psnr == 23.7  # baselines share ours' PSNR


def test_results_are_written_per_budget_and_kept_scenes_survive(study, tmp_path: Path) -> None:
    args = study.Args(results=tmp_path, ensemble_size=10)  # the kept scene's own ensemble row is still found
    fast = {"budget": study.dataclasses.asdict(study.FAST), "caption": "c", "scenes": {"fox": scene("2026-01-01")}}
    study.write_results(fast, args, study.FAST)
    quick = {"budget": study.dataclasses.asdict(study.QUICK), "caption": "c", "scenes": {"poster": scene("2026-01-02")}}
    study.write_results(quick, args, study.QUICK)

    assert (tmp_path / "uncertainty_study.json").is_file() and (tmp_path / "uncertainty_study_quick.json").is_file()
    assert (tmp_path / "uncertainty_study_fox_speed.png").is_file()  # drawn with the one budget that has fox
    assert (tmp_path / "uncertainty_study_poster_speed.png").is_file()
    table = (tmp_path / "uncertainty_study.md").read_text()
    assert "Measured 2026-01-01 on test CPU" in table and "reused from an earlier invocation" in table
    assert "fox: best ours (ablation-u-degree-0) AUSE-MAE ÷ ensemble-4" in table

    kept = study.earlier_scenes(tmp_path / "uncertainty_study.json", study.FAST)
    assert kept["fox"]["measured"]["date"] == "2026-01-01"
    with pytest.raises(SplatuError, match="other quality settings"):
        study.earlier_scenes(tmp_path / "uncertainty_study.json", study.QUALITY)
    assert json.loads((tmp_path / "uncertainty_study_quick.json").read_text())["budget"]["name"] == "quick"


def test_repeat_timings_train_only_the_missing_ones_and_the_table_names_them(study, tmp_path: Path,
                                                                              monkeypatch) -> None:
    trained: list[Path] = []
    monkeypatch.setattr(study.trainer, "train_run", lambda config, scene, run_dir: trained.append(run_dir))
    variant = study.Variant("ours-antipodal", lambda c: c)
    run_dir = tmp_path / "ours-antipodal"
    run_dir.mkdir()
    first = study.repeat_timings(variant, None, None, run_dir, 2)
    assert len(first) == 2 and len(trained) == 2 and all(not p.is_relative_to(run_dir) for p in trained)
    again = study.repeat_timings(variant, None, None, run_dir, 3)  # a rerun asking for more reuses the two
    assert again[:2] == first and len(trained) == 3
    assert study.repeat_timings(variant, None, None, run_dir, 1) == first[:1] and len(trained) == 3

    timed = {**scene("2026-01-03"), "timings": {"ours-antipodal": [563.0, 481.0, 490.0]}}
    results = {"budget": study.dataclasses.asdict(study.QUALITY), "caption": "c", "scenes": {"poster": timed}}
    assert "median of 3 trainings of it (563, 481, 490 s" in study.markdown(results, study.QUALITY)


def test_ours_timings_below_one_is_one_clear_error(study) -> None:
    with pytest.raises(SplatuError, match="--ours-timings is 0"):
        study.main(study.Args(ours_timings=0))
