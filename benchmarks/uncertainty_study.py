"""The uncertainty study (issue 6): ours against ensemble-10 and baselines, with ablations.

    .venv/bin/python benchmarks/uncertainty_study.py --quick             # tiny budgets, minutes
    .venv/bin/python benchmarks/uncertainty_study.py                     # the `fast` preset, hours
    .venv/bin/python benchmarks/uncertainty_study.py --preset quality    # the `quality` preset, longer
    ... --ours-timings 3    # time ours three times, take the median (the ensemble's wall already sums ten)

Scenes: the built-in poster stand-in (contiguous eval block) and fox (../shared/data/fox,
contiguous eval block; skipped with a message when absent). Every training goes through the
trainer's Python API (`splatu.trainer.train_run` / `splatu.ensemble_training.train_ensemble`) on one
loaded scene, with one budget for all (a preset, or tiny overrides of `fast` with --quick), so wall times compare.

Rows: ours (antipodal, mean, weighted losses), ensemble-N (plain 3DGS members differing only
in seed), visibility count, Fisher diagonal, colour spread, training residual, angular gap and random, all on
the ours (antipodal) Gaussians, which the uncertainty loss never moves, so only the uncertainty differs; and
ours-weighted OR colour spread, ours-weighted OR training residual (OR angular gap; the residual also read from
each view's direction). ours-antipodal trains alone (the
cost of one run of ours); ours-mean, ours-weighted and the ablations (every scene: λ and u-SH degree on
the weighted loss, the supervision threshold on the antipodal loss, which has one) are
uncertainty heads of ONE more training.
Every AUSE sits beside the random baseline and the oracle on the same images; the caption
states grid, normalisation and aggregation. Writes benchmarks/results/uncertainty_study.{md,json} (the
`fast` budget; uncertainty_study_<budget>.* for the others) and the curve plots next to them. A scene not run
this time keeps its earlier entry, stamped with when and on which CPU it was measured. The speed-against-error
figure of a scene puts every budget measured for it on one plot, a marker per budget.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
import tyro

from splatu import ause as A
from splatu import ensemble_training, trainer
from splatu.baselines import METHODS_WITH_OURS, UncertaintyMethod
from splatu.baselines.load import build_method, load_any_run
from splatu.config_values import apply_values
from splatu.data.config import DataConfig
from splatu.data.poster import PosterConfig
from splatu.data.resolve import load_scene
from splatu.data.scene import Scene
from splatu.errors import SplatuError
from splatu.eval_ause import score_entries
from splatu.figures import SpeedPoint, plot_sparsification, plot_speed_against_error
from splatu.losses import psnr
from splatu.provenance import measured_on
from splatu.render_uncertainty import RenderUncertaintyConfig, map_entries, render_views, view_spec
from splatu.train_config import TrainConfig, preset_config

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("SPLATU_SHARED_DATA", REPO.parent / "shared" / "data"))


@dataclass(frozen=True)
class Budget:
    """One training budget for every run of a study, so times and errors compare."""

    name: str
    preset: str
    overrides: dict[str, Any]
    """Values applied over the preset (nested dicts for nested configs)."""
    poster: PosterConfig
    fox_downscale: int
    lams: tuple[float, ...]
    thresholds: tuple[float, ...]
    u_degrees: tuple[int, ...]


QUICK = Budget(
    name="quick", preset="fast",
    # the splatfacto scaling breaks down this short (refine every step), so the quick schedule keeps the
    # tiny end-to-end test's proportions: refine every 10 steps, split until 2/3 of the run.
    overrides={"steps": 60, "resolution_interval": 20,
               "model": {"sh_degree_interval": 15, "random_init_points": 2500, "u_sh_degree": 1},
               "densify": {"warmup_length": 10, "refine_every": 10, "stop_split_at": 40,
                           "stop_screen_size_at": 20, "max_gaussians": 2500}},
    poster=PosterConfig(width=48, height=80, frames=24, eval_block=5, interp_every=6, points=2000),
    fox_downscale=16, lams=(0.1,), thresholds=(0.2,), u_degrees=(0, 3))
# u-SH degree 1 in every budget: the default when this study was first run (its ablation is why the default is
# now 3); kept so that a method's rows compare across budgets
FAST = Budget(name="fast", preset="fast", overrides={"model": {"u_sh_degree": 1}}, poster=PosterConfig(),
              fox_downscale=8, lams=(0.05, 0.1, 0.2, 0.4, 0.45), thresholds=(0.01, 0.02, 0.1, 0.2),
              u_degrees=(0, 2, 3))
QUALITY = dataclasses.replace(FAST, name="quality", preset="quality")
BUDGETS = {b.name: b for b in (QUICK, FAST, QUALITY)}


@dataclass
class Args:
    quick: bool = False
    """Tiny budgets (a small stand-in, 60 steps): the whole study in minutes."""
    preset: Literal["fast", "quality"] = "fast"
    """Without --quick: the training preset every run of the study uses."""
    scenes: list[str] = field(default_factory=lambda: ["poster", "fox"])
    """poster (built-in stand-in) and/or fox (../shared/data/fox)."""
    ensemble_size: int = 10
    """Members of the ensemble baseline (the paper uses 10)."""
    ablations: bool = True
    """Also learn the λ, threshold and u-SH-degree ablations, as extra heads of the one heads training."""
    ours_timings: int = 1
    """Train ours-antipodal this many times (the extra ones into scratch folders) and take the median wall as its
    train time: one training is one sample of a shared machine's noise, where ensemble-N's wall already sums N."""
    output_dir: Path = Path("outputs/uncertainty_study")
    """Where the study's training runs go; finished runs found there are reused, not retrained."""
    results: Path = REPO / "benchmarks" / "results"
    """Where uncertainty_study[_<budget>].md, .json and the plots are written."""


