"""Checkpoints: atomic writes, exact-resume state, and `load_run` for rendering and evaluation.

A checkpoint is written to a temporary file in the same directory and moved into place with
os.replace, so a crash mid-write leaves the previous checkpoint untouched. It holds the model,
the optimizer and density-controller state, the step, every RNG state and the config, which is
what an exact resume needs. Only the newest few are kept (`--keep-checkpoints`): a 3DGS checkpoint with
Adam moments is tens of MB.
"""

from __future__ import annotations

import dataclasses
import random
import re
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from splatu.atomic import atomic_write
from splatu.config_values import changed_options
from splatu.errors import SplatuError, a_few
from splatu.losses import parse_head, uncertainty_heads
from splatu.model import GaussianModel, head_coefficients
from splatu.run_dir import LATEST, still_training
from splatu.train_config import DISPLAY_OPTIONS, TrainConfig, from_dict, load_config, option_value
from splatu.world_frame import WorldTransform

CHECKPOINT_DIR = "checkpoints"
CHECKPOINT_NAME = re.compile(r"step-(\d+)\.pt")
"""What the trainer names its checkpoints (checkpoint_path); nothing else in the folder is one."""
FORMAT = "splatu-checkpoint-v1"
MODEL_KEYS = ("step", "config", "model", "num_gaussians")
"""What rendering and evaluation read from a checkpoint."""
RESUME_KEYS = (*MODEL_KEYS, "optimizers", "density", "rng", "scene_extent", "nonfinite_streak", "train_seconds")
"""What `--resume` needs of what the trainer writes (trainer._checkpoint_state); `world_transform` and
`uncertainty_rng` are read when present (older checkpoints lack them)."""


def checkpoint_path(run_dir: Path, step: int) -> Path:
    return run_dir / CHECKPOINT_DIR / f"step-{step:07d}.pt"


def save_checkpoint(run_dir: Path, step: int, state: dict[str, Any], keep: int = 2) -> Path:
    """Write the checkpoint for `step` (completed steps) atomically, then delete all but the newest `keep`."""
    path = checkpoint_path(run_dir, step)
    atomic_write(path, lambda f: torch.save({"format": FORMAT, "step": step, **state}, f))
    for old in list_checkpoints(run_dir)[:-keep]:
        old.unlink(missing_ok=True)
    return path


def checkpoint_step(path: Path) -> int:
    """The step a checkpoint file was written at, from its name (step-0001000.pt → 1000)."""
    return int(path.stem.removeprefix("step-"))


def list_checkpoints(run_dir: Path) -> list[Path]:
    """Checkpoints of a run, oldest first. Only names the trainer writes count: a user's copy such as
    "step-0000200 (copy).pt" is neither resumed from nor pruned."""
    found = [path for path in (run_dir / CHECKPOINT_DIR).glob("step-*.pt")
             if CHECKPOINT_NAME.fullmatch(path.name) and path.is_file()]
    return sorted(found, key=checkpoint_step)


def resolve_checkpoint(run_dir_or_checkpoint: Path) -> Path:
    """The checkpoint file named, or the newest one of a run directory."""
    target = Path(run_dir_or_checkpoint).expanduser()
    if target.is_file():
        return target
    if not target.is_dir():
        raise SplatuError("run directory or checkpoint not found", f"at {target}",
                          "pass a run directory (outputs/<scene>/<method>/<timestamp>) or a .pt checkpoint")
    if (target / "ensemble.json").is_file():
        raise SplatuError("this is an ensemble run; it has one model per member", f"in {target}",
                          "load each run listed in its ensemble.json")
    if not (target / CHECKPOINT_DIR).is_dir() and not (target / "config.yml").is_file():  # a run saves its config first
        raise SplatuError(f"not a splatu run (it has no {CHECKPOINT_DIR}/ folder or config.yml)", f"in {target}",
                          _instead_of_no_run(target))
    found = list_checkpoints(target)
    if not found:
        raise SplatuError("no checkpoint in this run directory", f"in {target / CHECKPOINT_DIR}",
                          "train it first (splatu train) or point to a run that saved checkpoints")
    return found[-1]


