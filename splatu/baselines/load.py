"""Build any uncertainty method from a run directory (a single run or an ensemble run)."""

from __future__ import annotations

import dataclasses
import shlex
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from rich.progress import Progress

from splatu.baselines import (
    METHODS_FOR_PLAIN_RUNS,
    METHODS_FROM_TRAINING_IMAGES,
    METHODS_FROM_TRAINING_VIEWS,
    METHODS_WITH_OURS,
    UncertaintyMethod,
    UncertaintySource,
    method_list,
)
from splatu.baselines.angle import AngleSource, view_coverage
from splatu.baselines.ensemble import EnsembleSource, read_ensemble
from splatu.baselines.fisher import fisher_diagonal, fisher_feature
from splatu.baselines.model_sources import FeatureSource, OursSource, RandomSource, SpreadSource
from splatu.baselines.residual import ResidualSource, mean_residuals, training_residuals, view_residual_sums
from splatu.baselines.visibility import visibility_counts, visibility_feature
from splatu.checkpoint import checkpoint_step, load_run, resolve_checkpoint, unfinished_members
from splatu.data.config import DataConfig
from splatu.data.resolve import load_camera_scene, load_scene
from splatu.data.scene import CameraScene, Scene, Views
from splatu.errors import SplatuError
from splatu.json_files import is_finite_number, read_json
from splatu.model import GaussianModel
from splatu.train_config import TrainConfig, eval_background
from splatu.train_progress import view_pass, view_progress
from splatu.world_frame import WorldTransform, require_same_frame, scene_frame


@dataclass
class LoadedRun:
    """A run's config and its model(s): one, or every member of an ensemble."""

    run_dir: Path
    config: TrainConfig
    models: list[GaussianModel]
    train_seconds: float | None
    """Time inside training steps, summary.json's train_seconds (an ensemble: the sum of its members'), the one
    measure of cost that ours and the ensemble are compared on; None for a run or ensemble not finished. Without
    the kernels' compiles, unless `train_compile_seconds` is None for a finished run (saved before they were timed
    apart, its train_seconds includes them)."""
    frames: list[WorldTransform | None]
    """Per model, the frame (scene normalisation) it was trained in; None in older checkpoints."""
    member_steps: tuple[int, ...] | None = None
    """An ensemble that is not whole now (`unfinished_members`): the step of each member's checkpoint loaded, which
    names what is made of it; None for a finished ensemble and a single run."""
    wall_seconds: float | None = None
    """Wall time of the training, scene loading and evaluations included: summary.json's wall_seconds (an ensemble:
    ensemble.json's, every session that trained a member); None when `train_seconds` is."""
    train_compile_seconds: float | None = None
    """The part of the steps' time spent compiling the rasterizer's kernels, summary.json's train_compile_seconds
    (an ensemble: its members' summed); None when `train_seconds` is, or a run (a member) recorded none."""


@dataclass
class BuiltMethod:
    source: UncertaintySource
    setup_seconds: float
    """Post-training cost of the method (visibility counting, Fisher accumulation); 0 for the others."""


SUMMARY_SECONDS = ("train_seconds", "train_compile_seconds", "wall_seconds")
"""summary.json's times, in the order `_summary_seconds` returns them."""


def _summary_seconds(run_dir: Path) -> tuple[float | None, float | None, float | None]:
    """summary.json's SUMMARY_SECONDS, None for each it lacks: all for a run not finished, the compile time for one
    saved before it was recorded."""
    path = run_dir / "summary.json"
    if not path.is_file():
        return None, None, None
    summary = read_json(path)
    for key in SUMMARY_SECONDS:
        if summary.get(key) is not None and not is_finite_number(summary[key]):
            raise SplatuError(f"{key} is {summary[key]!r}, not a number", f"in {path}", "fix or regenerate the file")
    return summary.get("train_seconds"), summary.get("train_compile_seconds"), summary.get("wall_seconds")


def _ensemble_seconds(record_wall: float | None,
                      members: list[Path]) -> tuple[float | None, float | None, float | None]:
    """An ensemble's time in steps and its compile time, each the sum of its members' (each summary.json's, as a
    single run reports its own), and its wall time from ensemble.json; all None unless every member has its time
    in steps. The compile time is None unless every member has one, and then the time in steps includes every
    member's compiles, as a single run's does (a member with none counted its compiles in its steps)."""
    seconds = [_summary_seconds(member)[:2] for member in members]
    if any(train is None for train, _ in seconds):
        return None, None, None
    train = sum(train for train, _ in seconds)
    compiles = [compiling for _, compiling in seconds]
    if None in compiles:
        return train + sum(c for c in compiles if c is not None), None, record_wall
    return train, sum(compiles), record_wall