@dataclass(frozen=True)
class Variant:
    """One training of the study: a name, a config change, and whether it is an ensemble."""

    name: str
    change: Callable[[TrainConfig], TrainConfig]
    ensemble: bool = False


def _uncertainty(**changes: Any) -> Callable[[TrainConfig], TrainConfig]:
    return lambda c: dataclasses.replace(c, uncertainty=dataclasses.replace(c.uncertainty, **changes))


def variants(ensemble_size: int, heads: Variant) -> list[Variant]:
    """ours (antipodal) alone, timed as the cost of ours; one training with every other head; the ensemble."""
    ensemble = Variant(f"ensemble-{ensemble_size}",
                       lambda c: dataclasses.replace(c, method="ensemble", ensemble=ensemble_size,
                                                     uncertainty=dataclasses.replace(c.uncertainty, off=True)),
                       ensemble=True)
    return [Variant("ours-antipodal", _uncertainty(kind="antipodal")), heads, ensemble]


def head_rows(budget: Budget, default_degree: int, ablations: bool) -> tuple[Variant, dict[str, str | None]]:
    """ONE training whose uncertainty heads give the ours-mean and ours-weighted rows and, with `ablations`, every
    ablation; and row name → head (None: the run's own head, the weighted loss at the highest degree).

    L_u never moves the geometry, so each head is the u_sh a separate run would learn (tests/unit/test_trainer.py
    checks this), on the same Gaussians as ours-antipodal. λ and the degree vary the weighted loss at the
    default degree; the threshold varies the paper's antipodal loss, since the weighted loss has none.
    """
    degrees = sorted({*budget.u_degrees, default_degree}) if ablations else [default_degree]
    top = max(degrees)

    def spec(degree: int, extra: str = "") -> str | None:
        return None if degree == top and not extra else f"{extra}degree={degree}"

    rows: dict[str, str | None] = {"ours-mean": spec(default_degree, "kind=mean,"),
                                   "ours-weighted": spec(default_degree)}
    if ablations:
        rows |= {f"ablation-u-degree-{d}": spec(d) for d in degrees}
        rows |= {f"ablation-lam-{v}": spec(default_degree, f"lam={v},") for v in budget.lams}
        rows |= {f"ablation-threshold-{v}-antipodal": spec(default_degree, f"kind=antipodal,threshold={v},")
                 for v in budget.thresholds}
    heads = tuple(dict.fromkeys(h for h in rows.values() if h is not None))  # a row may repeat another's head
    # the settings are in the folder's name, so a study with other settings never reuses this training
    digest = hashlib.sha1(repr((top, heads)).encode()).hexdigest()[:8]
    run = Variant(f"heads-{digest}", lambda c: dataclasses.replace(
        c, model=dataclasses.replace(c.model, u_sh_degree=top),
        uncertainty=dataclasses.replace(c.uncertainty, kind="weighted", extra_heads=heads)))
    return run, rows