def _instead_of_no_run(folder: Path) -> str:
    """The fix for a folder passed as a run that is none: the run its checkpoints/ folder belongs to, the newest run
    of a method's folder, or a few runs beneath a folder above them (outputs/, a scene's), found by their `latest`
    links, else by their config.yml, at most three levels down (outputs/<scene>/<method>/<timestamp>)."""
    if folder.name == CHECKPOINT_DIR and (folder.parent / "config.yml").is_file():
        return f"pass its run, {folder.parent}, or one of the .pt files in this folder"
    newest = folder / LATEST
    if newest.is_dir():
        return f"pass {newest}, the newest run in it, or one of its timestamped runs"
    runs = sorted(link for pattern in ("*/latest", "*/*/latest") for link in folder.glob(pattern) if link.is_dir())
    if not runs:
        runs = sorted(path.parent for pattern in ("*/config.yml", "*/*/config.yml", "*/*/*/config.yml")
                      for path in folder.glob(pattern))
    if runs:
        return f"pass a run beneath it, such as {a_few(runs)}"
    return "pass a run directory (outputs/<scene>/<method>/<timestamp>) or a .pt checkpoint"


def pinned_unless_finished(load: Path) -> tuple[Path, str | None]:
    """What `--load` names, and a note when that is not a finished model. A run folder that a `splatu train` is
    training now, or that was stopped before its end (it has no summary.json, which a run writes last), is pinned to
    its newest checkpoint file, as if that file had been passed: what renders or scores it is named after that
    checkpoint (`ours-step-0001000`), never taken for the finished run's, and set aside with it by a resume from an
    earlier one. An ensemble is pinned while `unfinished_members` says so: its members keep their own newest
    checkpoints, and what is written is named after their steps (`UncertaintyOptions.label`)."""
    target = Path(load).expanduser()
    if target.is_file():
        return Path(load), None
    if (target / "ensemble.json").is_file():
        if not unfinished_members(target):
            return Path(load), None
        return Path(load), (f"{load} has members still training or left unfinished; their newest checkpoints so far "
                            "are the models used")
    training = still_training(target)
    if not training and (target / "summary.json").is_file():
        return Path(load), None
    if (target / "members").is_dir() and not (target / CHECKPOINT_DIR).is_dir():  # as load_any_run tells them apart
        if not training:
            return Path(load), None  # load_any_run says how to finish it
        raise SplatuError("this ensemble is still training: it has no ensemble.json until its last member finishes",
                          f"in {target}", "wait for its `splatu train` to finish, or load one finished member "
                          "(members/<k>)")
    pinned = resolve_checkpoint(target)
    if training:
        return pinned, f"{load} is still training; its newest checkpoint so far, {pinned.name}, is the model used"
    return pinned, (f"{load} is unfinished (stopped before its last step; `splatu train --resume` finishes it); its "
                    f"newest checkpoint, {pinned.name}, is the model used")


def unfinished_members(ensemble_dir: Path) -> bool:
    """Whether an ensemble that finished once (it has ensemble.json) is not whole now: a member has no summary.json
    (a `--resume` of it from an earlier checkpoint set it aside, and a resume of the ensemble retrains it) or a
    `splatu train` holds a member's lock (the ensemble's resume, or one of the member folder itself). Its members'
    newest checkpoints are then partly intermediate models, not the finished ensemble's."""
    members = [path for path in (Path(ensemble_dir) / "members").glob("*") if path.is_dir()]
    return any(not (member / "summary.json").is_file() or still_training(member) for member in members)


def run_folder(run_dir_or_checkpoint: Path) -> Path:
    """The run directory of a `--load` value, which may name the run or one of its checkpoint files: where
    renders and reports of it are written."""
    path = Path(run_dir_or_checkpoint).expanduser()
    return run_dir_of(path) if path.is_file() else path


def run_dir_of(checkpoint: Path) -> Path:
    """The run directory a checkpoint file belongs to."""
    parent = checkpoint.resolve().parent
    return parent.parent if parent.name == CHECKPOINT_DIR else parent


