"""`splatu train`: a new run, or `--resume` of a single run or of a whole ensemble.

It checks every option before the scene loads, loads the scene, makes the run folder (or finds the one to
resume, and the options it continues with), holds the run's lock, and hands over to `splatu.trainer` (one
run) or `splatu.ensemble_training`. `train(config)` is also the Python entry point.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

from splatu.checkpoint import (
    RESUME_KEYS,
    list_checkpoints,
    read_checkpoint,
    refuse_foreign_checkpoint,
    resolve_checkpoint,
    run_holding,
    saved_frame,
)
from splatu.config_values import changed_options, flat_options, to_dict
from splatu.data.assemble import refuse_split_flags_the_scene_overrides
from splatu.data.config import DataConfig
from splatu.data.resolve import (
    POSTER,
    downscale_note,
    load_new_scene,
    load_scene,
    refuse_unused_poster_options,
)
from splatu.data.scene import Scene
from splatu.degree_choice import held_out_block, with_choice_heads
from splatu.ensemble_dirs import ensemble_config, ensemble_members
from splatu.ensemble_training import counted_in_ensemble, enclosing_ensemble_lock, train_locked_ensemble
from splatu.errors import SplatuError, creatable_dir
from splatu.evaluation import refuse_unscorable_sets
from splatu.interrupts import TrainingInterrupted, exit_code, sigterm_as_ctrl_c
from splatu.losses import UncertaintyLossConfig, refuse_copies_of_the_own_head
from splatu.methods import METHODS, loss_setting, method_of
from splatu.run_dir import latest_new_run, training_lock
from splatu.train_config import (
    DEFAULT_PRESET,
    DISPLAY_OPTIONS,
    SCHEDULE,
    SPLATFACTO_STEPS,
    TrainConfig,
    blamed_on_preset,
    blamed_on_saved,
    check_parts,
    file_schedule,
    flags_given,
    flags_off_preset,
    from_dict,
    load_config,
    option_flag,
    option_value,
    own_length,
    preset_config,
    preset_label,
    preset_values,
    readable_preset_values,
    scaled_schedule,
    with_display,
)
from splatu.train_progress import console, scene_line
from splatu.trainer import fitting_frame, restartable, train_locked_run
from splatu.training_step import StepHook, resolution_level
from splatu.world_frame import require_same_frame, scene_frame


def check_options(config: TrainConfig, typed: Collection[str]) -> None:
    """Every option check that needs no scene: a bad option fails in one line before the scene loads (which
    may build the stand-in) and before a run folder is made and `latest` pointed at it. An option whose value came
    from the preset file, its flag not among those `typed`, is named as the file's."""
    try:
        check_parts(config)
        config.data.refuse_unused_flags()
        refuse_max_image_size_beside_downscale(config.data, typed)
        refuse_unused_poster_options(config.data)
        refuse_copies_of_the_own_head(config.uncertainty, config.model.u_sh_degree)  # parses every head, too
    except SplatuError as err:
        raise blamed_on_preset(err, config, typed) from None


UNCERTAINTY_OPTIONS = (*(f"uncertainty.{f.name}" for f in dataclasses.fields(UncertaintyLossConfig) if f.name != "off"),
                       "model.u_sh_degree", "model.u_init_logit")
"""The options only the uncertainty loss reads: with it off they change nothing but what config.yml records."""


def refuse_uncertainty_options_without_the_loss(config: TrainConfig, typed: Collection[str]) -> None:
    """Refuse `--method splatu` typed beside `--uncertainty.off` (which of the two trains?), and an uncertainty option
    typed (in `typed`) for a run without the loss (--method splatfacto or ensemble, or --uncertainty.off), which would
    never train and only be recorded as if it had. A preset file's or the defaults' values are not typed: a file may
    hold them for the runs that train the loss."""
    off_typed = "--uncertainty.off" in typed and config.uncertainty.off
    setting = loss_setting(config.method, config)
    if off_typed and "--method" in typed and setting:
        plain = next(name for name in METHODS if loss_setting(name, config) is False and not METHODS[name].ensemble)
        raise SplatuError(f"--method {config.method} trains the uncertainty loss, which --uncertainty.off turns off",
                          "in the options", f"drop --uncertainty.off, or pass --method {plain} for plain 3DGS")
    given = [name for name in UNCERTAINTY_OPTIONS if option_flag(name) in typed]
    if not config.uncertainty.off or not given:
        return
    listed = " ".join(f"{option_flag(name)} {option_value(config, name)}" for name in given)
    if off_typed or setting is not False:  # the method would train the loss: the flag turned it off
        cause, other = "--uncertainty.off", "drop --uncertainty.off"
    else:
        members = " (its members are plain splatfacto)" if METHODS[config.method].ensemble else ""
        trained = next(name for name in METHODS if loss_setting(name, config) and not METHODS[name].ensemble)
        cause, other = f"--method {config.method}{members}", f"pass --method {trained}"
    raise SplatuError(f"{listed} {'sets an option' if len(given) == 1 else 'set options'} of the uncertainty loss, "
                      f"which {cause} does not train", "in the options", f"drop {'it' if len(given) == 1 else 'them'}, "
                      f"or {other} to train the loss")


