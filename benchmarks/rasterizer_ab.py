"""A/B of the rasterizer against an earlier commit, in one process: the ratio of render times.

    python benchmarks/rasterizer_ab.py --base COMMIT [--cases 20k 100k training] [--pairs 20] [--eager]
        [--run outputs/poster/splatu/latest]

These shared hosts drift between invocations of benchmarks/rasterizer.py by more than many changes are
worth (its 20k case read 85–100 ns per pair over three invocations in a row), so a change is measured
here instead: the base commit's `splatu` package is exported with `git archive`, renamed `splatu_base`
and imported beside the working tree's, and the two render the same scene alternately (forward +
backward of benchmarks/rasterizer.py's loss, after two warm-ups each; which of the two goes first
alternates from one pair to the next). Each pair of renders gives a ratio current / base; the median
and quartiles of those ratios are the result, for the whole render and for its footprint pass
(block_entries) alone, whose share of a render is too small for a change to it to stand out of the
render's noise. Before timing, the two are compared on one render: the largest differences of image
and gradients, and the pair counts. Prints a table and writes JSON, with every timing.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import re
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Literal

import torch
import tyro

from splatu.allocator import keep_freed_memory
from splatu.errors import SplatuError
from splatu.provenance import source_revision

REPO = Path(__file__).resolve().parents[1]
BASE_PACKAGE = "splatu_base"
CaseName = Literal["20k", "100k", "training"]


@dataclass
class AbConfig:
    base: str
    """The commit (or any git revision) to compare the working tree against."""
    cases: list[CaseName] = field(default_factory=lambda: ["20k", "100k", "training"])
    """benchmarks/rasterizer.py's two cases, and a training-sized render (18k Gaussians at 256×144)."""
    pairs: int = 20
    """Timed (base, current) render pairs per case."""
    run: Path | None = None
    """Also time a trained run's model (a run folder, e.g. outputs/poster/splatu/latest) at its training views, the
    pairs spread evenly over them, with the run's screen blur; its colours are those of the view direction, as a
    training step renders them. A trained scene's renders differ from the random scenes', and so can a change's
    effect."""
    eager: bool = False
    """Time the eager kernels instead of the compiled ones that the presets use."""
    json: Path = REPO / "benchmarks" / "results" / "rasterizer_ab.json"
    """Where to write the results."""


def rename_package(source: str) -> str:
    """Point a module's absolute imports of splatu at BASE_PACKAGE (only import statements are touched)."""
    return re.sub(r"^(\s*(?:from|import)\s+)splatu\b", rf"\g<1>{BASE_PACKAGE}", source, flags=re.MULTILINE)


def resolve_commit(revision: str) -> str:
    """The full hash of `revision`, or one clear line and exit if it names no commit of this repository."""
    found = subprocess.run(["git", "rev-parse", "--verify", "--quiet", "--end-of-options", f"{revision}^{{commit}}"],
                           cwd=REPO, capture_output=True, text=True, check=False)
    if found.returncode:
        raise SystemExit(f"error: {revision!r} is not a commit of the repository at {REPO}; "
                         "pass a commit hash, tag or branch to --base")
    return found.stdout.strip()


def export_base(commit: str, into: Path) -> None:
    """Write the package `splatu` of `commit` into `into`/splatu_base, its imports renamed."""
    archive = subprocess.run(["git", "archive", commit, "splatu"], cwd=REPO, capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive.stdout, check=True)
    (into / "splatu").rename(into / BASE_PACKAGE)
    for module in (into / BASE_PACKAGE).rglob("*.py"):
        module.write_text(rename_package(module.read_text()))