def run_holding(checkpoint: Path) -> Path | None:
    """The run a checkpoint file is inside, which a `--resume` of it trains on in, or None for a file inside none (a
    copy in ~/Downloads, or one set aside in a run's abandoned/): a run is a folder holding config.yml, which a run
    writes before anything else, and its checkpoints lie in its checkpoints/ folder or, put there by hand, in it."""
    folder = run_dir_of(checkpoint)
    return folder if (folder / "config.yml").is_file() else None


OLDER_CHECKPOINT = "use an older checkpoint of the run (its checkpoints/ folder), or retrain"


def read_checkpoint(path: Path, required: tuple[str, ...] = ("step",)) -> dict[str, Any]:
    """Load a checkpoint dict holding the `required` keys and a finite model, or raise a one-line error for a
    corrupt, foreign, incomplete or non-finite file. The dict also holds "read_from", the path, for later messages.

    Training never saves a non-finite model (it skips such steps), so NaN or Inf here is damage; caught now, a
    resume fails before it sets anything aside, and a render names the file rather than blaming the rasterizer."""
    not_ours = SplatuError("not a splatu checkpoint", f"in {path}", "pass a .pt checkpoint written by `splatu train`")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except MemoryError:
        raise
    except Exception as err:  # any junk (text, a truncated zip, a foreign pickle) raises its own type from torch
        if path.suffix != ".pt":
            raise not_ours from None
        raise SplatuError(f"corrupt or unreadable checkpoint ({type(err).__name__})", f"in {path}",
                          OLDER_CHECKPOINT) from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise not_ours
    missing = [key for key in required if key not in state]
    if missing:
        raise SplatuError(f"incomplete checkpoint (missing {', '.join(missing)})", f"in {path}", OLDER_CHECKPOINT)
    damaged = [key for key in ("config", "model", "world_transform") if not isinstance(state.get(key, {}), dict)]
    if damaged:
        raise SplatuError(f"damaged checkpoint ({', '.join(damaged)} is not a mapping)", f"in {path}",
                          OLDER_CHECKPOINT)
    for name, value in state.get("model", {}).items():
        if isinstance(value, torch.Tensor) and value.is_floating_point() and not bool(value.isfinite().all()):
            count = int((~value.isfinite()).sum())
            raise SplatuError(f"checkpoint has NaN or Inf in {name} ({count:,} of {value.numel():,} values)",
                              f"in {path}", OLDER_CHECKPOINT)
    return {**state, "read_from": str(path)}


