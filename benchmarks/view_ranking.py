"""How well each uncertainty ranks whole views by their error: the question a next-view planner asks.

    .venv/bin/python benchmarks/view_ranking.py --load outputs/poster/splatu/latest

AUSE ranks pixels within a view; a planner ranks candidate views. Over every held-out view of the run's scene (its
eval split and extra sets: poster's unseen block and its every-8th path frames), each method's mean U over the view
is set against the view's error, the mean over the pixels AUSE scores of the error it uses (absolute error summed
over RGB; a masked scene's object pixels only; unobserved pixels included: a planner wants to look where the model
is wrong). Spearman's ρ across the views says how well ranking views by mean U ranks them by error (1: the same
order; 0 for noise). ρ within each set says more than ρ over all: the unseen block's views are far worse than the
path frames', which any coverage measure sees. "First pick" is the view with the highest mean U, and its error's
rank among the views (1: the worst view). Each method renders on the run's own Gaussians (`render-uncertainty
--method M`), so its time is its setup plus its renders. Prints a table and writes benchmarks/results/view_ranking.json.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tyro

from splatu import ause as A
from splatu.baselines import UncertaintySource
from splatu.baselines.load import build_method, load_any_run, run_data
from splatu.data.resolve import load_scene
from splatu.data.scene import Scene
from splatu.maps import file_stems
from splatu.provenance import measured_on
from splatu.render_uncertainty import RenderedView, ViewSpec, render_views

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


@dataclass
class Args:
    load: Path = Path("outputs/poster/splatu/latest")
    """A trained run with the uncertainty loss on (ours needs it)."""
    methods: tuple[str, ...] = ("ours", "angle", "visibility", "spread", "ours-view-residual-angle", "random")
    """Uncertainty methods of `render-uncertainty --method` to compare."""
    json: Path = RESULTS / "view_ranking.json"


def ranks(values: np.ndarray) -> np.ndarray:
    """Ranks from 1 (smallest), ties given their mean rank, as Spearman's ρ needs."""
    order = np.argsort(values, kind="stable")
    ranked = np.empty(len(values))
    ranked[order] = np.arange(1, len(values) + 1)
    for value in np.unique(values):
        tied = values == value
        ranked[tied] = ranked[tied].mean()
    return ranked


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation; 0 when either has a single value throughout (no order to agree with)."""
    ra, rb = ranks(a) - (len(a) + 1) / 2, ranks(b) - (len(b) + 1) / 2
    scale = float(np.sqrt((ra**2).sum() * (rb**2).sum()))
    return float((ra * rb).sum() / scale) if scale > 0 else 0.0


def first_pick_rank(mean_uncertainty: np.ndarray, error: np.ndarray) -> int:
    """The error rank (1: the worst view) of the view with the highest mean U."""
    pick = int(np.argmax(mean_uncertainty))
    return int((error > error[pick]).sum()) + 1


def view_error(view: RenderedView) -> float | None:
    """The view's mean error over the pixels AUSE scores (its object mask's, when the scene has one: an RGBA
    image's alpha, its mask files); None when the mask leaves none, a view eval-ause leaves out too."""
    assert view.gt is not None  # held-out views have ground truth
    errors = A.pixel_errors(view.maps["rgb"], view.gt)
    if view.mask is not None:
        errors = errors[view.mask]
    return float(errors.mean()) if errors.size else None


def held_out_scores(source: UncertaintySource, scene: Scene) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Each held-out view's name, mean U (over the whole view: what a planner ranks by) and mean error."""
    names, mean_u, error = [], [], []
    for set_name, views in {"eval": scene.eval, **scene.extra_eval}.items():
        spec = ViewSpec(views.cameras, file_stems(views.names), views, list(range(len(views))))
        rendered, _ = render_views(source, spec)
        for view in rendered:
            if (view_mean := view_error(view)) is not None:
                names.append(f"{set_name}/{view.name}")
                mean_u.append(float(view.maps["uncertainty"].mean()))
                error.append(view_mean)
    return names, np.array(mean_u), np.array(error)


def measure(args: Args) -> dict[str, Any]:
    run = load_any_run(args.load)
    scene = load_scene(run_data(run))
    rows = []
    for method in args.methods:
        started = time.perf_counter()
        built = build_method(method, run, scene)  # type: ignore[arg-type]
        names, mean_u, error = held_out_scores(built.source, scene)
        pick = int(np.argmax(mean_u))
        sets = {name.split("/", 1)[0] for name in names}
        within = {set_name: spearman(mean_u[mask], error[mask]) for set_name in sorted(sets)
                  if (mask := np.array([n.startswith(f"{set_name}/") for n in names])).sum() > 1}
        rows.append({"method": method, "spearman": spearman(mean_u, error), "spearman_within": within,
                     "views": len(names),
                     "first_pick": names[pick], "first_pick_error_rank": first_pick_rank(mean_u, error),
                     "seconds": time.perf_counter() - started,
                     "per_view": [{"name": n, "mean_uncertainty": u, "error": e}
                                  for n, u, e in zip(names, mean_u.tolist(), error.tolist(), strict=True)]})
    return {"run": str(args.load), "measured_on": measured_on(), "methods": rows}


def print_table(result: dict[str, Any]) -> None:
    sets = list(result["methods"][0]["spearman_within"])
    within = "".join(f" {'rho in ' + name:>14}" for name in sets)
    print(f"{'method':<26} {'rho, all':>9}{within} {'first pick (error rank)':>36} {'seconds':>8}")
    for row in result["methods"]:
        pick = f"{row['first_pick']} ({row['first_pick_error_rank']}/{row['views']})"
        values = "".join(f" {row['spearman_within'][name]:>14.3f}" for name in sets)
        print(f"{row['method']:<26} {row['spearman']:>9.3f}{values} {pick:>36} {row['seconds']:>8.1f}")


def main(args: Args) -> None:
    result = measure(args)
    print_table(result)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main(tyro.cli(Args))