def load_rasterizer_benchmark() -> ModuleType:
    """benchmarks/rasterizer.py as a module, for its scenes and loss."""
    spec = importlib.util.spec_from_file_location("rasterizer_benchmark", REPO / "benchmarks" / "rasterizer.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses resolve annotations through it
    spec.loader.exec_module(module)
    return module


@dataclass
class View:
    """One render's inputs: the five Gaussian tensors and camera of a scene tuple, and the image size and options."""

    scene: tuple[torch.Tensor, ...]
    width: int
    height: int
    options: dict = field(default_factory=lambda: {"log_scales": True})


def render_step(rasterize: Callable, bench: ModuleType, view: View) -> tuple[torch.Tensor, list[torch.Tensor], int]:
    """One forward + backward: the image, the gradients of the five Gaussian inputs, the pair count."""
    leaves = [t.clone().requires_grad_(i < 5) for i, t in enumerate(view.scene)]
    out = rasterize(*leaves, view.width, view.height, **view.options)
    bench.loss_of(out.image, out.alpha).backward()
    return out.image.detach(), [leaf.grad for leaf in leaves[:5]], out.num_contributing_pairs


def case_views(name: str, bench: ModuleType) -> tuple[str, list[View]]:
    """A named case's name and its one view."""
    case = {"20k": bench.CASES[0], "100k": bench.CASES[1],
            "training": bench.Case("18k Gaussians at 256x144 (training-sized)", 18_000, 256, 144, seed=3)}[name]
    return case.name, [View(bench.make_scene(case), case.width, case.height)]


def trained_views(run: Path) -> tuple[str, list[View]]:
    """A trained run's model at each of its training views: colours evaluated for that view, the run's blur."""
    from splatu.checkpoint import load_run
    from splatu.data.resolve import load_scene

    trained = load_run(run)
    model, degree = trained.model, trained.config.model.sh_degree
    views = []
    with torch.no_grad():
        for camera in load_scene(trained.config.data).train.cameras:
            scene = (model.means, model.quats, model.log_scales, torch.sigmoid(model.opacity_logits),
                     model.colors(model.view_dirs(camera), degree), camera.world_to_camera, camera.K)
            options = {"log_scales": True, "near": camera.near, "far": camera.far, "blur": model.cfg.screen_blur,
                       "antialiased": model.cfg.antialiased}
            views.append(View(tuple(t.detach() for t in scene), camera.width, camera.height, options))
    return f"trained run: {len(model.means):,} Gaussians, {len(views)} views", views


def compare_case(name: str, views: list[View], base: ModuleType, current: ModuleType, bench: ModuleType,
                 pairs: int, footprint_seconds: dict[ModuleType, list[float]]) -> dict:
    """Check the two agree on the first view, then time `pairs` alternating renders of each, pair k at view
    k·len(views)/pairs (rounded down), so that the pairs spread evenly over the views.

    `footprint_seconds` holds, per package, the list its footprint passes append their times to.
    """
    for seconds in footprint_seconds.values():
        seconds.clear()
    (image_b, grads_b, pairs_b), (image_c, grads_c, pairs_c) = (
        render_step(r, bench, views[0]) for r in (base.rasterize, current.rasterize))
    if any(len(seconds) != 1 for seconds in footprint_seconds.values()):
        raise SystemExit("error: a render did not run exactly one footprint pass through "
                         "rasterizer.rasterize.block_entries, so footprint times cannot be paired with renders")
    if base.kernels.kernels_compiled() != current.kernels.kernels_compiled():
        raise SystemExit("error: torch.compile failed for one of the two packages only (see the warning above), "
                         "so their times are not comparable; rerun with --eager")
    for index in range(2):
        render_step(base.rasterize, bench, views[index % len(views)])
        render_step(current.rasterize, bench, views[index % len(views)])
    base_ms, current_ms = [], []
    for seconds in footprint_seconds.values():
        seconds.clear()
    for index in range(pairs):
        order = ((base.rasterize, base_ms), (current.rasterize, current_ms))
        for rasterize, times in order if index % 2 == 0 else order[::-1]:
            start = time.perf_counter()
            render_step(rasterize, bench, views[index * len(views) // pairs])
            times.append(1e3 * (time.perf_counter() - start))
    footprint_b, footprint_c = ([1e3 * t for t in footprint_seconds[p]] for p in (base, current))
    return {
        "name": name,
        "contributing_pairs": {"base": pairs_b, "current": pairs_c},
        "max_abs_image_difference": float((image_b - image_c).abs().max()),
        "max_abs_gradient_difference": max(float((b - c).abs().max()) for b, c in zip(grads_b, grads_c, strict=True)),
        **ratio_summary("", base_ms, current_ms),
        **ratio_summary("footprint_", footprint_b, footprint_c),
        "ms_base": [round(t, 1) for t in base_ms],
        "ms_current": [round(t, 1) for t in current_ms],
        "footprint_ms_base": [round(t, 1) for t in footprint_b],
        "footprint_ms_current": [round(t, 1) for t in footprint_c],
    }


def ratio_summary(prefix: str, base_ms: list[float], current_ms: list[float]) -> dict:
    """Median times of each side, and the median and quartiles of the per-pair ratios current / base."""
    ratios = [c / b for b, c in zip(base_ms, current_ms, strict=True)]
    quartiles = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else [ratios[0]] * 3
    return {
        f"{prefix}ms_base_median": round(statistics.median(base_ms), 1),
        f"{prefix}ms_current_median": round(statistics.median(current_ms), 1),
        f"{prefix}ratio_median": round(statistics.median(ratios), 3),
        f"{prefix}ratio_quartiles": [round(quartiles[0], 3), round(quartiles[2], 3)],
    }


def main(config: AbConfig) -> None:
    if config.pairs < 1:
        raise SystemExit("error: --pairs must be at least 1")
    commit = resolve_commit(config.base)
    keep_freed_memory()  # as in training and every splatu command
    bench = load_rasterizer_benchmark()
    with tempfile.TemporaryDirectory() as scratch:
        export_base(commit, Path(scratch))
        sys.path.insert(0, scratch)
        try:
            base = importlib.import_module(f"{BASE_PACKAGE}.rasterizer")
            current = importlib.import_module("splatu.rasterizer")
            for package in (base, current):
                importlib.import_module(f"{package.__name__}.kernels").set_compile(not config.eager)
            footprint_seconds = {base: bench.record_footprint_times(BASE_PACKAGE),
                                 current: bench.record_footprint_times()}
            cases = [case_views(name, bench) for name in config.cases]
            if config.run is not None:
                try:
                    cases.append(trained_views(config.run))
                except SplatuError as error:  # a missing or foreign run folder: one line, no traceback
                    raise SystemExit(f"error: {error}") from None
            results = [compare_case(name, views, base, current, bench, config.pairs, footprint_seconds)
                       for name, views in cases]
        finally:
            sys.path.remove(scratch)
    print(f"{'case':45s} {'base ms':>9s} {'current ms':>11s} {'current / base':>15s} {'quartiles':>14s}")
    for r in results:
        for label, prefix in ((r["name"], ""), ("  of which the footprint", "footprint_")):
            q = r[f"{prefix}ratio_quartiles"]
            print(f"{label:45s} {r[f'{prefix}ms_base_median']:9.1f} {r[f'{prefix}ms_current_median']:11.1f} "
                  f"{r[f'{prefix}ratio_median']:15.3f} {q[0]:6.3f}–{q[1]:.3f}")
        print(f"{'':45s} image differs by ≤ {r['max_abs_image_difference']:.2g}, gradients by ≤ "
              f"{r['max_abs_gradient_difference']:.2g}; pairs {r['contributing_pairs']}")
    report = {"base": commit, "current": source_revision(), "pairs": config.pairs,
              "kernels": "eager" if config.eager else "torch.compile", "threads": torch.get_num_threads(),
              "cases": results}
    config.json.parent.mkdir(parents=True, exist_ok=True)
    config.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"written to {config.json}")


if __name__ == "__main__":
    main(tyro.cli(AbConfig))
