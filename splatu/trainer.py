"""The training loop: splatfacto-style 3DGS with the uncertainty SH learned in the same step.

It drives `train_step` (splatu.training_step) from a fresh or restored state to the last step, with periodic
evaluation, checkpoints, the mid-run choice of SH degrees, and a clean stop on Ctrl-C or SIGTERM, then
finishes the run (final checkpoint, evaluation, PLY, summary.json).

`train_run(config, scene, run_dir)` trains one run on a loaded scene, fresh or from a checkpoint, holding the run
folder's lock as `splatu train` does; the `splatu train` command around it (options, the scene, the run folder,
--resume) is splatu.train_command, and ensembles are splatu.ensemble_training.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import random
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from splatu.allocator import keep_freed_memory
from splatu.atomic import atomic_write_text
from splatu.checkpoint import (
    capture_rng,
    checkpoint_path,
    checkpoint_step,
    list_checkpoints,
    model_from_state,
    restore_rng,
    save_checkpoint,
    saved_frame,
)
from splatu.config_values import to_dict
from splatu.data.scene import Scene
from splatu.degree_choice import (
    apply_choice,
    decision_step,
    score_degrees,
    split_for_choice,
    training_views,
    with_choice_heads,
)
from splatu.densify import DensityController
from splatu.ensemble_dirs import enclosing_ensemble
from splatu.errors import SplatuError
from splatu.evaluation import evaluate_scene
from splatu.interrupts import (
    TrainingInterrupted,
    deferred_interrupt,
    signal_of,
    stop_at_once,
)
from splatu.json_files import read_json
from splatu.losses import uncertainty_heads
from splatu.model import GaussianModel
from splatu.optim import Optimizers
from splatu.ply import save_ply
from splatu.rasterizer.kernels import compile_pending, compile_seconds, set_compile
from splatu.run_dir import training_lock
from splatu.run_records import (
    DEGREE_CHOICE_FILE,
    MetricsLog,
    remove_torn_checkpoints,
    set_aside_ensemble_outputs,
    set_aside_final_outputs,
    set_aside_later_work,
)
from splatu.train_config import (
    TrainConfig,
    eval_background,
    save_config,
)
from splatu.train_progress import (
    COMPILE_LINE,
    PLAIN_PROGRESS_LINES,
    StepRate,
    console,
    eval_line,
    on_terminal,
    progress_bar,
    progress_line,
    stopping_line,
)
from splatu.training_step import (
    NonFiniteUpdate,
    StepHook,
    StepOutcome,
    TrainImages,
    TrainState,
    resolution_level,
    scene_extent,
    train_step,
    trained_sh_degree,
)
from splatu.world_frame import WorldTransform, require_same_frame, scene_frame

UNCERTAINTY_SEED_OFFSET = 7_919
"""Offsets the uncertainty loss's seed from the geometry's, so the two streams differ."""


def _checkpoint_state(state: TrainState, config: TrainConfig) -> dict[str, Any]:
    return {
        "config": to_dict(dataclasses.replace(config, resume=None)),
        "model": state.model.state_dict(),
        "num_gaussians": len(state.model),
        "optimizers": state.optimizers.state_dict(),
        "density": state.density.state_dict(),
        "rng": capture_rng(state.generator),
        "uncertainty_rng": [g.get_state() for g in state.uncertainty_generators],
        "scene_extent": state.scene_extent,
        "world_transform": state.to_world.state_dict(),
        "nonfinite_streak": state.nonfinite_streak,
        "train_seconds": state.train_seconds,
        "train_compile_seconds": state.train_compile_seconds,
        "wall_seconds": time.perf_counter() - state.wall_start,
    }


def seed_everything(seed: int) -> torch.Generator:
    """Seed torch, numpy and random; return the trainer's own generator."""
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    random.seed(seed)
    return torch.Generator().manual_seed(seed)


def fresh_state(config: TrainConfig, scene: Scene) -> TrainState:
    """The state a new training starts from. It checks what a new run may not use and a saved one may (the
    uncertainty threshold 0; the model's initial values, in `from_points`): every new training begins here, from
    Python (`train_run`) too, and an ensemble's members not yet started."""
    config.uncertainty.validate()
    generator = seed_everything(config.seed)
    extent = scene_extent(scene.train.cameras)
    heads = uncertainty_heads(config.uncertainty, config.model.u_sh_degree)  # validates each head's degree
    model = GaussianModel.from_points(scene.points, scene.point_colors, config.model, generator, len(heads))
    optimizers = Optimizers(model, config.optim, extent, config.steps)
    density = DensityController(config.densify, extent, generator)
    return TrainState(model, optimizers, density, generator, uncertainty_generators(config.seed, len(heads)),
                      extent, scene_frame(scene))


