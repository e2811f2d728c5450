"""A run's records on disk besides checkpoints: its metrics log, and setting aside what a resume from an
older checkpoint abandons."""

from __future__ import annotations

import contextlib
import json
import re
from pathlib import Path
from typing import Any

from splatu.atomic import atomic_write_text, leftover_temporaries, sync_appended
from splatu.checkpoint import (
    CHECKPOINT_DIR,
    checkpoint_step,
    list_checkpoints,
)
from splatu.errors import unwritable
from splatu.json_files import is_finite_number
from splatu.run_dir import new_timestamped_dir

REDONE_AT_RESUME = ("eval", "degree_choice")
"""Records of a step that a resume from that step's checkpoint redoes: its evaluation (which a stop may have
skipped or cut short, and which the final one repeats) and the degree choice, made after the checkpoint of
its step. Redone rather than trusted, a resumed run's log reads as an uninterrupted run's."""
DEGREE_CHOICE_FILE = "degree_choice.json"


class MetricsLog:
    """metrics.jsonl: one JSON object per line, appended and flushed as training goes, and fsynced by `sync`."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def write(self, record: dict[str, Any]) -> None:
        try:
            with self.path.open("a") as f:
                f.write(json.dumps(record) + "\n")
        except OSError as err:
            raise unwritable(self.path, err) from None

    def sync(self) -> None:
        """Make the lines written so far survive a machine crash; called before each checkpoint, not per line,
        as an fsync costs milliseconds."""
        try:
            sync_appended(self.path)
        except FileNotFoundError:
            return  # nothing logged yet
        except OSError as err:
            raise unwritable(self.path, err) from None

    def drop_after(self, step: int) -> list[str]:
        """On resume: forget the lines logged after the checkpoint of `step` (they are about to be redone), the
        lines of that step that its checkpoint does not hold (`REDONE_AT_RESUME`), and a line torn by a killed
        process; return the dropped whole lines. Rewritten atomically: a crash here keeps the old log."""
        if not self.path.is_file():
            return []
        kept, dropped = [], []
        for line in self.path.read_text(encoding="utf-8").splitlines():
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue  # empty, or half a line: the process died while appending it
            logged_at = record.get("step", 0) if isinstance(record, dict) else None
            if not is_finite_number(logged_at):
                continue  # not a record this log writes (a hand edit): nothing a resume could place
            later = logged_at > step or (logged_at == step and record.get("event") in REDONE_AT_RESUME)
            (dropped if later else kept).append(line)
        atomic_write_text(self.path, "".join(ln + "\n" for ln in kept))
        return dropped


ABANDONED_DIR = "abandoned"
SUPERSEDED_DIR = "superseded"
CHECKPOINT_IN_LABEL = re.compile(r"-step-(\d+)")
"""How an output label names the checkpoint file it was made of (`UncertaintyOptions.label`)."""
STEPS_IN_LABEL = re.compile(r"-steps-(\d+(?:-\d+)*)")
"""How an ensemble's output label names the steps of its members' checkpoints, in member order (the same)."""


def set_aside_later_work(run_dir: Path, step: int) -> Path | None:
    """Resuming from a checkpoint older than the run's newest abandons what came after it. Move the later
    checkpoints, their metrics lines, a finished run's summary.json and splat.ply, the renders and AUSE
    reports made of it, and a degree choice made at or after `step` (the resume makes it again) into
    abandoned/<time>/: nothing trained is lost, and `--resume RUN`,
    `render-uncertainty` and `eval-ause`, which take the newest checkpoint, never pick up the abandoned
    branch. Returns that folder, or None."""
    later = [path for path in list_checkpoints(run_dir) if checkpoint_step(path) > step]
    choice = run_dir / DEGREE_CHOICE_FILE
    stale_choice = choice.is_file() and _choice_step(choice) >= step  # made at or after `step`: made again
    if not later and not stale_choice:
        return None
    folder = new_timestamped_dir(run_dir / ABANDONED_DIR)  # never merged with an earlier set-aside
    dropped = MetricsLog(run_dir / "metrics.jsonl").drop_after(step)
    atomic_write_text(folder / "metrics.jsonl", "".join(ln + "\n" for ln in dropped))
    moved = [choice] if stale_choice else []
    if later:  # with the model they came from: its summary, export, renders and scores
        moved += [*later, *_outputs_made_after(run_dir, step)]
    _move_into(folder, run_dir, moved)
    return folder


def set_aside_final_outputs(run_dir: Path, step: int) -> Path | None:
    """Training a run on from step `step` supersedes what was taken for its final model: after its end (`--extend-to`),
    the summary.json and splat.ply of step `step` and the renders, AUSE reports and exports made of it (those naming
    no checkpoint); before it (a resume of a stopped run), any render or report naming no checkpoint, which was made of
    that unfinished model as if it were the finished one. They move into superseded/<time>/, so that none is taken
    for the longer run's; the checkpoint stays until newer ones prune it. Returns that folder, or None when there was
    nothing to move."""
    outputs = [path for path in _outputs_made_after(run_dir, step) if path.exists()]
    if not outputs:
        return None
    folder = new_timestamped_dir(run_dir / SUPERSEDED_DIR)
    _move_into(folder, run_dir, outputs)
    return folder


def set_aside_ensemble_outputs(member_dir: Path, step: int) -> Path | None:
    """A member of a finished ensemble (it has ensemble.json) resumed from a checkpoint older than its newest abandons
    the model that the ensemble's renders and AUSE reports were made of: move those into the ensemble's
    superseded/<time>/, laid out as a single run's, so that none is taken for the ensemble's once the member is
    retrained. Those made while the member was at `step` or before, which name it among their members' steps
    (`ensemble-steps-80-7-eval`), stay. Called before the member's own set-aside, so a kill between the two leaves the
    later checkpoints that make a second resume do it again. Returns that folder, or None."""
    ensemble_dir = member_dir.parent.parent
    if member_dir.parent.name != "members" or not (ensemble_dir / "ensemble.json").is_file():
        return None
    if not any(checkpoint_step(path) > step for path in list_checkpoints(member_dir)):
        return None
    reports = (*ensemble_dir.glob("ause_*"), *ensemble_dir.glob("uncertainty/*"))
    stale = [path for path in reports if _member_step(path.name, member_dir.name) > step]
    if not stale:
        return None
    folder = new_timestamped_dir(ensemble_dir / SUPERSEDED_DIR)
    _move_into(folder, ensemble_dir, stale)
    return folder


def _member_step(name: str, member: str) -> int:
    """The step of member `member` (its folder's number) that an ensemble's render or report was made of: one of an
    ensemble not whole names its members' steps in order; one that names none was made of the finished ensemble, so of
    the member's newest model, and counts as made late, as does one whose name cannot say."""
    named = STEPS_IN_LABEL.search(name)
    steps = named.group(1).split("-") if named else []
    return int(steps[int(member)]) if member.isdigit() and int(member) < len(steps) else 1 << 62


def _outputs_made_after(run_dir: Path, step: int) -> list[Path]:
    """The run's summary and export, and the renders, reports and exports made of a model after `step`."""
    reports = (*run_dir.glob("ause_*"), *run_dir.glob("uncertainty/*"), *run_dir.glob("exports/*"))
    return [run_dir / "summary.json", run_dir / "splat.ply", *(p for p in reports if _made_after(p.name, step))]


def _move_into(folder: Path, run_dir: Path, paths: list[Path]) -> None:
    """Move `paths` into `folder`: renders and exports keep their folder; the rest go straight in, checkpoints too,
    which then lie inside no run (`run_holding`), so that a resume of one trains on in a new run. A renders' or
    exports' folder left empty goes: an empty `uncertainty/` read as renders made and lost."""
    emptied = set()
    for path in paths:
        if path.exists():
            kept_folder = path.parent in (run_dir / "uncertainty", run_dir / "exports")
            target = folder / path.parent.name if kept_folder else folder
            target.mkdir(exist_ok=True)
            path.replace(target / path.name)
            if kept_folder:
                emptied.add(path.parent)
    for left in emptied:
        with contextlib.suppress(OSError):  # not empty: it holds what was kept, made of an earlier checkpoint
            left.rmdir()


def _made_after(name: str, step: int) -> bool:
    """Whether a render, AUSE report or export was made of a model after `step`: one made of a checkpoint file names it
    (`ause_ours-step-0000020.json`, `uncertainty/ours-step-0000020-eval`, `exports/splat-step-0000020.ply`), and one
    that names none was made of the run's newest model, which the resume abandons."""
    named = CHECKPOINT_IN_LABEL.search(name)
    return named is None or int(named.group(1)) > step


def remove_torn_checkpoints(run_dir: Path) -> None:
    """On resume: delete the temporary files of checkpoint writes that a killed process left (each the size of a
    checkpoint); a write that completes renames its own away. The run's lock keeps any other writer out."""
    for path in leftover_temporaries(run_dir / CHECKPOINT_DIR, "step-*.pt"):
        path.unlink(missing_ok=True)


def _choice_step(path: Path) -> int:
    """The step a degree choice was made after; a damaged record counts as made late, so it is set aside."""
    try:
        return int(json.loads(path.read_text(encoding="utf-8"))["step"])
    except (OSError, ValueError, KeyError, TypeError):
        return 1 << 62