def base_config(budget: Budget, data: DataConfig) -> TrainConfig:
    """The budget's preset with its overrides, on `data`, without checkpoints or progress bars."""
    config = apply_values(preset_config(budget.preset), budget.overrides, f"the {budget.name} study budget")
    return dataclasses.replace(config, data=data, progress=False, checkpoint_every=0, eval_every_steps=0,
                               preset=f"study-{budget.name}")


def data_config(scene: str, budget: Budget) -> DataConfig | None:
    if scene == "poster":
        return DataConfig(data="poster", poster=budget.poster)
    path = SHARED_DATA / scene
    if not path.is_dir():
        print(f"skipping {scene}: {path} not found (../shared/data is absent on this machine)")
        return None
    return DataConfig(data=str(path), eval_split="contiguous", downscale=budget.fox_downscale)


def train_variant(variant: Variant, config: TrainConfig, scene: Scene, run_dir: Path) -> float:
    """Train (or reuse) one variant; returns its wall seconds, measured here around the trainer call (or by the
    invocation that trained it: `trained_before` says which)."""
    timing = run_dir / "study_wall_seconds.json"
    if timing.is_file():
        return float(json.loads(timing.read_text())["wall_seconds"])
    config = variant.change(config)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "study_wall_repeats.json").unlink(missing_ok=True)  # timings of an earlier training of it
    started = time.perf_counter()
    if variant.ensemble:
        ensemble_training.train_ensemble(config, scene, run_dir, started)
    else:
        trainer.train_run(config, scene, run_dir)
    wall = time.perf_counter() - started
    timing.write_text(json.dumps({"wall_seconds": wall}))
    return wall


def repeat_timings(variant: Variant, config: TrainConfig, scene: Scene, run_dir: Path, count: int) -> list[float]:
    """Wall seconds of `count` more trainings of `variant`, each into a scratch folder; recorded in
    run_dir/study_wall_repeats.json after each, so a rerun (or one stopped half-way) reuses them."""
    record = run_dir / "study_wall_repeats.json"
    walls = json.loads(record.read_text())["wall_seconds"] if record.is_file() else []
    while len(walls) < count:
        with tempfile.TemporaryDirectory() as scratch:
            walls.append(train_variant(variant, config, scene, Path(scratch) / variant.name))
        record.write_text(json.dumps({"wall_seconds": walls}))
    return walls[:count]


def warm_up_kernels(config: TrainConfig, scene: Scene, scratch: Path) -> float:
    """Compile the rasterizer's kernels, untimed, before any timed training; returns its wall seconds.

    torch.compile caches per process, and the first render at each resolution level compiles: without
    this, whichever training comes first pays ~10-30 s that the others do not, which skews the wall ratios.
    A few steps per resolution level, then the final evaluation (the no-grad path), compile everything.
    """
    levels = config.resolution_levels + 1
    short = dataclasses.replace(config, steps=2 * levels, resolution_interval=2)
    started = time.perf_counter()
    trainer.train_run(short, scene, scratch)
    return time.perf_counter() - started