def uncertainty_generators(seed: int, heads: int) -> list[torch.Generator]:
    """One identically seeded stream per uncertainty head: a head draws exactly what a run of its own would."""
    return [torch.Generator().manual_seed(seed + UNCERTAINTY_SEED_OFFSET) for _ in range(heads)]


def fitting_frame(checkpoint: dict[str, Any], config: TrainConfig, scene: Scene) -> WorldTransform:
    """The scene's frame, refused unless the checkpoint's model was trained in it (a scene whose normalisation
    moved: its cameras would not fit the model)."""
    to_world = scene_frame(scene)
    require_same_frame(saved_frame(checkpoint), to_world, f"in {config.data.data}",
                       "resume with the scene as it was, or start a new run")
    return to_world


def restored_state(checkpoint: dict[str, Any], config: TrainConfig, scene: Scene) -> TrainState:
    """The checkpointed state, in a scene that fits it (`fitting_frame`)."""
    to_world = fitting_frame(checkpoint, config, scene)
    model = model_from_state(checkpoint, config)
    extent = float(checkpoint["scene_extent"])
    optimizers = Optimizers(model, config.optim, extent, config.steps)
    optimizers.load_state_dict(checkpoint["optimizers"])
    generator = torch.Generator()
    restore_rng(checkpoint["rng"], generator)
    density = DensityController(config.densify, extent, generator)
    density.load_state_dict(checkpoint["density"])
    u_generators = uncertainty_generators(config.seed, model.u_sh.shape[-1])
    for u_generator, saved_state in zip(u_generators, checkpoint.get("uncertainty_rng", []), strict=False):
        u_generator.set_state(saved_state)  # absent in checkpoints written before L_u had its own streams
    return TrainState(model, optimizers, density, generator, u_generators, extent, to_world,
                      step=int(checkpoint["step"]),
                      nonfinite_streak=int(checkpoint["nonfinite_streak"]),
                      train_seconds=float(checkpoint["train_seconds"]),
                      train_compile_seconds=_saved_compile_seconds(checkpoint))


def _saved_compile_seconds(checkpoint: dict[str, Any]) -> float | None:
    """The checkpoint's compile time; None when it has none (written before it was recorded apart)."""
    saved = checkpoint.get("train_compile_seconds")
    return None if saved is None else float(saved)


# --- the loop --------------------------------------------------------------------------------