def load_any_run(run_dir: Path, head: str | None = None) -> LoadedRun:
    """A single run via `load_run` (with one of its extra uncertainty heads when `head` is given), or every
    member listed in an ensemble run's ensemble.json."""
    run_dir = Path(run_dir)
    if (run_dir / "ensemble.json").is_file():
        if head is not None:
            raise SplatuError("--head needs a single run, this is an ensemble", f"in {run_dir}", "drop --head")
        record = read_ensemble(run_dir)
        for member in record.members:
            if not member.is_dir():
                raise SplatuError("an ensemble member that ensemble.json lists is missing", f"at {member}",
                                  f"train it again with `splatu train --resume {shlex.quote(str(run_dir))}` "
                                  "(trained members are kept)")
        unfinished = unfinished_members(run_dir)  # asked first: a member finishing meanwhile is then loaded final
        checkpoints = [resolve_checkpoint(member) for member in record.members]
        loaded = [load_run(checkpoint) for checkpoint in checkpoints]
        steps = tuple(map(checkpoint_step, checkpoints)) if unfinished else None
        # an ensemble not whole now is made of partly intermediate models: no finished ensemble's cost, as a single
        # run's checkpoint pinned before its end reports none
        train, compiling, wall = ((None, None, None) if unfinished
                                  else _ensemble_seconds(record.wall_seconds, record.members))
        return LoadedRun(run_dir, loaded[0].config, [m.model for m in loaded], train, [m.frame for m in loaded],
                         steps, wall, compiling)
    if (run_dir / "members").is_dir() and not (run_dir / "checkpoints").is_dir():
        raise SplatuError("this ensemble is unfinished (it has members but no ensemble.json yet)", f"in {run_dir}",
                          f"finish it with `splatu train --resume {shlex.quote(str(run_dir))}`")
    config, model, frame = load_run(run_dir, head)
    train, compiling, wall = _summary_seconds(run_dir)
    return LoadedRun(run_dir, config, [model], train, [frame], wall_seconds=wall, train_compile_seconds=compiling)


def run_data(run: LoadedRun, data: str | None = None) -> DataConfig:
    """The scene options the run was trained with (split, downscale, …); `data` replaces only where the scene is."""
    if data is not None:
        return dataclasses.replace(run.config.data, data=data)
    recorded = run.config.data
    if recorded.data != "poster" and not Path(recorded.data).expanduser().exists():
        raise SplatuError(f"the scene this run was trained on no longer exists ({recorded.data})",
                          f"in {run.run_dir}", "pass --data PATH with the scene's new location "
                          "(the run's recorded split and downscale still apply)")
    return recorded


def method_scene(method: UncertaintyMethod, data: DataConfig, ground_truth: bool = False) -> Scene | CameraScene:
    """The scene as `method` needs it: a `Scene` with its images decoded for the residuals, which compare renders with
    them, or when the views rendered need their `ground_truth`; else a `CameraScene`, its training cameras alone
    (with the mask files that visibility, fisher and angle honour), which decodes no image."""
    if ground_truth or method in METHODS_FROM_TRAINING_IMAGES:
        return load_scene(data)
    return load_camera_scene(data, masks=method in METHODS_FROM_TRAINING_VIEWS)


def check_frames(run: LoadedRun, scene: Scene | CameraScene) -> None:
    """Refuse to render a run on a scene normalised differently from the one it was trained on, e.g. a
    `poster` run of the stand-in once the real capture is present: every map would be silently wrong."""
    trained_on = run.config.data.data
    fix = ("pass --data with the scene it was trained on" if trained_on != "poster" else
           "pass --data with the poster it was trained on (the built-in stand-in or the real capture, "
           "whichever `poster` found then; the stand-in is in the splatu cache)")
    for frame in run.frames:
        require_same_frame(frame, scene_frame(scene), f"in {run.run_dir}", fix)


