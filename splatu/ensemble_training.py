"""Ensembles: N plain 3DGS members that differ only in seed, trained one after another into one run folder.

The paper's baseline (REFERENCE §5): their per-pixel spread is the uncertainty that splatu's single model is
compared with, so its cost (every member's wall time, over every session) is recorded honestly.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from splatu.atomic import atomic_write_text
from splatu.baselines.ensemble import ENSEMBLE_FILE
from splatu.checkpoint import RESUME_KEYS, list_checkpoints, read_checkpoint
from splatu.data.scene import Scene
from splatu.ensemble_dirs import enclosing_ensemble, ensemble_members
from splatu.errors import SplatuError
from splatu.interrupts import TrainingInterrupted, signal_of
from splatu.json_files import is_finite_number, read_json
from splatu.run_dir import Began, training_lock
from splatu.train_config import TrainConfig, from_dict, load_config, save_config, with_display
from splatu.train_progress import console
from splatu.trainer import train_locked_run
from splatu.training_step import StepHook

ENSEMBLE_SESSIONS = "ensemble_sessions.json"


def train_member(member: TrainConfig, scene: Scene, member_dir: Path, hooks: Sequence[StepHook],
                 began: Callable[[], None] | None) -> None:
    """Skip a finished member (summary.json written last), continue one from its newest checkpoint (with its saved
    options, but for what `member` shows), or start it; the caller holds the member's `training_lock`, under which
    this choice is made. `began` as in `train_locked_run`."""
    if (member_dir / "summary.json").is_file():
        console.print(f"already trained: {member_dir}", soft_wrap=True)
        return
    found = list_checkpoints(member_dir)
    if not found:
        train_locked_run(member, scene, member_dir, hooks, began=began)
        return
    checkpoint = read_checkpoint(found[-1], RESUME_KEYS)
    saved = with_display(from_dict(checkpoint["config"], str(found[-1])), member)
    train_locked_run(saved, scene, member_dir, hooks, checkpoint, began=began)


def recorded_sessions(run_dir: Path) -> list[float]:
    """The wall times of an ensemble run's earlier sessions (ensemble_sessions.json), read before any training so
    that a damaged file is a one-line error then, not one that hides how the session ended."""
    path = run_dir / ENSEMBLE_SESSIONS
    if not path.is_file():
        return []
    sessions = read_json(path).get("session_seconds")
    if not isinstance(sessions, list) or not all(map(is_finite_number, sessions)):
        raise SplatuError("session_seconds is not a list of numbers", f"in {path}",
                          "fix the file, or delete it (the ensemble's wall time then counts from this session)")
    return [float(s) for s in sessions]


def train_ensemble(config: TrainConfig, scene: Scene, run_dir: Path, wall_start: float,
                   hooks: Sequence[StepHook] = ()) -> dict[str, Any]:
    """Train an ensemble into `run_dir` (`train_locked_ensemble`) holding the folder's `training_lock`, as `splatu
    train` does: a second session on it, which would write config.yml, ensemble_sessions.json and ensemble.json from
    what it read at its start, is refused. A caller that holds the lock already calls `train_locked_ensemble`."""
    with training_lock(run_dir):
        return train_locked_ensemble(config, scene, run_dir, wall_start, hooks)


def train_locked_ensemble(config: TrainConfig, scene: Scene, run_dir: Path, wall_start: float,
                          hooks: Sequence[StepHook], began: Began | None = None) -> dict[str, Any]:
    """N members differing only in seed (seed + k), then ensemble.json with their dirs and wall time; the caller
    holds `run_dir`'s `training_lock`.

    Calling it again on the same `run_dir` resumes: finished members are skipped, an interrupted one
    continues from its newest checkpoint, one never started starts fresh. `wall_seconds` is honest
    across sessions: every call (session) that trains a member adds its own wall time, from `wall_start`
    (the start of `train`, so scene loading counts) until it finishes, is interrupted or fails, to
    ensemble_sessions.json, and `wall_seconds` is their sum; so does a `--resume` of a member's own folder
    (`counted_in_ensemble`). A session that trains none did no work and adds nothing: every member finished
    already, or it was refused before a member's training began (`train_locked_run`'s `began`: a member's
    lock held by another `splatu train`, a checkpoint that does not fit the scene). A session killed
    outright (SIGKILL, power loss) cannot record itself and is missing from the sum. `began`: the caller's, to
    learn the same (`latest_new_run`).
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    save_config(config, run_dir / "config.yml")
    members = ensemble_members(run_dir, config)
    sessions = recorded_sessions(run_dir)
    began = Began() if began is None else began
    try:
        for k, member_dir in enumerate(members):
            member = dataclasses.replace(config, seed=config.seed + k, ensemble=1)
            console.print(f"ensemble member {k + 1}/{config.ensemble} (seed {member.seed})")
            try:
                with training_lock(member_dir):  # also against a `--resume` of the member folder itself
                    train_member(member, scene, member_dir, hooks, began)
            except TrainingInterrupted as stop:  # point the resume hint at the ensemble, not the member
                raise TrainingInterrupted(f"ensemble member {k + 1}/{config.ensemble}: {stop.what}",
                                          run_dir, stop.step, stop.signal_number) from None
            except KeyboardInterrupt as stop:  # between members: a resume finishes every unfinished one
                raise TrainingInterrupted(f"interrupted at ensemble member {k + 1}/{config.ensemble}", run_dir, 0,
                                          signal_of(stop)) from None
    finally:
        if began.trained:
            sessions.append(time.perf_counter() - wall_start)
            _write_sessions(run_dir, sessions)
    return _write_record(run_dir, config, sessions)


def _write_sessions(run_dir: Path, sessions: list[float]) -> None:
    atomic_write_text(run_dir / ENSEMBLE_SESSIONS, json.dumps({"session_seconds": sessions}, indent=2))


def _write_record(run_dir: Path, config: TrainConfig, sessions: list[float]) -> dict[str, Any]:
    """ensemble.json: what renders and scores the ensemble reads, its wall time included."""
    record = {"members": [str(m.relative_to(run_dir)) for m in ensemble_members(run_dir, config)],
              "seeds": [config.seed + k for k in range(config.ensemble)],
              "wall_seconds": sum(sessions), "session_seconds": sessions}
    atomic_write_text(run_dir / ENSEMBLE_FILE, json.dumps(record, indent=2))
    return record


@contextmanager
def enclosing_ensemble_lock(run_dir: Path) -> Iterator[Path | None]:
    """Hold the `training_lock` of the ensemble that `run_dir` is a member of, if any, and yield that ensemble: a
    `--resume` of the member trains the ensemble too (`counted_in_ensemble` records it there), so it must not run
    beside a session of the whole ensemble, which writes the same records."""
    ensemble = enclosing_ensemble(run_dir)
    if ensemble is None:
        yield None
        return
    with training_lock(ensemble):
        yield ensemble


@contextmanager
def counted_in_ensemble(ensemble: Path | None, wall_start: float) -> Iterator[Callable[[], None]]:
    """Add the wall time of a `--resume` of a member folder, from `wall_start` until it ends however it ends, to its
    `ensemble`'s sessions (a no-op for None), and rewrite ensemble.json's wall_seconds when the ensemble has one
    (else the `--resume` of the ensemble that writes it sums them): the member's training is the ensemble's cost,
    which render and eval-ause timings report. Only a session that trained counts: it yields the `began` to pass to
    `train_locked_run`, and a resume refused before that (its checkpoint does not fit the scene) adds nothing, as
    none of an ensemble's own sessions does. The caller holds the ensemble's lock (`enclosing_ensemble_lock`)."""
    began = Began()
    if ensemble is None:
        yield began
        return
    config, sessions = load_config(ensemble / "config.yml"), recorded_sessions(ensemble)  # damaged: refused now
    try:
        yield began
    finally:
        if began.trained:
            sessions.append(time.perf_counter() - wall_start)
            _write_sessions(ensemble, sessions)
            if (ensemble / ENSEMBLE_FILE).is_file():
                _write_record(ensemble, config, sessions)