def run_loop(state: TrainState, config: TrainConfig, scene: Scene, run_dir: Path,
             hooks: Sequence[StepHook]) -> tuple[TrainState, TrainConfig]:
    """Train from `state.step` to `config.steps`, with checkpoints, evaluation and Ctrl-C / SIGTERM handling.

    Returns the config too: choosing the SH degrees mid-run (`--degree-choice.on`) changes it.
    """
    images = TrainImages(training_views(scene.train, config, state.step))
    log = MetricsLog(run_dir / "metrics.jsonl")
    log.drop_after(state.step)
    terminal = on_terminal()
    plain_every = math.ceil(config.steps / PLAIN_PROGRESS_LINES) if config.progress and not terminal else 0
    compiling = compile_pending() and state.step < config.steps  # the first step compiles: say so, or all looks stuck
    if plain_every and compiling:
        console.print(COMPILE_LINE, highlight=False, soft_wrap=True)
    if _eval_due(state.step, config):  # a resume redoes its step's evaluation, which a stop may have skipped
        _log_eval(state, config, scene, log)
    smoothed_psnr = float("nan")
    session_start = time.perf_counter()  # the plain lines' elapsed time, as the bar's: the session's
    step_rate = StepRate(session_start, state.step, config.steps,
                         functools.partial(resolution_level, levels=config.resolution_levels,
                                           interval=config.resolution_interval))
    resumed_from = checkpoint_path(run_dir, state.step)  # where a resume's own checkpoint is, unless copied elsewhere
    saved_step = state.step if state.step > 0 and resumed_from.is_file() else None
    first_step = state.step + 1  # the session's: it compiles the kernels when `compiling`
    in_step = False

    def stop_line(signum: int) -> str:
        return stopping_line(state.step + 1 if in_step else None, state.step,
                             compiling and in_step and state.step + 1 == first_step, signum)

    with progress_bar(config.progress and terminal) as progress, deferred_interrupt(stop_line) as interrupt:
        task = progress.add_task("train", total=config.steps, completed=state.step, loss=None, psnr=None,
                                 gaussians=len(state.model), rate=None, left=None, compiling=compiling)
        try:
            while state.step < config.steps:
                in_step = True  # from here until the step is counted, a stop cannot save a consistent state
                if config.degree_choice.on and state.step == decision_step(config.degree_choice, config.steps):
                    config = choose_degrees(state, config, scene, log, run_dir)
                    images = TrainImages(scene.train)
                started, compiled_before = time.perf_counter(), compile_seconds()
                try:
                    outcome = train_step(state, config, images)
                except NonFiniteUpdate as bad:
                    raise SplatuError(f"training stopped: the {bad.by} of step {state.step + 1} made "
                                      f"{bad.parameter} non-finite", f"in {run_dir}",
                                      f"{_last_good(run_dir)}; retrain with lower learning rates") from None
                state.step += 1
                count_training_time(state, time.perf_counter() - started, compiled_since(compiled_before))
                in_step = False
                _account(state, config, outcome, log, run_dir)
                if outcome.skipped is None:
                    smoothed_psnr = (outcome.psnr if math.isnan(smoothed_psnr)
                                     else 0.9 * smoothed_psnr + 0.1 * outcome.psnr)
                rate, left = step_rate.tick(time.perf_counter()), step_rate.seconds_left()
                progress.update(task, completed=state.step, loss=outcome.photometric_loss, psnr=smoothed_psnr,
                                gaussians=len(state.model), rate=rate, left=left)
                if plain_every and (state.step % plain_every == 0 or state.step == config.steps):
                    console.print(progress_line(state.step, config.steps, outcome.photometric_loss, smoothed_psnr,
                                                len(state.model), rate, time.perf_counter() - session_start, left),
                                  highlight=False, soft_wrap=True)
                if _eval_due(state.step, config) and not interrupt.requested:  # a stop must not wait for it
                    with stop_at_once(interrupt):  # nor once it runs: the resume redoes it
                        _log_eval(state, config, scene, log)
                if config.checkpoint_every and state.step % config.checkpoint_every == 0:
                    _save(state, config, run_dir, log)
                    saved_step = state.step
                for hook in hooks:
                    hook(state.step, state)
                if interrupt.requested:
                    raise KeyboardInterrupt
            if saved_step != state.step:  # the final checkpoint, still deferring a stop until it is whole
                _save(state, config, run_dir, log)
                saved_step = state.step
            if interrupt.requested:
                raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise _interrupted(state, config, run_dir, in_step, interrupt.aborted, saved_step == state.step,
                               interrupt.signal_number) from None
    return state, config


def _save(state: TrainState, config: TrainConfig, run_dir: Path, log: MetricsLog) -> None:
    """Write the checkpoint of `state.step`, the log's lines up to it made durable first: after a machine crash a
    resume from that checkpoint still finds every line of the steps it covers."""
    log.sync()
    save_checkpoint(run_dir, state.step, _checkpoint_state(state, config), config.keep_checkpoints)


def choose_degrees(state: TrainState, config: TrainConfig, scene: Scene, log: MetricsLog,
                   run_dir: Path) -> TrainConfig:
    """Score the SH degrees on the held-out block, keep the chosen ones (see splatu.degree_choice), record why.

    It runs before step `decision_step + 1`, so the checkpoint at the decision step is the model before the
    choice, and a run interrupted during it resumes by choosing again. Its time counts as training time (a compile
    in it as compile time).
    """
    started, compiling = time.perf_counter(), compile_seconds()
    fitted_on, held_out = split_for_choice(scene.train, config.degree_choice.held_out)
    scores = score_degrees(state.model, held_out, fitted_on, config, eval_background(config))
    config, state.uncertainty_generators = apply_choice(state.model, state.optimizers,
                                                        state.uncertainty_generators, config, scores)
    choice = scores.record
    seconds = time.perf_counter() - started
    count_training_time(state, seconds, compiled_since(compiling))
    record = {"step": state.step, "event": "degree_choice", **choice, "seconds": seconds}
    log.write(record)
    atomic_write_text(run_dir / DEGREE_CHOICE_FILE, json.dumps(record, indent=2))
    save_config(config, run_dir / "config.yml")
    u_part = f", u-SH degree {choice['u_sh_degree']}" if "u_sh_degree" in choice else ""
    console.print(f"step {state.step}: chose colour SH degree {choice['sh_degree']}{u_part} "
                  f"on {len(choice['held_out_views'])} held-out views (scores in {run_dir / DEGREE_CHOICE_FILE})",
                  soft_wrap=True)
    return config