def score(run_dir: Path, method: UncertaintyMethod, scene: Scene, head: str | None = None) -> dict[str, Any]:
    """Render the eval block with `method` (and uncertainty `head`), score it, and time the render."""
    run = load_any_run(run_dir, head)
    built = build_method(method, run, scene)
    spec = view_spec(scene, "eval", RenderUncertaintyConfig(load=run_dir))
    views, seconds = render_views(built.source, spec)
    report, curves = score_entries(map_entries(views), "mae")
    psnrs = [psnr(torch.from_numpy(np.clip(v.maps["rgb"], 0.0, 1.0)), torch.from_numpy(v.gt)) for v in views]
    return {"mean": report["mean"], "per_image": report["per_image"], "curve": curves["uncertainty"],
            "setup_seconds": built.setup_seconds, "render_seconds_per_view": float(np.median(seconds)),
            "psnr": float(np.mean(psnrs))}


BASELINES_ON_OURS: tuple[UncertaintyMethod, ...] = ("visibility", "fisher", "spread", "residual", "angle", "random")


def study_scene(scene_name: str, data: DataConfig, args: Args, budget: Budget) -> dict[str, Any]:
    """Train every variant on one scene and score every method row on its eval block."""
    started = time.perf_counter()
    scene = load_scene(data)
    width, height = scene.train.cameras[0].width, scene.train.cameras[0].height
    print(f"{scene_name}: {len(scene.train)} train / {len(scene.eval)} eval views, {width}x{height}, "
          f"loaded in {time.perf_counter() - started:.1f} s")
    config = base_config(budget, data)
    root = args.output_dir / budget.name / scene_name
    rows: dict[str, dict[str, Any]] = {}
    heads_run, rows_of_heads = head_rows(budget, config.model.u_sh_degree, args.ablations)
    to_train = variants(args.ensemble_size, heads_run)
    warm_up = None
    reused = [v.name for v in to_train if (root / v.name / "study_wall_seconds.json").is_file()]
    if config.compile_kernels:  # also when every training is reused: the scoring renders then run compiled too
        with tempfile.TemporaryDirectory() as scratch:
            warm_up = warm_up_kernels(config, scene, Path(scratch))
        print(f"  compiled the rasterizer kernels in an untimed warm-up training: {warm_up:.1f} s")
    timings: dict[str, list[float]] = {}
    for variant in to_train:
        wall = train_variant(variant, config, scene, root / variant.name)
        if variant.name == "ours-antipodal" and args.ours_timings > 1:
            timings[variant.name] = [wall, *repeat_timings(variant, config, scene, root / variant.name,
                                                           args.ours_timings - 1)]
            wall = float(np.median(timings[variant.name]))
        method: UncertaintyMethod = "ensemble" if variant.ensemble else "ours"
        heads = rows_of_heads if variant is heads_run else {variant.name: None}
        for name, head in heads.items():
            row = score(root / variant.name, method, scene, head)
            rows[name] = {**row, "train_seconds": wall, "method": method, "head": head}
            print(f"  {name}: AUSE-MAE {row['mean']['ause_mae']:.3f} (random {row['mean']['random_ause_mae']:.3f})"
                  f", PSNR {row['psnr']:.2f}, train {wall:.0f} s")
    for method in BASELINES_ON_OURS:
        row = score(root / "ours-antipodal", method, scene)
        rows[method] = {**row, "train_seconds": rows["ours-antipodal"]["train_seconds"] + row["setup_seconds"],
                        "method": method}
        print(f"  {method}: AUSE-MAE {row['mean']['ause_mae']:.3f}")
    # ours OR colour spread, ours OR training residual (OR angular gap), on the default head and every u-SH degree's
    seen_heads: set[str | None] = set()
    for name in ["ours-weighted", *sorted(n for n in rows_of_heads if n.startswith("ablation-u-degree-"))]:
        if rows_of_heads[name] in seen_heads:
            continue
        seen_heads.add(rows_of_heads[name])
        for method in ("ours-spread", "ours-residual", "ours-residual-angle", "ours-view-residual-angle"):
            row = score(root / heads_run.name, method, scene, rows_of_heads[name])
            extra_seconds = row["setup_seconds"]  # the spread has none; the residual and angle passes are timed
            suffix = method.removeprefix("ours-")
            rows[f"{name}-{suffix}"] = {**row, "train_seconds": rows[name]["train_seconds"] + extra_seconds,
                                        "method": method, "head": rows_of_heads[name]}
            print(f"  {name}-{suffix}: AUSE-MAE {row['mean']['ause_mae']:.3f}")
    return {"rows": rows, "kernel_warm_up_seconds": warm_up, "measured": measured_on(), "trained_before": reused,
            "timings": timings,
            "views": {"train": len(scene.train), "eval": len(scene.eval)},
            "size": [scene.train.cameras[0].width, scene.train.cameras[0].height]}