def capture_rng(generator: torch.Generator) -> dict[str, Any]:
    """Every RNG state that training draws from, as tensors and plain values (weights_only-safe)."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    return {
        "torch": torch.get_rng_state(),
        "generator": generator.get_state(),
        "python": random.getstate(),
        "numpy": {"kind": kind, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                  "has_gauss": int(has_gauss), "cached": float(cached)},
    }


def restore_rng(state: dict[str, Any], generator: torch.Generator) -> None:
    torch.set_rng_state(state["torch"])
    generator.set_state(state["generator"])
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal), gauss))
    n = state["numpy"]
    np.random.set_state((n["kind"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached"]))


def model_from_state(state: dict[str, Any], config: TrainConfig) -> GaussianModel:
    model = GaussianModel.empty_like_config(int(state["num_gaussians"]), config.model,
                                            1 + len(config.uncertainty.extra_heads))
    try:
        model.load_state_dict(state["model"])
    except RuntimeError as err:  # shapes that do not match the saved config (e.g. another SH degree)
        first = str(err).strip().splitlines()[-1].strip()
        raise SplatuError(f"checkpoint model does not match its config ({first})",
                          f"in {state.get('read_from', 'the run checkpoint')}",
                          "retrain, or load the checkpoint with the config it was written with") from None
    return model


def saved_frame(state: dict[str, Any]) -> WorldTransform | None:
    """The frame the model was trained in (the scene's normalisation), or None in checkpoints older than it; a
    damaged one (NaN, a zero scale, a missing part) is a one-line error naming the file."""
    saved = state.get("world_transform")
    if saved is None:
        return None
    try:
        return WorldTransform.from_state(saved)
    except (KeyError, TypeError, ValueError, AttributeError, RuntimeError):  # WorldTransform refuses a bad frame
        raise SplatuError("checkpoint's world_transform (the scene's normalisation) is damaged",
                          f"in {state.get('read_from', 'the run checkpoint')}", OLDER_CHECKPOINT) from None


class TrainedRun(NamedTuple):
    """What rendering and evaluation need of a run: its config, its model and the frame it was trained in."""

    config: TrainConfig
    model: GaussianModel
    frame: WorldTransform | None


RUN_CHANGES = ("data.data", "steps", "optim.means_lr_steps", "model.sh_degree", "model.u_sh_degree", "uncertainty.",
               "degree_choice.", *DISPLAY_OPTIONS)
"""Options a run's own life changes, so that its checkpoints may differ from its config.yml there: the scene's move
(--data beside --resume), --extend-to, the mid-run degree choice, and what a resume shows (`DISPLAY_OPTIONS`)."""


def refuse_foreign_checkpoint(checkpoint: TrainConfig, run: TrainConfig, path: Path, run_dir: Path, flag: str) -> None:
    """Refuse a checkpoint copied in from another run: resuming it rewrote this run's config.yml and records with
    the other run's, and rendering or exporting it filed the other model's outputs under this run's name. Told by an
    option that no resume of this run could have changed."""
    foreign = [name for name in changed_options(checkpoint, run)
               if not any(name == key or name.startswith(key) for key in RUN_CHANGES)]
    if foreign:
        name = foreign[0]
        raise SplatuError(f"this checkpoint was not written by this run (its {name} is "
                          f"{option_value(checkpoint, name)!r}, the run's config.yml has {option_value(run, name)!r})",
                          f"in {path}",
                          f"pass the run it came from, or {run_dir} or one of its own checkpoints, to {flag}")


def load_run(run_dir: Path, head: str | None = None) -> TrainedRun:
    """A run's config, trained model (its newest checkpoint) and frame, for rendering and evaluation; with
    `head`, as if the run had trained only that extra uncertainty head (see `select_head`)."""
    path = resolve_checkpoint(Path(run_dir))  # an ensemble run is refused there
    state = read_checkpoint(path, MODEL_KEYS)
    config = from_dict(state["config"], str(run_dir))
    saved = run_dir_of(path) / "config.yml"
    if saved.is_file():
        refuse_foreign_checkpoint(config, load_config(saved), path, run_dir_of(path), "--load")
    model = model_from_state(state, config)
    if head is not None:
        config, model = select_head(config, model, head, run_dir)
    return TrainedRun(config, model, saved_frame(state))


def select_head(config: TrainConfig, model: GaussianModel, head: str, run_dir: Path) -> tuple[TrainConfig,
                                                                                                 GaussianModel]:
    """The config and model of a run that trained only extra head `head`: the same Gaussians, u_sh = that
    head's channel at its degree, and the head's loss settings in the config."""
    heads = uncertainty_heads(config.uncertainty, config.model.u_sh_degree)
    settings = [(h.loss, h.degree) for h in heads[1:]]
    try:  # by settings, not by spelling: "degree=1,lam=0.1" finds the head trained as "lam=0.1,degree=1"
        wanted = parse_head(head, config.uncertainty, config.model.u_sh_degree)
        channel = settings.index((wanted.loss, wanted.degree)) + 1
    except (SplatuError, ValueError):
        names = ", ".join(repr(h.name) for h in heads[1:])
        raise SplatuError(f"no uncertainty head {head!r} in this run", f"in {run_dir}",
                          f"pass --head with one of: {names}" if names
                          else "drop --head: this run trained no extra heads") from None
    chosen = heads[channel]
    model_cfg = dataclasses.replace(config.model, u_sh_degree=chosen.degree)
    u_sh = head_coefficients(model.u_sh.detach(), channel, chosen.degree)
    selected = GaussianModel(model.means.detach(), model.quats.detach(), model.log_scales.detach(),
                             model.opacity_logits.detach(), model.sh_dc.detach(), model.sh_rest.detach(), u_sh,
                             model_cfg)
    return dataclasses.replace(config, model=model_cfg, uncertainty=chosen.loss), selected