def compiled_since(before: float | None) -> float | None:
    """Seconds compiled since `compile_seconds()` read `before`; None once the clock has stopped (or had)."""
    now = compile_seconds()
    return None if before is None or now is None else now - before


def count_training_time(state: TrainState, seconds: float, compiling: float | None) -> None:
    """Add `seconds` of training, `compiling` of it spent compiling kernels, to the state's two clocks: the time of
    the steps alone is what a run's cost is compared on, and a session's first step can take a minute to compile.
    A state resumed from a checkpoint without a compile time keeps its measure, compiles included; so does one whose
    compiles could not be timed (`compiling` None), with those already timed put back, as null means that measure."""
    if compiling is None or state.train_compile_seconds is None:
        state.train_seconds += seconds + (state.train_compile_seconds or 0.0)
        state.train_compile_seconds = None
        return
    state.train_compile_seconds += compiling
    state.train_seconds += seconds - compiling


def _account(state: TrainState, config: TrainConfig, outcome: StepOutcome, log: MetricsLog, run_dir: Path) -> None:
    """Log the step; count non-finite steps in a row and stop after too many."""
    if outcome.skipped is not None:
        state.nonfinite_streak += 1
        log.write({"step": state.step, "event": "nonfinite_skipped", "what": outcome.skipped,
                   "num_gaussians": len(state.model), **({"refined": outcome.refined} if outcome.refined else {})})
        print(f"step {state.step}: non-finite {outcome.skipped}, step skipped", file=sys.stderr)
        if state.nonfinite_streak >= config.max_nonfinite_steps:
            raise SplatuError(
                f"training stopped: {state.nonfinite_streak} steps in a row had a non-finite value "
                f"(last: {outcome.skipped} at step {state.step})",
                f"in {run_dir}",
                f"{_last_good(run_dir)}; check the input data or retrain with lower learning rates",
            )
        return
    state.nonfinite_streak = 0
    if outcome.refined or state.step % config.log_every == 0:
        log.write({"step": state.step, "event": "train", "loss": outcome.loss,
                   "uncertainty_loss": outcome.uncertainty_loss, "psnr": outcome.psnr,
                   "num_gaussians": len(state.model), "train_seconds": state.train_seconds,
                   **({"refined": outcome.refined} if outcome.refined else {})})


def _last_good(run_dir: Path) -> str:
    """Where a stopped training can resume from: every checkpoint training writes is finite."""
    found = list_checkpoints(run_dir)
    return f"the last good checkpoint is {found[-1]}" if found else "no checkpoint was written yet"


def _eval_due(step: int, config: TrainConfig) -> bool:
    """A periodic evaluation follows this step (the last step's is the final one, in `finish_run`)."""
    return bool(config.eval_every_steps) and 0 < step < config.steps and step % config.eval_every_steps == 0


def _log_eval(state: TrainState, config: TrainConfig, scene: Scene, log: MetricsLog) -> dict[str, dict[str, float]]:
    """Evaluate and log the model of `state.step`. The kernels it compiles count as the run's compile time, though
    its other time is no training: an evaluation renders with the forward kernels of the steps, and which of the two
    compiles them first is an accident of order (a resume redoes its step's evaluation before any step)."""
    compiling = compile_seconds()
    results = evaluate_scene(state.model, scene, config, trained_sh_degree(state.step, config.model))
    compiled = compiled_since(compiling)
    count_training_time(state, compiled or 0.0, compiled)  # a stopped clock (None) adds none to the steps' time
    for name, metrics in results.items():
        log.write({"step": state.step, "event": "eval", "set": name, **metrics})
        console.print(eval_line(state.step, name, metrics), highlight=False, soft_wrap=True)
    return results