def targets(scene_name: str, rows: dict[str, dict[str, Any]], ensemble: str) -> list[tuple[str, float, str, bool]]:
    """The issue's numbers, measured: (what, value, target, reached)."""
    ours = rows["ours-antipodal"]
    family = {n: r for n, r in rows.items() if r["method"] in METHODS_WITH_OURS}  # ablations included
    best_name = min(family, key=lambda n: family[n]["mean"]["ause_mae"])
    best = family[best_name]
    result = []
    for name, row in (("ours (antipodal)", ours), (f"best ours ({best_name})", best)):
        ratio = row["mean"]["ause_mae"] / row["mean"]["random_ause_mae"]
        result.append((f"{name} AUSE-MAE ÷ random", ratio, "≤ 0.5", ratio <= 0.5))
    if ensemble in rows:
        ratio = best["mean"]["ause_mae"] / max(rows[ensemble]["mean"]["ause_mae"], 1e-12)
        result.append((f"best ours ({best_name}) AUSE-MAE ÷ {ensemble}", ratio, "≤ 1.0", ratio <= 1.0))
        wall = rows[ensemble]["train_seconds"] / ours["train_seconds"]
        result.append((f"{ensemble} wall ÷ ours (antipodal) wall", wall, "≥ 9", wall >= 9.0))
    for name, row in (("ours (antipodal)", ours), (f"best ours ({best_name})", best)):
        auroc = row["mean"]["auroc_unobserved"]
        if auroc is not None:  # one variant must meet every target, so the best one is checked here too
            result.append((f"{name} AUROC-unobserved", auroc, "≥ 0.85", auroc >= 0.85))
    return [(f"{scene_name}: {what}", value, target, ok) for what, value, target, ok in result]