def refuse_max_image_size_beside_downscale(data: DataConfig, typed: Collection[str]) -> None:
    """A typed --max-image-size only chooses the factor that --downscale gives: beside it, it would change nothing,
    and the run would load at another size than the user asked for without a word. `typed`: the flags typed."""
    if data.downscale is not None and "--max-image-size" in typed:
        raise SplatuError(f"--max-image-size {data.max_image_size} is not used beside --downscale {data.downscale}, "
                          "which sets the image size itself", "in the options",
                          "drop --max-image-size, or drop --downscale to have train choose the factor from it")


def budget_note(config: TrainConfig, scene: Scene) -> str | None:
    """What to say when the run starts above its Gaussian budget: --densify.max-gaussians caps what densification
    adds, and one Gaussian per initial point is made before it, so a cloud larger than the budget is not cut to it."""
    start = scene.points.shape[0] or config.model.random_init_points
    budget = config.densify.max_gaussians
    if start <= budget:
        return None
    fewer = "thin the point cloud" if scene.points.shape[0] else "lower --model.random-init-points"
    return (f"note: the run starts with {start:,} Gaussians (one per initial point), above --densify.max-gaussians "
            f"{budget:,}: densification adds none until pruning brings the model under it; raise the budget, or "
            f"{fewer}")


def schedule_note(config: TrainConfig, typed: Collection[str]) -> str | None:
    """What to say when a typed --steps set another length than the preset's (`scaled_schedule`): one line of the
    values it rescaled and of the preset's own values off the rule that it kept, spelt as the flags that would repeat
    them; the flags typed beside it are the user's own, so not told. None when there is nothing to tell."""
    scaled = scaled_schedule(config.preset, config.steps, typed) if "--steps" in typed else None
    if scaled is None:
        return None
    kept = [name for name in SCHEDULE if name not in scaled and option_flag(name) not in typed]

    def flags(names: Sequence[str]) -> str:
        return " ".join(f"{option_flag(name)} {option_value(config, name)}" for name in names)

    told = []
    if scaled:
        told.append(f"rescales the schedule to splatfacto's × {config.steps}/{SPLATFACTO_STEPS}: {flags(list(scaled))}")
    if kept:
        told.append(f"keeps the preset's {flags(kept)}, {_why_kept(preset_values(config.preset))}")
    if not told:  # every schedule flag typed
        return None
    return f"note: --steps {config.steps} {'; '.join(told)} (a flag typed beside --steps sets that value instead)"


def file_schedule_note(config: TrainConfig, typed: Collection[str]) -> str | None:
    """What to say when a preset file sets its steps but leaves schedule settings out (`file_schedule`): they follow
    its steps, not the full recipe's 30000 that the file starts from. Not when a typed --steps rescaled them anyway
    (`schedule_note` tells that), nor of a setting typed (the user's own)."""
    values = readable_preset_values(config.preset, as_written=True) or {}
    if "steps" not in values or ("--steps" in typed and config.steps != values["steps"]):
        return None
    left_out = [name for name in SCHEDULE if name not in values]
    own = file_schedule(values)
    told = [name for name in own if option_flag(name) not in typed]
    if not told or values["steps"] == SPLATFACTO_STEPS:
        return None
    flags = " ".join(f"{option_flag(name)} {option_value(config, name)}" for name in told)
    which = ("no schedule, so its schedule is" if len(left_out) == len(SCHEDULE)
             else "part of the schedule, so the rest is")
    return (f"note: {preset_label(config.preset)} sets steps: {values['steps']} and {which} splatfacto's scaled to "
            f"{values['steps']} steps (× {values['steps']}/{SPLATFACTO_STEPS}): {flags} (a flag typed sets that value "
            "instead)")