def _interrupted(state: TrainState, config: TrainConfig, run_dir: Path, mid_step: bool, aborted: bool,
                 saved: bool, signal_number: int) -> TrainingInterrupted:
    """Save (unless saved already, and only at a step boundary, where the state is consistent) and say how to
    resume. After a second stop (`aborted`: a step, evaluation or save cut short), or one during this save, nothing
    more is written (a cut save leaves no torn file) and the message names the checkpoint before."""
    if mid_step:
        return _stopped_outside_steps(f"aborted during step {state.step + 1}", run_dir, signal_number)
    if aborted:
        return _stopped_outside_steps(f"aborted after step {state.step}", run_dir, signal_number)
    path = checkpoint_path(run_dir, state.step)
    if not saved:
        try:
            _save(state, config, run_dir, MetricsLog(run_dir / "metrics.jsonl"))
        except KeyboardInterrupt:
            return _stopped_outside_steps(f"aborted while saving step {state.step}", run_dir, signal_number)
    return TrainingInterrupted(f"interrupted at step {state.step}, saved {path}", run_dir, state.step, signal_number)


def _stopped_outside_steps(what: str, run_dir: Path, signal_number: int) -> TrainingInterrupted:
    """A stop where no consistent state could be saved: name what a resume would continue from."""
    found = list_checkpoints(run_dir)
    if found:
        where, resumable = f"the last checkpoint is {found[-1]}", True
    elif restartable(run_dir):
        where, resumable = f"no checkpoint was written, so a resume starts at step 0 from {run_dir}/config.yml", True
    else:
        where, resumable = "no checkpoint was written", False
    return TrainingInterrupted(f"{what}; {where}", run_dir, checkpoint_step(found[-1]) if found else 0,
                               signal_number, resumable=resumable)


def restartable(run_dir: Path) -> bool:
    """Whether `run_dir` is a run stopped before its first checkpoint, which a resume starts at step 0 rather than
    leave it unresumable with `latest` pointing at it: its config.yml, written first, holds all its first state is
    made of (options, seed), so a step-0 checkpoint would add nothing, and none can be written during a stop while
    that state is built or after a second Ctrl-C. Not a finished run whose checkpoints were deleted, nor one whose
    config.yml the degree choice rewrote (it writes degree_choice.json first)."""
    return ((run_dir / "config.yml").is_file() and not list_checkpoints(run_dir)
            and not (run_dir / "summary.json").exists() and not (run_dir / DEGREE_CHOICE_FILE).exists())


def finish_run(state: TrainState, config: TrainConfig, scene: Scene, run_dir: Path) -> dict[str, Any]:
    """Final evaluation, PLY export and summary.json (the final checkpoint is `run_loop`'s)."""
    log = MetricsLog(run_dir / "metrics.jsonl")
    results = _log_eval(state, config, scene, log)
    save_ply(state.model, run_dir / "splat.ply", state.to_world, uncertainty=not config.uncertainty.off)
    summary = {"scene": scene.name, "stand_in": scene.stand_in, "method": config.method, "preset": config.preset,
               "steps": state.step, "num_gaussians": len(state.model),
               # the degree the model is, and the cap its schedule (one more every --model.sh-degree-interval) had
               "sh_degree": trained_sh_degree(state.step, config.model), "sh_degree_max": config.model.sh_degree,
               # no uncertainty SH was trained with the loss off: a degree would describe an untrained initial value
               "u_sh_degree": None if config.uncertainty.off else config.model.u_sh_degree,
               "train_seconds": state.train_seconds, "train_compile_seconds": state.train_compile_seconds,
               "wall_seconds": time.perf_counter() - state.wall_start, "eval": results}
    if (run_dir / DEGREE_CHOICE_FILE).is_file():
        summary["degree_choice"] = read_json(run_dir / DEGREE_CHOICE_FILE)
    log.sync()  # as before a checkpoint: a resume of a finished run changes nothing, so lost lines would stay lost
    atomic_write_text(run_dir / "summary.json", json.dumps(summary, indent=2))
    return summary


def train_run(config: TrainConfig, scene: Scene, run_dir: Path, hooks: Sequence[StepHook] = (),
              checkpoint: dict[str, Any] | None = None, wall_start: float | None = None) -> dict[str, Any]:
    """Train one model into `run_dir` (fresh, or continuing `checkpoint`); returns the summary. It holds the folder's
    `training_lock` meanwhile, as `splatu train` does: a second training of the folder is refused, and a render sees
    the run as training. A caller that holds the lock already calls `train_locked_run`.

    An ensemble's member folder is refused: its session would be missing from the ensemble's wall time, and a config
    other than the member's would make it a model the ensemble did not train; `splatu train --resume MEMBER`
    (`splatu.train_command.train`) trains it with its saved options and counts it."""
    ensemble = enclosing_ensemble(run_dir)
    if ensemble is not None:
        raise SplatuError(f"this folder is a member of the ensemble {ensemble}, which train_run would train outside "
                          "its record of wall time", f"in {run_dir}",
                          f"resume it with `splatu train --resume {shlex.quote(str(run_dir))}` "
                          "(from Python: splatu.train_command.train "
                          "with resume set), which counts it")
    with training_lock(run_dir):
        return train_locked_run(config, scene, run_dir, hooks, checkpoint, wall_start)