def _cell(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"


def markdown(results: dict[str, Any], budget: Budget) -> str:
    lines = [f"# Uncertainty study (budget `{budget.name}`)", "",
             "Each scene says the command that measured it, when and on which CPU. The machines are shared: times "
             "are noisy, compare ratios within one scene's table.",
             f"Budget `{budget.name}`: the `{budget.preset}` preset with {budget.overrides or 'no changes'}.", "",
             f"AUSE caption: {A.CAPTION}; per-pixel error summed over RGB; random = mean over "
             f"{len(A.RANDOM_SEEDS)} seeds of uniform noise on the same images; oracle = AUSC-MAE, the area under "
             "the oracle curve (its AUSE is 0 by construction); "
             "start-norm = curves divided by O(0) instead of the joint max (exposes anti-correlation). "
             "train wall s (the JSON's train_seconds): the wall time of each training, timed around the trainer call "
             "the same way for every method (not summary.json's train_seconds, the time inside steps). "
             "visibility / Fisher / spread / residual / angle / random use the ours (antipodal) model; their train "
             "time adds their post-training cost (the *-residual rows: the residual pass over the training views; "
             "*-angle: also the pass that records which training views saw each Gaussian). "
             "PSNR: mean over eval images (ensemble: the members' mean render). "
             "ours-mean, ours-weighted and the ablation rows are uncertainty heads of ONE training (its wall time "
             "in each of those rows; ours-antipodal, trained alone, is what one run of ours costs): L_u never "
             "moves the geometry, so each head is what a separate run with that setting would learn, on the same "
             "Gaussians as ours-antipodal.", ""]
    all_targets = []
    for scene_name, scene in results["scenes"].items():
        rows = scene["rows"]
        measured = scene.get("measured") or {}
        stamp = (f"Measured {measured.get('date', 'before measurements were stamped')} on "
                 f"{measured.get('cpu', 'an unrecorded CPU')} by `{measured.get('command', 'an earlier version')}`.")
        if measured.get("note"):
            stamp += f" {measured['note']}"
        if scene.get("trained_before"):
            stamp += (f" Trainings reused from an earlier invocation in the same output folder (their times are "
                      f"that invocation's): {', '.join(scene['trained_before'])}.")
        lines += [f"## {scene_name} ({scene['size'][0]}x{scene['size'][1]}, {scene['views']['train']} train / "
                  f"{scene['views']['eval']} eval views, contiguous eval block)", "", stamp, "",
                  "| method | AUSE-MAE | AUSE-RMSE | random AUSE-MAE | oracle AUSC-MAE | AUSE-MAE start-norm "
                  "(random) | AUROC-unobserved | PSNR dB | train wall s | render s/view |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for name, row in rows.items():
            m = row["mean"]
            lines.append(f"| {name} | {_cell(m['ause_mae'])} | {_cell(m['ause_rmse'])} | "
                         f"{_cell(m['random_ause_mae'])} | {_cell(m['oracle_ausc_mae'])} | "
                         f"{_cell(m['ause_mae_start_norm'])} ({_cell(m['random_ause_mae_start_norm'])}) | "
                         f"{_cell(m['auroc_unobserved'])} | {row['psnr']:.2f} | {row['train_seconds']:.0f} | "
                         f"{row['render_seconds_per_view']:.2f} |")
        warm_up = scene.get("kernel_warm_up_seconds")
        if warm_up is not None:
            lines += ["", f"An untimed warm-up training compiled the rasterizer kernels ({warm_up:.0f} s) before the "
                      "trainings timed in the same invocation, so none of them pays the compile."]
        for name, walls in (scene.get("timings") or {}).items():
            lines += ["", f"{name}'s train time is the median of {len(walls)} trainings of it ("
                      f"{', '.join(f'{w:.0f}' for w in walls)} s; the first is the scored run, the others only timed)."]
        lines += ["", f"Curves: `{results_stem(budget.name)}_{scene_name}_curves.png`; speed against error, every "
                  f"budget: `uncertainty_study_{scene_name}_speed.png`.", ""]
        ensemble = next((n for n in rows if n.startswith("ensemble-")), "ensemble")
        all_targets += targets(scene_name, rows, ensemble) if "ours-antipodal" in rows else []
    lines += ["## Targets (issue 6)", "", "| figure | measured | target | reached |", "|---|---|---|---|"]
    lines += [f"| {what} | {value:.3f} | {target} | {'yes' if ok else 'no'} |"
              for what, value, target, ok in all_targets]
    return "\n".join(lines) + "\n"


def results_stem(budget: str) -> str:
    return "uncertainty_study" if budget == FAST.name else f"uncertainty_study_{budget}"


def speed_points(rows: dict[str, dict[str, Any]]) -> dict[str, SpeedPoint]:
    """Every non-ablation row as a point; the baselines on ours' Gaussians share its PSNR, so they get none."""
    return {n: SpeedPoint(r["train_seconds"], r["mean"]["ause_mae"] / r["mean"]["random_ause_mae"],
                          None if n in BASELINES_ON_OURS else r["psnr"])
            for n, r in rows.items() if not n.startswith("ablation-")}


def plots(results: dict[str, Any], out_dir: Path) -> None:
    """Curves of the scenes run now; the speed figure of every scene with every budget measured for it."""
    budgets = {name: json.loads(path.read_text())["scenes"] for name in BUDGETS
               if (path := out_dir / f"{results_stem(name)}.json").is_file()}
    budgets[results["budget"]["name"]] = results["scenes"]
    for scene_name, scene in results["scenes"].items():
        rows = scene["rows"]
        if all("curve" in r for r in rows.values()):  # a scene kept from an earlier invocation has no curves
            main = {n: r["curve"] for n, r in rows.items() if not n.startswith("ablation-")}
            plot_sparsification(out_dir / f"{results_stem(results['budget']['name'])}_{scene_name}_curves.png", main,
                                f"{scene_name}: {A.CAPTION}, curves / O(0)", "mae")
        measured = {b: scenes[scene_name] for b in BUDGETS if scene_name in (scenes := budgets.get(b, {}))}
        stamps = "; ".join(f"{b}: {s['size'][0]}x{s['size'][1]}, {(s.get('measured') or {}).get('date', 'unstamped')}"
                           for b, s in measured.items())
        plot_speed_against_error(out_dir / f"uncertainty_study_{scene_name}_speed.png",
                                 {b: speed_points(s["rows"]) for b, s in measured.items()},
                                 f"{scene_name}: training wall time (baselines: ours + their own cost) vs error; "
                                 "each budget "
                                 f"scores its own eval images ({stamps})")


def write_results(results: dict[str, Any], args: Args, budget: Budget) -> None:
    """JSON (curves left out) and the markdown table, then the plots; called after every scene, so a plotting
    failure never loses a scene's hours of training."""
    args.results.mkdir(parents=True, exist_ok=True)
    plain = {**results, "scenes": {name: {**scene, "rows": {n: {k: v for k, v in r.items() if k != "curve"}
                                                            for n, r in scene["rows"].items()}}
                                   for name, scene in results["scenes"].items()}}
    stem = results_stem(budget.name)
    (args.results / f"{stem}.json").write_text(json.dumps(plain, indent=2, default=str))
    (args.results / f"{stem}.md").write_text(markdown(results, budget))
    plots(results, args.results)


def earlier_scenes(path: Path, budget: Budget) -> dict[str, Any]:
    """The scenes an earlier invocation of this budget measured, kept beside the ones run now."""
    if not path.is_file():
        return {}
    earlier = json.loads(path.read_text())
    settings = json.loads(json.dumps(dataclasses.asdict(budget), default=str))  # as the file stores them
    if earlier.get("budget") != settings:
        raise SplatuError(f"{path} holds a study with other {budget.name} settings", "in the results folder",
                          "move it aside (or pass --results DIR) before running this budget")
    return earlier["scenes"]


def main(args: Args) -> None:
    if args.quick and args.preset != "fast":
        raise SplatuError("--quick is a tiny budget over the `fast` preset", "in the study's options",
                          "drop --preset, or drop --quick")
    if args.ours_timings < 1:
        raise SplatuError(f"--ours-timings is {args.ours_timings}", "in the study's options", "pass 1 or more")
    budget = QUICK if args.quick else BUDGETS[args.preset]
    command = " ".join(["python benchmarks/uncertainty_study.py", *sys.argv[1:]])
    stem = results_stem(budget.name)
    results: dict[str, Any] = {"budget": dataclasses.asdict(budget), "caption": A.CAPTION,
                               "scenes": earlier_scenes(args.results / f"{stem}.json", budget)}
    for scene_name in args.scenes:
        data = data_config(scene_name, budget)
        if data is not None:
            scene = study_scene(scene_name, data, args, budget)
            scene["measured"]["command"] = command
            results["scenes"][scene_name] = scene
            write_results(results, args, budget)
    if not results["scenes"]:
        sys.exit("error: no scene was studied, in --scenes, pass poster and/or a scene present in ../shared/data")
    print((args.results / f"{stem}.md").read_text())


if __name__ == "__main__":
    try:
        main(tyro.cli(Args))
    except SplatuError as err:  # a bad option or results folder: one line, as every splatu command prints it
        sys.exit(f"error: {err}")