def check_method(method: UncertaintyMethod, run: LoadedRun, typed: bool = True) -> None:
    """Refuse a method the run cannot provide, before any scene is loaded; one not `typed` (the run's own, as no
    --method chose it) is said to be the default, so a splatfacto run's user learns which to type instead."""
    if method != "ensemble" and len(run.models) > 1:
        raise SplatuError(f"--method {method} needs a single run, this is an ensemble", f"in {run.run_dir}",
                          "pass one member (members/<k>), or drop --method for the ensemble's std (its default)")
    if method == "ensemble" and len(run.models) < 2:
        raise SplatuError("--method ensemble needs an ensemble run (with ensemble.json)", f"in {run.run_dir}",
                          "train one with `splatu train --method ensemble --ensemble 10`")
    if method in METHODS_WITH_OURS and run.config.uncertainty.off:
        chosen = f"--method {method} needs" if typed else f"without --method a single run renders {method}, which needs"
        raise SplatuError(f"{chosen} a run trained with the uncertainty loss; this one had it off", f"in {run.run_dir}",
                          f"pass one of --method {method_list(METHODS_FOR_PLAIN_RUNS)}, which render a run trained "
                          "without it, or train with `splatu train --method splatu`")


def build_method(method: UncertaintyMethod, run: LoadedRun, scene: Scene | CameraScene | None,
                 density_aware: bool = False, fisher_probes: int = 2, seed: int = 0) -> BuiltMethod:
    """The renderer of `method` for this run; visibility, Fisher, residual and angle look at the scene's training
    views first (their setup_seconds, which render.json records: a pass over every training view, so a bar counts
    them on a terminal), the residuals at their images too (a `Scene`; the others take a `CameraScene`). `scene` may
    be None for the other methods, which render the model alone; the caller then checks the frame its cameras are
    in."""
    check_method(method, run)
    if scene is not None:
        check_frames(run, scene)
    if scene is None and method in METHODS_FROM_TRAINING_VIEWS:
        raise ValueError(f"method {method!r} needs the scene's training views")
    if not isinstance(scene, Scene) and method in METHODS_FROM_TRAINING_IMAGES:
        raise ValueError(f"method {method!r} needs the scene's training images")
    started = time.perf_counter()
    with view_progress(enabled=method in METHODS_FROM_TRAINING_VIEWS) as bar:
        source = _source(method, run, scene, bar, density_aware, fisher_probes, seed)
    return BuiltMethod(source, time.perf_counter() - started)


def _source(method: UncertaintyMethod, run: LoadedRun, scene: Scene | CameraScene | None, bar: Progress,
            density_aware: bool, fisher_probes: int, seed: int) -> UncertaintySource:
    """`build_method`'s renderer, each pass over the training views counted on `bar`."""
    degree = run.config.model.sh_degree
    background = eval_background(run.config)
    model = run.models[0]
    threshold = run.config.uncertainty.threshold
    if method == "ours":
        return OursSource(model, degree, background)
    if method == "ensemble":
        return EnsembleSource(run.models, degree, background, density_aware)
    if method == "random":
        return RandomSource(model, degree, background, seed)
    if method in ("spread", "ours-spread"):
        return SpreadSource(model, degree, background, with_ours=method == "ours-spread")
    if method not in METHODS_FROM_TRAINING_VIEWS:
        raise SplatuError(f"unknown uncertainty method {method!r}", "in --method", f"use {method_list()}")
    assert scene is not None  # build_method refused it
    train = scene.train
    count = len(train.cameras)
    if method == "visibility":
        counts = visibility_counts(model, train.cameras, threshold, train.mask_files,
                                   view_pass(bar, "visibility", count))
        return FeatureSource(model, degree, background, visibility_feature(counts))
    if method == "fisher":
        information = fisher_diagonal(model, train.cameras, degree, fisher_probes, torch.Generator().manual_seed(seed),
                                      view_pass(bar, "fisher information", count))
        return FeatureSource(model, degree, background, fisher_feature(information))
    if method == "angle":
        return AngleSource(model, degree, background, view_coverage(model, train.cameras, threshold, train.mask_files,
                                                                    view_pass(bar, "view coverage", count)))
    assert isinstance(train, Views)  # the residual methods: build_method refused a CameraScene
    if method == "ours-view-residual-angle":
        directional = view_residual_sums(model, train, degree, background,
                                         view_pass(bar, "training residuals", count))
        residuals = mean_residuals(directional)
    else:
        directional = None
        residuals = training_residuals(model, train, degree, background,
                                       view_pass(bar, "training residuals", count))
    coverage = (view_coverage(model, train.cameras, threshold, train.mask_files,
                              view_pass(bar, "view coverage", count))
                if method.endswith("-angle") else None)
    return ResidualSource(model, degree, background, residuals, with_ours=method != "residual", coverage=coverage,
                          directional=directional)