def train_locked_run(config: TrainConfig, scene: Scene, run_dir: Path, hooks: Sequence[StepHook],
                     checkpoint: dict[str, Any] | None = None, wall_start: float | None = None,
                     began: Callable[[], None] | None = None) -> dict[str, Any]:
    """`train_run` for a caller that holds `run_dir`'s `training_lock` (a second acquisition, even by the same
    process, is refused): `splatu train` and an ensemble's members, which choose what to resume under it. `began` is
    called once the state is built and fits the scene, when the training begins: an ensemble counts the wall time of
    a session that reached it, not of one refused before."""
    wall_start = time.perf_counter() if wall_start is None else wall_start
    if config.compile_kernels:  # here, so every way in (train, ensemble members, the benchmarks) compiles
        set_compile(True)
    keep_freed_memory()  # likewise: without it the first training of a process page-faults ~20% of its time away
    if checkpoint is None:
        config = with_choice_heads(config) if config.degree_choice.on else config
        save_config(config, run_dir / "config.yml")  # first: a stop from here on leaves a run that `restartable` takes
    try:
        state = fresh_state(config, scene) if checkpoint is None else restored_state(checkpoint, config, scene)
        if began is not None:
            began()
        return _train_state(state, config, scene, run_dir, hooks, checkpoint, wall_start)
    except TrainingInterrupted:
        raise
    except KeyboardInterrupt as stop:  # outside the steps: before the first, or finishing the run
        raise _stopped_outside_steps("interrupted", run_dir, signal_of(stop)) from None


def _train_state(state: TrainState, config: TrainConfig, scene: Scene, run_dir: Path, hooks: Sequence[StepHook],
                 checkpoint: dict[str, Any] | None, wall_start: float) -> dict[str, Any]:
    """`train_run` from its fresh or restored state: record the session's start, train, finish."""
    if checkpoint is not None:  # only once the scene loaded and fits: a failed resume must leave the run whole
        save_config(config, run_dir / "config.yml")
        remove_torn_checkpoints(run_dir)
        ensemble_reports = set_aside_ensemble_outputs(run_dir, state.step)
        if ensemble_reports is not None:
            console.print(f"resuming an ensemble's member from step {state.step}: the ensemble's renders and reports "
                          f"made of its later model moved to {ensemble_reports}", soft_wrap=True)
        abandoned = set_aside_later_work(run_dir, state.step)
        if abandoned is not None:
            console.print(f"resuming from step {state.step}: what the run did after it moved to "
                          f"{abandoned}", soft_wrap=True)
    # wall time counts scene loading and every earlier session up to its last checkpoint (older ones lack it)
    state.wall_start = wall_start - (0.0 if checkpoint is None else float(checkpoint.get("wall_seconds", 0.0)))
    if checkpoint is not None and (int(checkpoint["config"]["steps"]) < config.steps  # --extend-to
                                   or not checkpoint_path(run_dir, state.step).is_file()):
        # its checkpoint again, with the new length, or into a run that lacks it (a new run continuing a checkpoint
        # from outside any): a resume after a kill from here on trains on from it, not anew from config.yml
        _save(state, config, run_dir, MetricsLog(run_dir / "metrics.jsonl"))
    if checkpoint is not None:
        # a summary that outlived the resume's checks is a finished run's that this one trains on (after a kill, its
        # resume); without one, a report naming no checkpoint was made of this unfinished run as if it were finished
        finished = (run_dir / "summary.json").is_file()
        superseded = set_aside_final_outputs(run_dir, state.step)
        if superseded is not None:
            what = ("the finished model's summary, export and reports" if finished else
                    f"the renders and reports of the unfinished step-{state.step} model named as the finished one's")
            console.print(f"training on to step {config.steps}: {what} moved to {superseded}", soft_wrap=True)
    state, config = run_loop(state, config, scene, run_dir, hooks)
    return finish_run(state, config, scene, run_dir)
