"""`splatu eval-ause`: score uncertainty maps with sparsification curves, AUSE and AUROC.

Every method is scored through the same maps layout (`splatu.maps`): `--maps DIR` reads one
directly; `--load RUN` first renders the run's eval views into that layout with the chosen
`--method`, then scores it, so a run and a foreign tool's maps are judged identically.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import torch
import tyro
from rich.console import Console
from rich.table import Table

from splatu import ause as A
from splatu.atomic import atomic_write_text, file_identity, what_a_stop_left
from splatu.checkpoint import run_folder
from splatu.errors import FREE_AND_RERUN, SplatuError, creatable_dir, no_empty_folders_left
from splatu.interrupts import finish_first, saying_what_is_left
from splatu.losses import psnr
from splatu.maps import MapEntry, entry_names, read_entry
from splatu.uncertainty_options import DEFAULTS, OPTION_NAMES, UncertaintyOptions


def plot_sparsification(path: Path, curves: Mapping[str, A.Curves], title: str, metric: str) -> None:
    """figures.plot_sparsification, imported at the first plot: matplotlib takes most of a second to import, which
    `splatu eval-ause --help` does not need."""
    from splatu.figures import plot_sparsification as plot

    plot(path, curves, title, metric)


@dataclass
class EvalAuseConfig:
    """Options of `splatu eval-ause`."""

    load: Path | None = None
    """A training run directory, or one of its checkpoint files: render its eval views with --method, then score
    them. Without it or --maps: outputs/poster/splatu/latest, as for render-uncertainty and export."""
    uncertainty: Annotated[UncertaintyOptions, tyro.conf.OmitArgPrefixes] = field(default_factory=UncertaintyOptions)
    """With --load: what to render and score (a maps directory already holds its one uncertainty)."""
    maps: Path | None = None
    """A maps directory (rgb/NAME.png, gt/NAME.png, uncertainty/NAME.npy, optional mask/, unobserved/) to score."""
    metric: A.Metric = "mae"
    """Error leading the table and the curve plot; the JSON always has mae and rmse (and mse when chosen)."""
    per_image: bool = False
    """Also print a row per image (of --metric): the JSON always has them, as per_image."""
    output: Path | None = None
    """Where to write the JSON (default: ause_<label>.json in the run, the label being the method and the options
    that change its maps; or ause.json in the maps dir). With --load it also takes the maps it scores, as
    <output stem>-maps/ beside it, so that a run folder that cannot be written to can still be scored."""


RANDOM_CURVE = "random baseline"
"""The plot's name for the baseline's curve: `--method random` labels the method's own curve "random"."""


def render_psnr(entry: MapEntry) -> dict[str, float | None]:
    """PSNR of the render, clipped to [0, 1] as a stored map is, against the ground truth, on the scored pixels and on
    the observed ones (None where there are none). Each method's AUSE ranks its own render's error, so an
    ensemble's mean render, which is better than one model's, is ranked on smaller errors: the report gives each
    render's PSNR beside its AUSE."""
    rgb, gt = torch.from_numpy(entry.rgb).clamp(0.0, 1.0), torch.from_numpy(entry.gt)
    scored = torch.ones(rgb.shape[:2], dtype=torch.bool) if entry.mask is None else torch.from_numpy(
        np.asarray(entry.mask, dtype=bool))
    observed = None if entry.unobserved is None else scored & ~torch.from_numpy(np.asarray(entry.unobserved, bool))
    return {"psnr": psnr(rgb, gt, scored) if scored.any() else None,
            "psnr_observed": psnr(rgb, gt, observed) if observed is not None and observed.any() else None}


def score_entries(entries: list[MapEntry], metric: A.Metric) -> tuple[dict[str, Any], dict[str, A.Curves]]:
    """Per-image scores and the mean over images (PSNR too: the mean of each image's own), plus the mean curves for
    the plot."""
    metrics: tuple[A.Metric, ...] = tuple(dict.fromkeys(("mae", "rmse", metric)))
    scored = {e.name: A.score_image(e.rgb, e.gt, e.uncertainty, e.mask, e.unobserved, metrics) for e in entries}
    per_image = {e.name: scored[e.name][0] | render_psnr(e) for e in entries}
    ours = [A.start_normalised(curves[metric].ours) for _, curves in scored.values()]
    # every seed the table's random baseline averages, so the plotted curve is the reported one
    random = [A.start_normalised(c) for _, curves in scored.values() for c in curves[metric].random]
    mean_curves = {
        name: A.Curves(np.mean([c.oracle for c in curves], axis=0), np.mean([c.sparsification for c in curves], axis=0))
        for name, curves in (("uncertainty", ours), (RANDOM_CURVE, random))
    }
    report = {"mean": A.mean_scores(per_image), "per_image": per_image, "caption": A.CAPTION,
              "metric": metric, "images": len(entries)}
    return report, mean_curves


