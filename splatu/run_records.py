"""A run's records on disk besides checkpoints: its metrics log, and setting aside what a resume from an
older checkpoint abandons."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from splatu.atomic import atomic_write_text
from splatu.checkpoint import (
    checkpoint_step,
    list_checkpoints,
)
from splatu.errors import SplatuError
from splatu.run_dir import new_timestamped_dir


class MetricsLog:
    """metrics.jsonl: one JSON object per line, appended and flushed as training goes."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def write(self, record: dict[str, Any]) -> None:
        with self.path.open("a") as f:
            f.write(json.dumps(record) + "\n")

    def drop_after(self, step: int) -> list[str]:
        """On resume: forget the lines logged after the checkpoint (they are about to be redone) and a line
        torn by a killed process; return the dropped whole lines. Rewritten atomically: a crash here keeps
        the old log."""
        if not self.path.is_file():
            return []
        kept, dropped = [], []
        for line in self.path.read_text(encoding="utf-8").splitlines():
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue  # empty, or half a line: the process died while appending it
            (kept if record.get("step", 0) <= step else dropped).append(line)
        atomic_write_text(self.path, "".join(ln + "\n" for ln in kept))
        return dropped


ABANDONED_DIR = "abandoned"


def set_aside_later_work(run_dir: Path, step: int) -> Path | None:
    """Resuming from a checkpoint older than the run's newest abandons what came after it. Move the later
    checkpoints, their metrics lines, a finished run's summary.json and splat.ply, and the renders and AUSE
    reports made of it into abandoned/<time>/: nothing trained is lost, and `--resume RUN`,
    `render-uncertainty` and `eval-ause`, which take the newest checkpoint, never pick up the abandoned
    branch. Returns that folder, or None."""
    later = [path for path in list_checkpoints(run_dir) if checkpoint_step(path) > step]
    if not later:
        return None
    folder = new_timestamped_dir(run_dir / ABANDONED_DIR)  # never merged with an earlier set-aside
    dropped = MetricsLog(run_dir / "metrics.jsonl").drop_after(step)
    atomic_write_text(folder / "metrics.jsonl", "".join(ln + "\n" for ln in dropped))
    reports = [*run_dir.glob("ause_*"), run_dir / "uncertainty"]  # renders and scores of the abandoned model
    for path in [*later, run_dir / "summary.json", run_dir / "splat.ply", *reports]:
        if path.exists():
            path.replace(folder / path.name)
    return folder


def refuse_set_aside_checkpoint(checkpoint: Path) -> None:
    """A checkpoint in abandoned/ has no run folder of its own: resuming it would train inside abandoned/."""
    if checkpoint.resolve().parent.parent.name == ABANDONED_DIR:
        raise SplatuError("this checkpoint was set aside by an earlier resume (it is in abandoned/)",
                          f"at {checkpoint}", "copy it into a new folder and resume from there, or resume the run")
