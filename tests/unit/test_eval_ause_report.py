"""The eval-ause score table, as it lands in a log file or a CI job's output (no terminal)."""

from __future__ import annotations

import re

from splatu.eval_ause import print_report

COLUMNS = ("ause_mae", "random_ause_mae", "ause_mae_start_norm", "random_ause_mae_start_norm", "ausc_mae",
           "random_ausc_mae", "oracle_ausc_mae", "auroc_unobserved")


def test_a_piped_table_keeps_every_name_and_score_whole(capsys, monkeypatch):
    """rich assumes 80 columns off a terminal, which cut the scores to "0.05…" and folded the image names."""
    for variable in ("FORCE_COLOR", "TTY_COMPATIBLE", "COLUMNS"):
        monkeypatch.delenv(variable, raising=False)
    names = [f"images_frame_{i:05d}" for i in range(100, 133)]
    per_image = {name: {c: 0.1 + 0.001 * i + 0.0001 * j for j, c in enumerate(COLUMNS)} for i, name in enumerate(names)}
    per_image[names[0]]["auroc_unobserved"] = None
    report = {"method": "ours", "caption": "grid r=k/100", "per_image": per_image,
              "mean": {c: 0.2345 for c in COLUMNS}}
    print_report(report, "mae")
    out = capsys.readouterr().out
    assert "…" not in out
    rows = {line.split("│")[1].strip(): line for line in out.splitlines() if line.startswith("│")}
    for name, scores in per_image.items():
        shown = re.findall(r"\d\.\d{4}|n/a", rows[name])
        assert shown == ["n/a" if v is None else f"{v:.4f}" for v in (scores[c] for c in COLUMNS)]