def evaluate_maps(maps_dir: Path, metric: A.Metric = "mae", label: str = "uncertainty",
                  output: Path | None = None, options: dict[str, Any] | None = None,
                  entries: list[MapEntry] | None = None, stand_in: bool | None = None) -> dict[str, Any]:
    """Score a maps directory, write the JSON and the curve plot beside it, and return the report; `options`
    (what rendered the maps) are recorded in it, and `stand_in` when the scene is known (`Scene.stand_in`: numbers
    of the built-in stand-in are not the real poster's). `entries` are its views when the caller already holds them
    as stored (write_maps_dir), so the directory is not read again."""
    if entries is None:
        entries = [read_entry(maps_dir, name) for name in entry_names(maps_dir)]
    report, curves = score_entries(entries, metric)
    report["method"] = label
    report["options"] = options or {"maps": str(maps_dir)}
    if stand_in is not None:
        report["stand_in"] = stand_in
    output = checked_output(output or maps_dir / "ause.json")
    curves = {label if name == "uncertainty" else name: c for name, c in curves.items()}
    # a full disk leaves no folder made for the two files; a stop between them would pair new scores with an old plot
    with no_empty_folders_left(output.parent), finish_first():
        plot_sparsification(output.with_suffix(".png"), curves, f"{label}: {A.CAPTION}, curves / O(0)", metric)
        atomic_write_text(output, json.dumps(report, indent=2), FREE_AND_RERUN)
    return report


def checked_output(output: Path) -> Path:
    """The JSON path, its folder created and proven writable, so a bad --output is one line and not a traceback.
    It must end in .json: the plot goes beside it with the suffix .png, and would overwrite a .png path."""
    if output.is_dir():
        raise SplatuError("--output is a folder, eval-ause writes a JSON file (and a .png beside it)", f"in {output}",
                          f"pass a file path such as {output / 'ause.json'}")
    if output.suffix != ".json":
        raise SplatuError("--output must name a .json file (the curve plot is written beside it as .png)",
                          f"in {output}", f"pass a path such as {output.with_suffix('.json')}")
    if output.with_suffix(".png").is_dir():
        raise SplatuError("the curve plot's path is a folder (eval-ause writes the plot beside the JSON, as .png)",
                          f"in {output.with_suffix('.png')}", "move that folder, or pass another --output")
    creatable_dir(output.parent, "--output (a .json path in a writable folder)")
    return output


def maps_beside(output: Path) -> Path:
    """Where `--load --output X.json` puts the maps it scores: X-maps/ beside the JSON. The render replaces that
    folder whole, so a folder of that name that eval-ause did not write (no timing.json) is refused, not deleted."""
    root = output.with_name(f"{output.stem}-maps")
    if root.exists() and not (root / "timing.json").is_file():
        raise SplatuError("the folder eval-ause would write the scored maps to exists and holds something else",
                          f"in {root}", "move it, or pass another --output")
    return root


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.4f}"


def _ratio(ours: float | None, random: float | None) -> str:
    """Ours ÷ random, as the README's results quote AUSE: the fraction of random's that ours keeps."""
    return "n/a" if ours is None or random is None or random <= 0 else f"{ours / random:.2f}"


def _print_wide(table: Table) -> None:
    """As wide as the table needs: fitted to a log file's assumed 80 columns, or to a narrow terminal, rich would
    cut scores to "0.05…" or drop whole columns; a terminal wraps a long line instead, losing nothing."""
    console = Console()
    needed = console.measure(table, options=console.options.update_width(1 << 12)).maximum
    Console(width=max(console.width, needed)).print(table)


