"""Training configuration: one dataclass tree, presets as YAML, and a YAML round trip.

`TrainConfig()` holds the full splatfacto recipe (30000 steps, REFERENCE §3). On 2 CPU cores
that is far too long, so a *preset* (configs/<name>.yaml, or any YAML path) rescales it:
its values replace the dataclass defaults, and command-line flags override them in turn.
The presets scale every step-based setting (`SCHEDULE`) by one factor s = steps / 30000, as
`splatfacto_schedule` computes it (tests/unit/test_trainer.py checks each preset file against it), so
iterations, the resolution schedule and densification move together instead of as scattered constants.
`--steps N` typed for a new run applies the same rule at N (`scaled_schedule`), as gsplat's `steps_scaler` does.
A user's preset file starts from the full recipe; the schedule settings it leaves out follow its own steps by the
same rule (`file_schedule`), so `steps: 300` alone densifies as a 300-step run should.

Which flags were typed (for --steps, a --max-image-size beside --downscale, a preset file's value blamed on the
file) is the command line's say (`flags_given`); Python code calling `train` has none, so there a flag counts
as typed when its option is off a bare preset's value (`flags_off_preset`), one notion spelt the same way.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import torch
import tyro
import yaml

from splatu.atomic import atomic_write_text
from splatu.config_values import apply_values, flat_options, nested_options, read_yaml, to_dict, without_options
from splatu.data.config import DataConfig
from splatu.degree_choice import DegreeChoiceConfig
from splatu.densify import DensifyConfig
from splatu.errors import OptionError, SplatuError, require_at_least
from splatu.losses import UncertaintyLossConfig
from splatu.methods import get_method, method_help
from splatu.model import ModelConfig
from splatu.optim import OptimConfig


def _configs_dir() -> Path:
    """The presets: inside the package in an installed wheel (pyproject maps configs/ there), else configs/
    beside the package in the source tree (a clone, or an editable install)."""
    package = Path(__file__).resolve().parent
    installed = package / "configs"
    return installed if installed.is_dir() else package.parent / "configs"


CONFIGS_DIR = _configs_dir()
DEFAULT_PRESET = "fast"
FULL_RECIPE = "none"
"""The preset name of the dataclass defaults themselves: the full 30000-step splatfacto recipe."""
MAX_SEED = 2**32
"""Seeds are below this, so every seed derived from one (per epoch, per member, per head) fits 64 bits."""
SPLATFACTO_STEPS = 30000
SCHEDULE = ("resolution_interval", "model.sh_degree_interval", "densify.warmup_length", "densify.refine_every",
            "densify.stop_split_at", "densify.stop_screen_size_at")
"""The recipe's step-based settings, which the presets scale with their length. The opacity reset, counted in
refinements, follows refine_every; the means' decay (optim.means_lr_steps 0) and the degree choice (a fraction)
follow the length by themselves. The contribution window (a view-count floor), the pause after a reset and the
checkpoint, evaluation and log cadences (bookkeeping, which the model does not depend on) are not scaled."""


@dataclass
class TrainConfig:
    """Everything one training run needs; saved as config.yml beside the run."""

    data: Annotated[DataConfig, tyro.conf.arg(name="")] = field(default_factory=DataConfig)
    """Which scene to train on and how to split it (flat flags: `--data poster`, `--downscale 4`)."""
    model: ModelConfig = field(default_factory=ModelConfig)
    """Gaussian model: SH degrees, initialisation."""
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    """Adaptive density control schedule and Gaussian budget."""
    optim: OptimConfig = field(default_factory=OptimConfig)
    """Adam learning rates per parameter group."""
    uncertainty: UncertaintyLossConfig = field(default_factory=UncertaintyLossConfig)
    """The view-dependent uncertainty loss (`--uncertainty.off` trains plain 3DGS)."""
    degree_choice: DegreeChoiceConfig = field(default_factory=DegreeChoiceConfig)
    """Choose the colour and u-SH degrees per scene on held-out views (`--degree-choice.on`)."""
    method: Annotated[str, tyro.conf.arg(help=method_help())] = "splatu"
    preset: str = FULL_RECIPE
    """Preset whose values are the defaults: a name in configs/ (fast, quality) or a YAML path; none (FULL_RECIPE)
    = the full splatfacto recipe, these dataclass defaults. A YAML file starts from that recipe, the step-based
    settings it leaves out scaled to its own steps (copy configs/fast.yaml to start from fast)."""
    steps: int = SPLATFACTO_STEPS
    """Number of optimisation steps (one training image per step). Typed for a new run with another length than
    the preset's, it rescales the step-based schedule (resolution levels, SH degree, densification) to the splatfacto
    recipe's × steps / 30000, as the presets are made (train says so in a note); a schedule flag typed beside it, or
    a preset file's own value off that rule, is kept. --resume keeps the run's saved schedule."""
    resolution_levels: int = 2
    """Start at 1/2^levels resolution; k = max(levels - step // resolution_interval, 0)."""
    resolution_interval: int = 3000
    """Steps per resolution level (splatfacto: 3000)."""
    ssim_lambda: float = 0.2
    """Weight of (1 - SSIM) in the photometric loss; L1 gets 1 - ssim_lambda."""
    train_background: Literal["random", "black", "white"] = "random"
    """Training background: random (a new colour each step, so empty space cannot fake colour; images with an
    alpha channel are recomposited on it) or fixed (white for RGB images already composited on white, which have
    no alpha to recomposite); evaluation renders on black (white if white)."""
    eval_every_steps: int = 0
    """Evaluate on the held-out views every this many steps (0: only at the end)."""
    log_every: int = 10
    """Append a training line to metrics.jsonl every this many steps, and at every densification step, whose line
    says what it cloned, split and pruned (every step when --densify.refine-every is 1, as --steps 300 sets it)."""
    checkpoint_every: int = 1000
    """Write a checkpoint every this many steps (and always at the end); 0: only at the end."""
    keep_checkpoints: int = 2
    """Keep the newest this many checkpoints, deleting older ones as new ones are written: one with its Adam moments
    is tens of MB. A checkpoint is written whole before the one before it goes, whatever this is; two keep an earlier
    point to resume from."""
    output_dir: Path = Path("outputs")
    """Runs go to <output_dir>/<scene>/<method>/<timestamp>/, with a `latest` symlink beside them."""
    seed: int = 0
    """Seeds torch, numpy, random and the trainer's own generator: same seed, same run."""
    resume: Path | None = None
    """Continue a run exactly from its latest checkpoint (a run directory or a .pt file), with its saved options:
    other flags are ignored (and named), except --data, which gives the scene's new location, --extend-to, and
    --no-progress, which changes only what the session shows."""
    extend_to: int | None = None
    """With --resume: train a single run on to this many steps in all, more than it was set to train (or the same
    number again, which continues an extension that stopped part way or finds it finished). Its schedules stay as
    they were, by step (so densification goes on only up to --densify.stop-split-at), and the means' rate holds its
    final value past the old length; the old final model's summary, export (the model itself) and reports move to
    superseded/<time>/, and its checkpoint stays until newer ones prune it (--keep-checkpoints)."""
    ensemble: int = 1
    """Train this many members that differ only in seed (seed + k) into <run>/members/<k>/; `--method ensemble`
    trains the paper's 10 when --ensemble is not given (a typed --ensemble 1 trains one model: plain splatfacto)."""
    max_nonfinite_steps: int = 5
    """Stop when this many steps in a row have a non-finite loss or gradient (each one is skipped)."""
    progress: bool = True
    """Show progress: a live bar (step, loss, PSNR, #Gaussians, it/s, ETA) and a bar of each evaluation's views on a
    terminal, plain lines off one."""
    compile_kernels: bool = False
    """Run the rasterizer's kernels through torch.compile: on in both presets (the poster main job took 4 min 59 s
    against 12 min 8 s eager at the old 1000-step schedule, on an earlier host and before later speed-ups; the
    first render of a process compiles, ~10 s with a warm cache, about a minute cold); --no-compile-kernels runs
    eager torch. SPLATU_COMPILE=1 also turns it on."""

    def __post_init__(self) -> None:
        self.data = absolute_data(self.data)
        positive = {"steps": self.steps, "resolution_interval": self.resolution_interval,
                    "log_every": self.log_every, "ensemble": self.ensemble, "keep_checkpoints": self.keep_checkpoints,
                    "max_nonfinite_steps": self.max_nonfinite_steps}
        for name, value in positive.items():
            require_at_least(value, 1, f"--{name.replace('_', '-')}")
        if not 0.0 <= self.ssim_lambda <= 1.0:
            raise SplatuError(f"--ssim-lambda {self.ssim_lambda} is not in [0, 1]", "in the training options",
                              "pass a weight from 0 (L1 only) to 1 (SSIM only); 3DGS uses 0.2")
        if self.extend_to is not None:
            require_at_least(self.extend_to, 1, "--extend-to")
            if self.resume is None:
                raise SplatuError("--extend-to trains on a run that --resume names", "in the training options",
                                  "pass --resume RUN beside it, or --steps N for a new run's length")
        for name in ("resolution_levels", "eval_every_steps", "checkpoint_every", "seed"):
            require_at_least(getattr(self, name), 0, f"--{name.replace('_', '-')}")
        if self.seed + self.ensemble > MAX_SEED:  # camera_index seeds torch with seed · 1,000,003 + epoch (64 bits);
            # an ensemble's members take seed, seed + 1, …
            raise SplatuError(f"--seed {self.seed} is too large", "in the training options",
                              f"pass a seed below {MAX_SEED - self.ensemble + 1:,}")


DISPLAY_OPTIONS = ("progress",)
"""Options that change what a session shows, never what it trains: a resume takes them from its own command (a batch
job resuming a run turns the bar off), where every other option is the run's saved one. Not --compile-kernels, whose
rounding differs from eager torch's, so that a resume with it changed would not continue the run exactly."""


def with_display(saved: TrainConfig, given: TrainConfig, names: Collection[str] = DISPLAY_OPTIONS) -> TrainConfig:
    """`saved` showing what `given` asks to, for the display options `names` (a resume: those typed, so a run started
    with --no-progress stays quiet when resumed without it). The run's config.yml and checkpoints then record the
    latest session's value: they hold the config that session ran with (checkpoint.RUN_CHANGES lets them differ from
    an older checkpoint)."""
    return dataclasses.replace(saved, **{name: getattr(given, name) for name in names})


def eval_background(config: TrainConfig) -> torch.Tensor:
    """The background evaluation renders on: white for white-background runs, else black."""
    return torch.full((3,), 1.0 if config.train_background == "white" else 0.0)


def absolute_data(data: DataConfig) -> DataConfig:
    """`data` with its scene path and eval list made absolute: the saved config must name the same files
    when render-uncertainty or eval-ause read it from another working directory. `poster` stays a name."""
    changes: dict[str, Any] = {}
    if data.data != "poster" and not Path(data.data).expanduser().is_absolute():
        changes["data"] = str(Path(data.data).expanduser().absolute())
    if data.eval_list is not None and not data.eval_list.is_absolute():
        changes["eval_list"] = data.eval_list.absolute()
    return dataclasses.replace(data, **changes) if changes else data


def preset_path(preset: str) -> Path:
    """A preset name (a file in configs/) or a path to a YAML file."""
    named = CONFIGS_DIR / f"{preset}.yaml"
    if named.is_file():
        return named
    path = Path(preset).expanduser()
    if path.is_file():
        return path
    if path.suffix in (".yaml", ".yml") or len(path.parts) > 1:
        shipped = (CONFIGS_DIR / f"{path.stem}.yaml").is_file()  # `--preset fast.yaml` from a folder without it
        fix = f", or pass --preset {path.stem} for the shipped preset" if shipped else ""
        raise SplatuError("preset file not found", f"at {path}", f"check the path of the YAML file{fix}")
    known = sorted(p.stem for p in CONFIGS_DIR.glob("*.yaml"))
    raise SplatuError(f"unknown preset {preset!r}", f"in {CONFIGS_DIR}",
                      f"use one of {', '.join(known)} or a path to a YAML file")


def preset_label(preset: str) -> str:
    """How a note names preset `preset`: `preset fast` for a shipped one, else its file's path."""
    return f"preset {preset}" if (CONFIGS_DIR / f"{preset}.yaml").is_file() else str(preset_path(preset))


SAVED_BEFORE = {"model": {"init_rotations": "identity"}}
"""What a saved run without these keys trained with: identity initial rotations before 3b6a78d (so that its restart
from step 0, or its ensemble's members not yet begun, start as it did)."""


def from_dict(values: Mapping[str, Any], source: str = "a saved config") -> TrainConfig:
    """A saved config (config.yml, a checkpoint's): an option it lacks was added after it was saved, so it reads as
    what the run trained with then (`SAVED_BEFORE`), not as today's default."""
    older = {part: {**options, **values[part]} for part, options in SAVED_BEFORE.items()
             if isinstance(values.get(part), Mapping)}
    return apply_values(TrainConfig(), {**values, **older}, source)


def save_config(config: TrainConfig, path: Path) -> None:
    atomic_write_text(path, yaml.safe_dump(to_dict(config), sort_keys=False))


def load_config(path: Path) -> TrainConfig:
    """Read a config.yml written by `save_config`."""
    return from_dict(read_yaml(path), str(path))


def check_parts(config: TrainConfig) -> None:
    """The range checks of `config`'s parts that do not run as they are made, for a new run: a saved config that
    carried a value they refuse (one allowed when it trained: the uncertainty threshold 0, a u_init_logit beyond
    ±30) still loads for render, eval, export and resume."""
    for part in (config.data, config.model, config.optim, config.densify, config.degree_choice, config.uncertainty):
        part.validate()


def option_flag(name: str) -> str:
    """The flag of dotted option `name`: `model.sh_degree` is --model.sh-degree, the scene's are flat (--downscale)."""
    return "--" + name.removeprefix("data.").replace("_", "-")


def _with_preset(config: TrainConfig, path: Path, overridden: Collection[str]) -> TrainConfig:
    """`config` with the preset file's values, less those of the flags `overridden` (which replace them anyway)."""
    raw = read_yaml(path)
    values = without_options(raw, {name for name in flat_options(raw) if option_flag(name) in overridden})
    own = {name: value for name, value in file_schedule(raw).items() if option_flag(name) not in overridden}
    try:
        config = apply_values(apply_values(config, values, str(path)), nested_options(own), str(path))
        check_parts(config)
    except SplatuError as err:
        raise _blamed_on_file(err, path, values) from None
    return config


def _blamed_on_file(err: SplatuError, path: Path, values: Mapping[str, Any]) -> SplatuError:
    """`err`, refusing the values of preset file `path`, told as the file's: the check names the option by its flag,
    which the user never typed, so the option is named by the file's key (with its value, for a range check)."""
    given = flat_options(values)
    keys = _keys_named(given, (err.what, err.where, err.fix))
    if not keys:
        return SplatuError(err.what, f"in {path}", err.fix)
    flags = [option_flag(key) for key in keys]
    if isinstance(err, OptionError) and [err.flag] == flags:
        return SplatuError(f"{keys[0]}: {err.value} {err.problem}", f"in {path}",
                           f"set {keys[0]} to {err.allowed} in that file, or override it with {flags[0]}")
    what = _as_keys(err.what, keys)
    named = what != err.what or all(str(given[key]) in what for key in keys)  # the keys or their values are said
    held = ", ".join(f"{key}: {given[key]!r}" for key in keys)
    return SplatuError(what if named else f"{what} (the file's {held})", f"in {path}",
                       f"fix {' or '.join(keys)} in that file, or override it with {' or '.join(flags)}")


def blamed_on_saved(err: SplatuError, config: TrainConfig, path: Path, why: str) -> SplatuError:
    """`err`, from a check of a saved run's `config` (its file `path`, which a restart trains anew from: `why`),
    told as the file's: every flag is ignored beside --resume, so the check's flags are named by the file's keys, and
    the fix is an edit of the file or a new run."""
    keys = _keys_named(flat_options(to_dict(config)), (err.what, err.where, err.fix))
    if isinstance(err, OptionError) and [err.flag] == [option_flag(key) for key in keys]:
        edit = f"set {keys[0]} to {err.allowed} in that file"
    else:
        edit = f"edit {' or '.join(keys) or 'its value'} in that file: {_as_keys(err.fix, keys)}"
    return SplatuError(_as_keys(err.what, keys), f"in {path}{why}", f"{edit}; or start a new run (without --resume)")


def _as_keys(text: str, keys: Collection[str]) -> str:
    """`text` with the flags of options `keys` spelt as the preset file's keys."""
    for key in keys:
        text = re.sub(re.escape(option_flag(key)) + r"(?![\w-])", key, text)
    return text


def blamed_on_preset(err: SplatuError, config: TrainConfig, typed: Collection[str]) -> SplatuError:
    """`err`, from a check of a new run's options together (flags and preset), told as the preset file's where it
    names an option whose value came from the file (its flag not among those `typed`, its value the file's): a check
    of two options (every-n's eval_every, with --eval-split typed) named the flag of the file's option, which was
    never typed. Only the error's subject counts: a typed flag's error whose fix names a file's option in passing
    stays the flag's. A range error is worded as the file's own are; any other keeps the check's own fix, with the
    file's keys for their flags: a flag replacing the file's value need not help (a file's eval_every beside a typed
    --eval-split contiguous is refused at any value, as a typed --eval-every would be)."""
    values = readable_preset_values(config.preset)
    if not values:  # the full recipe, or a Python caller's preset file gone since: the check's error as it is
        return err
    mine = flat_options(to_dict(config))
    kept = {name: value for name, value in values.items() if mine.get(name) == value and option_flag(name) not in typed}
    keys = _keys_named(kept, (err.what,))  # not a fix's mention in passing: "decay over the run's --steps"
    if not keys:
        return err
    path = preset_path(config.preset)
    if isinstance(err, OptionError) and [err.flag] == [option_flag(key) for key in keys]:
        return _blamed_on_file(err, path, kept)
    return SplatuError(_as_keys(err.what, keys), f"in {path}", _as_keys(err.fix, keys))


def _keys_named(keys: Collection[str], texts: Sequence[str]) -> list[str]:
    """The keys whose flags an error names, in the order it names them, from the first of `texts` (what, where, fix)
    that names any: a fix may mention another option in passing (the means' decay "over the run's --steps"), and a
    check of two options (degree_choice's held_out and at) names both, either of which may be the wrong one."""
    for text in texts:
        found = sorted((match.start(), key) for key in keys
                       if (match := re.search(re.escape(option_flag(key)) + r"(?![\w-])", text)) is not None)
        if found:
            return [key for _, key in found]
    return []


def option_value(config: Any, name: str) -> Any:
    """The value of dotted option `name` (`densify.refine_every`) in `config`."""
    for part in name.split("."):
        config = getattr(config, part)
    return config


def splatfacto_schedule(steps: int) -> dict[str, int]:
    """The `SCHEDULE` settings of the splatfacto recipe scaled to a run of `steps`: each × steps / 30000, rounded,
    never below one step (an interval of 0 steps cannot run: the checks refuse it). Every preset follows it."""
    scale = steps / SPLATFACTO_STEPS
    recipe = TrainConfig()
    return {name: max(1, round(option_value(recipe, name) * scale)) for name in SCHEDULE}


def own_length(values: Mapping[str, Any]) -> int | None:
    """The length a preset file's `values` scale their schedule from: its steps, the full recipe's when it sets none;
    None when its steps is no length (a typed --steps replaced it unchecked), so no rule can tell its schedule."""
    own = values.get("steps", SPLATFACTO_STEPS)
    return own if type(own) is int and own >= 1 else None


def file_schedule(values: Mapping[str, Any]) -> dict[str, int]:
    """The `SCHEDULE` settings a preset file's `values` leave out, scaled to the file's own steps by
    `splatfacto_schedule`: a file starts from the full 30000-step recipe, whose schedule a `steps: 300` alone left
    at warmup 500 and refine every 100, so it never densified. None without a length of its own (no steps, or one
    that is no length), whose schedule stays the recipe's."""
    flat = flat_options(values)
    if "steps" not in flat or (own := own_length(flat)) is None:
        return {}
    return {name: value for name, value in splatfacto_schedule(own).items() if name not in flat}


def scaled_schedule(preset: str, steps: int, kept: Collection[str] = ()) -> dict[str, int] | None:
    """The settings `--steps steps` rescales in `preset`, with their values: None at the preset's own length (no
    rescale applies); else every `SCHEDULE` setting whose flag is not in `kept` (the flags typed) and whose preset
    value follows `splatfacto_schedule` at the preset's length (a preset file's own choice off that rule stays, as a
    flag does); none for a preset file whose own steps is no length (which the typed --steps replaces)."""
    values = preset_values(preset)
    own = own_length(values)
    if own is None:
        return {}
    if own == steps:
        return None
    rule, scaled, recipe = splatfacto_schedule(own), splatfacto_schedule(steps), splatfacto_schedule(SPLATFACTO_STEPS)
    return {name: scaled[name] for name in SCHEDULE  # a setting the file leaves out has the recipe's value
            if option_flag(name) not in kept and values.get(name, recipe[name]) == rule[name]}


def preset_config(preset: str = DEFAULT_PRESET, method: str = "splatu", overridden: Collection[str] = (),
                  steps: int | None = None) -> TrainConfig:
    """The config a bare `splatu train --preset P --method M` starts from (the Python entry point); the preset's
    values for the flags in `overridden` are left out, so that a flag can replace a value the preset has wrong.
    With `steps`, that of `--steps steps` for a new run (`rescaled`, the settings whose flags are in `overridden`
    kept)."""
    config = TrainConfig()
    if preset != FULL_RECIPE:
        config = _with_preset(config, preset_path(preset), overridden)
    config = get_method(method).configure(dataclasses.replace(config, preset=preset, method=method))
    return config if steps is None else rescaled(config, steps, overridden)


def rescaled(config: TrainConfig, steps: int, kept: Collection[str] = ()) -> TrainConfig:
    """`config` as `--steps steps` makes it for a new run: that length, and the schedule `scaled_schedule` rescales
    (the settings whose flags are in `kept` keep their values)."""
    scaled = scaled_schedule(config.preset, steps, kept) or {}
    return apply_values(config, {"steps": steps, **nested_options(scaled)}, f"--steps {steps}")


def preset_values(preset: str, as_written: bool = False) -> dict[str, Any]:
    """The options preset `preset`'s file sets, by dotted name: as the file writes them, with the schedule it leaves
    out scaled to its steps (`file_schedule`) unless `as_written`; none for the full recipe."""
    if preset == FULL_RECIPE:
        return {}
    values = read_yaml(preset_path(preset))
    return flat_options(values) | ({} if as_written else file_schedule(values))


def readable_preset_values(preset: str, as_written: bool = False) -> dict[str, Any] | None:
    """`preset_values`, or None when the preset cannot be read: a config built in Python names its preset only as
    where its values came from, and the file may be gone (a relative path from another folder), which a new run,
    whose values are all in the config, never needed."""
    try:
        return preset_values(preset, as_written)
    except SplatuError:
        return None


def flags_off_preset(config: TrainConfig) -> set[str]:
    """The flags a command line would have typed to give `config`, told by value, for a caller without one (Python
    code calling `train`; the command line's own are `flags_given`): one per option off what a bare `--preset P`
    gives (the file's values, else the defaults, with the schedule `--steps N` rescales at the config's length), and
    --steps at another length than the preset's. A flag that repeats that value cannot be told from it; none is
    told from a preset file gone since the config was made (a new run does not need it: its values are in `config`)."""
    values = readable_preset_values(config.preset)
    if values is None:
        return set()
    scaled = scaled_schedule(config.preset, config.steps) or {}
    chosen = {"preset": config.preset, "method": config.method}  # they choose the bare config, as its flags do
    bare = flat_options(to_dict(TrainConfig())) | values | scaled | chosen
    return {option_flag(name) for name, value in flat_options(to_dict(config)).items() if bare.get(name) != value}


def _scan_flag(argv: Sequence[str], flag: str) -> str | None:
    """The value of `--flag V` or `--flag=V` in raw arguments (last one wins), before tyro parses them."""
    found = None
    for i, arg in enumerate(argv):
        if arg == flag and i + 1 < len(argv):
            found = argv[i + 1]
        elif arg.startswith(flag + "="):
            found = arg.split("=", 1)[1]
    return found


def flags_given(argv: Sequence[str]) -> set[str]:
    """The flags in raw arguments, spelt as `option_flag` spells them (`--no-progress` and `--model.sh_degree` as
    --progress and --model.sh-degree)."""
    given = set()
    for arg in argv:
        if arg.startswith("--"):
            parent, dot, last = arg[2:].split("=", 1)[0].replace("_", "-").rpartition(".")
            given.add(f"--{parent}{dot}{last.removeprefix('no-')}")
    return given


def _new_run_steps(argv: Sequence[str], typed: Collection[str]) -> int | None:
    """The `--steps` typed for a new run, which rescales the schedule; None without it, beside --resume (which keeps
    the run's saved options) or when it is no whole number of at least 1 (which tyro or the option checks refuse)."""
    value = _scan_flag(argv, "--steps")
    if value is None or "--resume" in typed:
        return None
    try:
        steps = int(value)
    except ValueError:
        return None
    return steps if steps >= 1 else None


def default_config(argv: Sequence[str]) -> TrainConfig:
    """Defaults for `splatu train`: the chosen preset and method, and the schedule a typed --steps rescales, so
    `--help` shows the real values. There each flag's default is the value the run takes without that flag: the
    preset's for a typed flag (a run leaves its preset value out for the flag to replace; shown, it read as the full
    recipe's; the recipe's for a typed flag that replaces a value the preset has wrong), and for a schedule setting,
    the one a typed --steps rescales it to, typed or not."""
    typed = flags_given(argv)
    preset, method = _scan_flag(argv, "--preset"), _scan_flag(argv, "--method")
    preset = DEFAULT_PRESET if preset is None else preset  # an empty `--preset=` is refused, as the name it is
    method = "splatu" if method is None else method
    steps = _new_run_steps(argv, typed)
    if "-h" not in argv and "--help" not in argv:
        return preset_config(preset, method, typed, steps)
    try:
        config = preset_config(preset, method)
    except SplatuError:  # a preset value refused, which a typed flag may replace: without it the run is refused
        config = preset_config(preset, method, typed)
    return config if steps is None else dataclasses.replace(rescaled(config, steps), steps=config.steps)