def steps_source(config: TrainConfig, typed: Collection[str]) -> str:
    """Where the run's length came from, as a note names it: `--steps`, or the preset's `steps:` when the file set it
    and --steps was not typed (the user never typed a --steps to blame)."""
    from_file = "--steps" not in typed and "steps" in (readable_preset_values(config.preset, as_written=True) or {})
    return f"{preset_label(config.preset)}'s steps:" if from_file else "--steps"


def _why_kept(values: Mapping[str, Any]) -> str:
    """Why `schedule_note` kept a preset file's values (`values`): off the rule at the file's own length, or, when its
    steps is no length (the typed --steps replaced it), because there is no length to scale from."""
    if own_length(values) is None:
        return f"as the file's own steps: {values['steps']!r} is no length to rescale them from"
    return f"not splatfacto's × its own length/{SPLATFACTO_STEPS}"


def resolution_note(config: TrainConfig, extension: bool = False, steps_from: str = "--steps") -> str | None:
    """What to say when a run ends before its resolution schedule reaches full resolution: with a schedule not scaled
    to the run (flags typed beside --steps, a 1- or 2-step run, a preset file's own values) such a run trains only on
    downscaled images and is scored on full-resolution ones. An `extension` (--extend-to) keeps the run's
    --resolution-interval, which --resume ignores: only a longer extension reaches full resolution. `steps_from`
    names where a new run's length came from (`steps_source`)."""
    last = resolution_level(config.steps - 1, config.resolution_levels, config.resolution_interval)
    if last == 0:
        return None
    levels, tenth = config.resolution_levels, max(1, config.steps // 10)
    if extension:
        full_at = levels * config.resolution_interval
        remedy = f"--extend-to {full_at + 1} or more reaches full resolution at step {full_at}"
    else:  # a tenth of the steps, as in every preset, unless that leaves the last step short of full resolution
        suggested = tenth if levels * tenth < config.steps else (config.steps - 1) // levels
        why = " (a tenth of the steps, as in every preset)" if suggested == tenth else ""
        remedy = ("--resolution-levels 0 trains at full resolution throughout" if suggested == 0 else
                  f"--resolution-interval {suggested}{why} reaches full resolution at step {levels * suggested}")
    flag = "--extend-to" if extension else steps_from
    return (f"note: {flag} {config.steps} ends at 1/{2 ** last} resolution, so no step trains on the images at the "
            f"size they loaded at (the schedule starts at 1/{2 ** levels} of it and doubles every "
            f"--resolution-interval {config.resolution_interval} steps); {remedy}")


def _flag(config: TrainConfig, name: str) -> str:
    """How dotted option `name` was spelt on the command line: `--no-progress` for a boolean turned off."""
    value = option_value(config, name)
    *parents, last = name.removeprefix("data.").split(".")
    return "--" + ".".join([*parents, ("no-" if value is False else "") + last]).replace("_", "-")


def resumed_config(given: TrainConfig, saved: TrainConfig, run_dir: Path,
                   typed: Collection[str] | None = None, *, in_new_run: bool = False) -> TrainConfig:
    """The config a resume continues with: the run's saved one. `--data` beside `--resume` moves only where the
    scene is (the run's split and downscale stay); any other option given is ignored, and the user told so: each
    flag `typed` on the command line (one at the preset's value too, which the run may not have), or for a caller
    without one (None), each option off a bare preset's value (none when the preset cannot be read, as a resume never
    needs it). An option of what the session shows (`DISPLAY_OPTIONS`: --no-progress) given is taken, not ignored, and
    so is --output-dir `in_new_run` (a checkpoint inside no run, `_resume_in_new_run`), which goes where a new run
    would."""
    if typed is None:
        chosen = [name for name, default in (("preset", DEFAULT_PRESET), ("method", "splatu"))
                  if getattr(given, name) != default]  # the base of the comparison below, so never in it
        try:
            bare = preset_config(given.preset, given.method)
        except SplatuError:  # its preset file gone since (a relative path from another folder): none can be told
            bare = given
        given_names = chosen + changed_options(given, bare)
    else:
        given_names = [name for name in flat_options(to_dict(given)) if option_flag(name) in typed]
    taken = ("resume", "extend_to", "data.data", *DISPLAY_OPTIONS, *(("output_dir",) if in_new_run else ()))
    ignored = [name for name in given_names if name not in taken]
    if ignored:
        flags = " ".join(_flag(given, name) for name in ignored)
        more = " (--extend-to N trains the run on to N steps)" if "steps" in ignored else ""
        console.print(f"note: --resume continues with the run's saved options; ignoring {flags}{more}", soft_wrap=True)
    saved = with_display(saved, given, [name for name in given_names if name in DISPLAY_OPTIONS])
    if in_new_run:
        saved = dataclasses.replace(saved, output_dir=given.output_dir)
    if given.data.data != POSTER:
        return dataclasses.replace(saved, data=dataclasses.replace(saved.data, data=given.data.data))
    if saved.data.data != POSTER and not Path(saved.data.data).exists():
        raise SplatuError(f"the scene this run was trained on no longer exists ({saved.data.data})", f"in {run_dir}",
                          "pass --data PATH with the scene's new location beside --resume (the run's split and "
                          "downscale still apply)")
    return saved


def extended(saved: TrainConfig, steps: int, step: int, run_dir: Path) -> TrainConfig:
    """`saved` trained on to `steps` in all from `step`: only the length changes. The means' rate keeps the decay it
    had (over the old length, then held), so the step after a checkpoint trains exactly as it would have. `steps`
    equal to the run's length is a plain resume: the same command given again, as a requeued job does, trains an
    extension that stopped part way on, and finds one that ended already finished."""
    if steps == saved.steps:
        return saved
    if steps <= saved.steps:
        raise SplatuError(f"--extend-to {steps} is not more than the {saved.steps} steps this run was set to train",
                          f"in {run_dir}", f"pass --extend-to with more than {saved.steps}, or start a new run")
    if saved.degree_choice.on:  # not yet chosen (a choice turns it off): its decision step is a fraction of the length
        raise SplatuError("--extend-to cannot train on a run stopped before its mid-run SH degree choice "
                          "(--degree-choice.on), which a longer run would make at another step", f"in {run_dir}",
                          "finish it with a plain --resume first; once it has chosen, --extend-to trains it on")
    decay = saved.optim.means_lr_steps or (saved.steps if step > 0 else 0)  # from step 0: as a new run of N steps
    return dataclasses.replace(saved, steps=steps, optim=dataclasses.replace(saved.optim, means_lr_steps=decay))


def filed_as_trained(config: TrainConfig) -> TrainConfig:
    """`config` named after the method it trains, saying so when a flag changed it: `--uncertainty.off` trains
    plain splatfacto, and its run belongs beside splatfacto's, not among runs with an uncertainty to score."""
    method = method_of(config)
    if method != config.method:
        console.print(f"note: these options train --method {method}, not {config.method}; the run is filed under "
                      f"{method}/", soft_wrap=True)
    return dataclasses.replace(config, method=method)


def train(config: TrainConfig, hooks: Sequence[StepHook] = (), typed: Collection[str] | None = None) -> Path:
    """Train (or resume, a single run or a whole ensemble) as configured; returns the run directory. `typed`: the
    flags of the command line (`flags_given`), which a new run's checks and notes tell from the preset's values (a
    --max-image-size typed beside --downscale, a file's value blamed on the file, the schedule a --steps rescaled)
    and a resume names as ignored; None for a caller without one, whose flags are told by value (`flags_off_preset`,
    and for a resume, `resumed_config`'s own comparison)."""
    wall_start = time.perf_counter()
    if config.resume is not None:
        saved_ensemble = ensemble_config(config.resume)
        if saved_ensemble is not None:
            run_dir = Path(config.resume).expanduser()
            with training_lock(run_dir):
                return _resume_ensemble(config, saved_ensemble, run_dir, wall_start, hooks, typed)
        path = _resume_point(config.resume)
        run_dir = Path(config.resume).expanduser().resolve() if path is None else run_holding(path)
        if run_dir is None:
            return _resume_in_new_run(config, path, wall_start, hooks, typed)
        # a member's resume holds its ensemble's lock too; then choose again: a training that just ended may have
        # pruned the checkpoint or saved a newer one
        with enclosing_ensemble_lock(run_dir) as ensemble, training_lock(run_dir):
            return _resume_run(config, _resume_point(config.resume), run_dir, ensemble, wall_start, hooks, typed)
    typed = flags_off_preset(config) if typed is None else typed  # as the caller gave it, before the method's own
    refuse_uncertainty_options_without_the_loss(config, typed)
    config = filed_as_trained(config)
    if config.degree_choice.on:
        config = with_choice_heads(config)
    check_options(config, typed)
    creatable_dir(config.output_dir, "--output-dir")  # before the scene, whose loading can take minutes
    given = config.data
    data, scene = load_new_scene(given)
    config = dataclasses.replace(config, data=data)
    refuse_split_flags_the_scene_overrides(config.data, scene)
    refuse_unscorable_sets(scene)
    console.print(scene_line(scene), soft_wrap=True)
    longest = max(max(c.width, c.height) for views in (scene.train, scene.eval, *scene.extra_eval.values())
                  for c in views.cameras)
    notes = (schedule_note(config, typed), file_schedule_note(config, typed),
             downscale_note(given, config.data, longest),
             resolution_note(config, steps_from=steps_source(config, typed)), budget_note(config, scene))
    for note in notes:
        if note is not None:  # after the scene line, which a run's output starts with
            console.print(note, soft_wrap=True)
    if config.degree_choice.on:
        held_out_block(len(scene.train), config.degree_choice.held_out)  # too few views: fail before the run folder
    with latest_new_run(config.output_dir, scene.name, config.method) as (run_dir, began), training_lock(run_dir):
        if config.ensemble > 1:
            train_locked_ensemble(config, scene, run_dir, wall_start, hooks, began)
        else:
            train_locked_run(config, scene, run_dir, hooks, wall_start=wall_start, began=began)
    return run_dir


def _resume_ensemble(config: TrainConfig, saved: TrainConfig, run_dir: Path, wall_start: float,
                     hooks: Sequence[StepHook], typed: Collection[str] | None) -> Path:
    """`--resume` of an ensemble run: finish every unfinished member (`typed`: as `resumed_config` takes it)."""
    if config.extend_to is not None:  # its members' schedules and its wall-time record are one run's
        raise SplatuError("--extend-to trains on a single run, not an ensemble", f"in {run_dir}",
                          "train a new ensemble with --steps N")
    saved = resumed_config(config, saved, run_dir, typed)
    members = ensemble_members(run_dir, saved)
    if (run_dir / "ensemble.json").is_file() and all((m / "summary.json").is_file() for m in members):
        console.print(f"already finished: every member of {run_dir} is trained; nothing to resume", soft_wrap=True)
        return run_dir
    scene = load_scene(saved.data)
    refuse_unscorable_sets(scene)
    console.print(scene_line(scene), soft_wrap=True)
    started = [found[-1] for found in map(list_checkpoints, members) if found]
    if started:  # members not yet started would otherwise train on whatever scene --data now names
        require_same_frame(saved_frame(read_checkpoint(started[0])), scene_frame(scene), f"in {run_dir}",
                           "resume with the scene as it was, or start a new run")
    train_locked_ensemble(saved, scene, run_dir, wall_start, hooks)
    return run_dir


def _resume_point(resume: Path) -> Path | None:
    """The checkpoint a `--resume` continues from, or None for a run folder that restarts at step 0."""
    target = Path(resume).expanduser()
    if target.is_dir() and restartable(target):
        return None
    return resolve_checkpoint(target)


def check_restart(saved: TrainConfig, run_dir: Path) -> None:
    """A run stopped before its first checkpoint restarts from step 0, a new model made of its config.yml: a new
    run's checks apply, which a saved config with a value allowed when it was written (threshold 0, a u_init_logit
    beyond ±30) passes only to load. Told before the scene loads, as the file's keys: a flag beside --resume is
    ignored."""
    try:
        check_parts(saved)
    except SplatuError as err:
        raise blamed_on_saved(err, saved, run_dir / "config.yml", ", which this resume trains anew from (the run "
                              "stopped before its first checkpoint)") from None


def _resume_run(config: TrainConfig, path: Path | None, run_dir: Path, ensemble: Path | None, wall_start: float,
                hooks: Sequence[StepHook], typed: Collection[str] | None) -> Path:
    """`--resume` of a single run from checkpoint `path`, or from step 0 and its config.yml when `path` is None;
    `ensemble` is the ensemble run that `run_dir` is a member of, whose wall time the session then adds to."""
    checkpoint = None if path is None else read_checkpoint(path, RESUME_KEYS)
    if checkpoint is not None:  # `run_holding`: the run has a config.yml
        refuse_foreign_checkpoint(from_dict(checkpoint["config"], str(path)), load_config(run_dir / "config.yml"),
                                  path, run_dir, "--resume")
    saved = resumed_config(config, load_config(run_dir / "config.yml") if checkpoint is None
                           else from_dict(checkpoint["config"], str(path)), run_dir, typed)
    step = 0 if checkpoint is None else int(checkpoint["step"])
    if checkpoint is None:
        check_restart(saved, run_dir)
    if config.extend_to is not None and ensemble is not None:
        raise SplatuError("--extend-to trains on a single run, not an ensemble's member (the others would stay at "
                          "their length)", f"in {run_dir}", "train a new ensemble with --steps N")
    saved = _extended_if_asked(saved, config.extend_to, step, run_dir)
    if step >= saved.steps and (run_dir / "summary.json").is_file():
        longer = config.steps if typed is not None and "--steps" in typed and config.steps > saved.steps else "N"
        console.print(f"already finished: {run_dir} trained all {saved.steps} steps; nothing to resume (--extend-to "
                      f"{longer} trains it on to {longer} steps)", soft_wrap=True)  # a typed --steps named the length
        return run_dir
    console.print(f"resuming {run_dir} at step {step} of {saved.steps}", soft_wrap=True)
    scene = load_scene(saved.data)
    refuse_unscorable_sets(scene)
    console.print(scene_line(scene), soft_wrap=True)
    with counted_in_ensemble(ensemble, wall_start) as began:
        train_locked_run(saved, scene, run_dir, hooks, checkpoint, wall_start, began)
    return run_dir


def _extended_if_asked(saved: TrainConfig, extend_to: int | None, step: int, where: Path) -> TrainConfig:
    """`saved` trained on to --extend-to's length from `step` when it is given (`extended`), with its resolution
    note: a short run trained on can still end before full resolution, as a new one can."""
    if extend_to is None:
        return saved
    saved = extended(saved, extend_to, step, where)
    note = resolution_note(saved, extension=True)
    if note is not None:
        console.print(note, soft_wrap=True)
    return saved


def _resume_in_new_run(config: TrainConfig, path: Path, wall_start: float, hooks: Sequence[StepHook],
                       typed: Collection[str] | None) -> Path:
    """`--resume` of checkpoint `path`, which is inside no run (`run_holding`: a copy in ~/Downloads, or one an
    earlier resume set aside in abandoned/): it trains on exactly as its run's resume would, but in a new run folder
    where a new run goes (<--output-dir>/<scene>/<method>/<time>, `latest` pointed at it), so that the folder it lies
    in never becomes a run. The folder is made once the scene has loaded and fits the checkpoint."""
    checkpoint = read_checkpoint(path, RESUME_KEYS)
    saved = resumed_config(config, from_dict(checkpoint["config"], str(path)), path, typed, in_new_run=True)
    saved = filed_as_trained(saved)  # an ensemble's member trains on as the single run it is
    step = int(checkpoint["step"])
    saved = _extended_if_asked(saved, config.extend_to, step, path)
    creatable_dir(saved.output_dir, "--output-dir")  # before the scene, whose loading can take minutes
    scene = load_scene(saved.data)
    refuse_unscorable_sets(scene)
    fitting_frame(checkpoint, saved, scene)
    named = Path(config.resume).expanduser()  # a folder named as a run, but without the config.yml a run writes first
    why = (f"{named} holds no config.yml, so it is no run folder" if named.is_dir()
           else f"{path} is not inside a run folder")
    with latest_new_run(saved.output_dir, scene.name, saved.method) as (run_dir, began), training_lock(run_dir):
        console.print(f"{why}: training continues from {path.name} (step {step} of {saved.steps}) in a new run, "
                      f"{run_dir}", soft_wrap=True)
        console.print(scene_line(scene), soft_wrap=True)
        train_locked_run(saved, scene, run_dir, hooks, checkpoint, wall_start, began)
    return run_dir


def run_command(config: TrainConfig, argv: Sequence[str] | None = None) -> None:
    """`splatu train` with the options `argv` gave (None: no command line, as `train`'s `typed`): train, print where
    the run went; Ctrl-C or SIGTERM prints how to resume and exits 130 or 143 (128 + the signal, as the shell
    reports a process the signal ended)."""
    try:
        with sigterm_as_ctrl_c():
            run_dir = train(config, typed=None if argv is None else flags_given(argv))
    except TrainingInterrupted as stop:
        print(stop.message, file=sys.stderr)  # plain print: one line, never wrapped
        raise SystemExit(exit_code(stop)) from None
    print(f"run saved to {run_dir}")  # on stdout, the one line a script reads