def print_report(report: dict[str, Any], metric: A.Metric, per_image: bool = False) -> None:
    """The mean over images of every error metric in the report (`metric` first), ours beside random and their
    ratio, then the AUROC; with `per_image` first a row per image, of `metric` alone, to keep it narrow. The title
    names the built-in stand-in when the scores are of it."""
    mean = report["mean"]
    ratio = "/" if Console().options.ascii_only else "÷"  # an ASCII-only stream (PYTHONIOENCODING) cannot print ÷
    scene = " on the built-in poster stand-in" if report.get("stand_in") else ""
    if per_image:
        table = Table(title=f"AUSE-{metric.upper()} of {report['method']}{scene}, per image")
        for header in ("image", "AUSE", "random", f"{ratio} random", "AUSE start-norm", "AUROC unobserved"):
            table.add_column(header, justify="left" if header == "image" else "right", overflow="fold")
        for name, scores in report["per_image"].items():
            table.add_row(name, _fmt(scores[f"ause_{metric}"]), _fmt(scores[f"random_ause_{metric}"]),
                          _ratio(scores[f"ause_{metric}"], scores[f"random_ause_{metric}"]),
                          _fmt(scores[f"ause_{metric}_start_norm"]), _fmt(scores["auroc_unobserved"]))
        _print_wide(table)
    metrics = [m for m in dict.fromkeys((metric, "mae", "rmse", "mse")) if f"ause_{m}" in mean]
    table = Table(title=f"AUSE of {report['method']}{scene}, mean over {len(report['per_image'])} images",
                  caption=report["caption"])
    for header in ("error", "AUSE", "random", f"{ratio} random", "AUSE start-norm", "random start-norm", "AUSC",
                   "random AUSC", "oracle AUSC"):
        table.add_column(header, justify="left" if header == "error" else "right")
    for m in metrics:
        table.add_row(m.upper(), _fmt(mean[f"ause_{m}"]), _fmt(mean[f"random_ause_{m}"]),
                      _ratio(mean[f"ause_{m}"], mean[f"random_ause_{m}"]), _fmt(mean[f"ause_{m}_start_norm"]),
                      _fmt(mean[f"random_ause_{m}_start_norm"]), _fmt(mean[f"ausc_{m}"]),
                      _fmt(mean[f"random_ausc_{m}"]), _fmt(mean[f"oracle_ausc_{m}"]))
    _print_wide(table)
    if mean["auroc_unobserved"] is not None:
        Console().print(f"AUROC of U for the unobserved pixels: {_fmt(mean['auroc_unobserved'])}", soft_wrap=True)
    if mean.get("psnr") is not None:  # reports written before it have no PSNR
        observed = "" if mean["psnr_observed"] is None else f", {mean['psnr_observed']:.2f} dB on the observed ones"
        Console().print(f"PSNR of the render scored: {mean['psnr']:.2f} dB on the scored pixels{observed} (the mean of "
                        "each image's own)", soft_wrap=True)


def load_only_options_set(options: UncertaintyOptions) -> list[str]:
    """The uncertainty options moved off their defaults, as flags: with --maps they would be silently ignored."""
    return [f"--{name.replace('_', '-')}" for name in OPTION_NAMES if getattr(options, name) != getattr(DEFAULTS, name)]


def scoring_into(output: Path) -> AbstractContextManager[None]:
    """A stop while the scores are computed and written to `output` says whether they were: they are written last,
    with their plot, and a stop there waits for both (`finish_first`); only a second stop there cuts it short, maybe
    between the plot (written first) and the scores."""
    plot = output.with_suffix(".png")
    earlier, earlier_plot = file_identity(output), file_identity(plot)

    def left() -> str:
        if file_identity(output) == earlier and file_identity(plot) != earlier_plot:
            kept = f"the earlier {output} is unchanged" if earlier else f"{output} is not written"
            return (f"a second stop cut short the write of the scores: their plot {plot} is new, but {kept}; run the "
                    "command again to write both")
        return what_a_stop_left(output, earlier, "report", output)

    return saying_what_is_left(left)


def run(config: EvalAuseConfig) -> None:
    if (config.load is None) == (config.maps is None):
        raise SplatuError("pass exactly one of --load and --maps", "in the eval-ause options",
                          "use --load RUN_DIR to evaluate a run or --maps DIR for precomputed maps")
    if config.maps is not None:
        ignored = load_only_options_set(config.uncertainty)
        if ignored:
            flags, verb = " ".join(ignored), "applies" if len(ignored) == 1 else "apply"
            raise SplatuError(f"{flags} only {verb} with --load (a maps directory already holds its images and "
                              "one uncertainty)", "in the eval-ause options",
                              f"drop {flags}, or pass --load RUN_DIR instead of --maps")
        output = config.output or config.maps / "ause.json"
        with scoring_into(output):
            report = evaluate_maps(config.maps, config.metric, "uncertainty", config.output)
    else:
        from splatu.render_uncertainty import pinned_load, render_eval_maps

        config.uncertainty.check()
        config = dataclasses.replace(config, load=pinned_load(config.load, "the report"))
        maps_root = None
        if config.output is not None:  # before the render, so a bad --output costs nothing
            maps_root = maps_beside(checked_output(config.output))
        # options: the method resolved for the run (`UncertaintyOptions.for_run`), as the report records it
        with saying_what_is_left(lambda: "no scores written, so any earlier report is unchanged"):
            maps_dir, entries, stand_in, label, options = render_eval_maps(config.load, config.uncertainty, maps_root)
        output = config.output or run_folder(config.load) / f"ause_{label}.json"
        with scoring_into(output):
            report = evaluate_maps(maps_dir, config.metric, label, output,
                                   {"load": str(config.load), **options.record()}, entries, stand_in)
    print_report(report, config.metric, config.per_image)
    Console().print(f"wrote {output} and {output.with_suffix('.png')}", soft_wrap=True)
