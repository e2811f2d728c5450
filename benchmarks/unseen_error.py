"""Where a trained poster model's error on the unseen eval block comes from (issue 5's 28 dB target).

    .venv/bin/python benchmarks/unseen_error.py --load outputs/poster/splatu/latest

Only the built-in stand-in can answer this, because its generator can re-render every eval view without
highlights. Over the observed pixels of the eval block (those some training camera saw), it splits the
squared error of the model's render three ways:
- by the angular gap of the pixel (`splatu.baselines.angle`, composited over what the pixel sees, in degrees):
  how far the view is from the nearest training view that saw the surface;
- by the texture under the pixel: the ground truth's central-difference gradient magnitude;
- by whether a highlight lights the pixel (ground truth with and without the specular term differ by more
  than 2/255).
Each bin gets its share of the pixels, its PSNR (pooled over its pixels, not averaged per image) and its share
of the squared error. Prints the tables and writes benchmarks/results/unseen_error.json.
"""

from __future__ import annotations

import itertools
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import torch
import tyro
from torch import Tensor

from splatu.baselines.angle import angular_gap, view_coverage
from splatu.baselines.load import load_any_run, run_data
from splatu.data.poster.generate import build_scene, camera_path
from splatu.data.poster.render import render
from splatu.data.resolve import load_scene, real_poster_candidates
from splatu.errors import SplatuError
from splatu.provenance import measured_on
from splatu.train_config import eval_background

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
GAP_EDGES = (0.0, 5.0, 10.0, 20.0, 30.0, 180.0)
GRADIENT_EDGES = (0.0, 0.01, 0.03, 0.1, math.inf)
HIGHLIGHT = 2.0 / 255.0
STORED_TOLERANCE = 1.5 / 255.0
"""The re-rendered ground truth must match the stored 8-bit images this closely, or the stand-in is another one."""


@dataclass
class Args:
    load: Path = Path("outputs/poster/splatu/latest")
    """A run trained on the built-in poster stand-in."""
    output: Path = RESULTS / "unseen_error.json"


def gradient_magnitude(image: Tensor) -> Tensor:
    """(H, W) central-difference gradient magnitude of the channel mean, 0 on the border."""
    grey = image.mean(-1)
    gy, gx = torch.zeros_like(grey), torch.zeros_like(grey)
    gy[1:-1] = (grey[2:] - grey[:-2]) / 2
    gx[:, 1:-1] = (grey[:, 2:] - grey[:, :-2]) / 2
    return (gx * gx + gy * gy).sqrt()


def binned(errors: Tensor, values: Tensor, edges: tuple[float, ...]) -> list[dict[str, float]]:
    """Share of pixels, pooled PSNR and share of squared error of each [lo, hi) bin of `values`."""
    rows = []
    for lo, hi in itertools.pairwise(edges):
        inside = (values >= lo) & (values < hi)
        if inside.any():
            rows.append({"from": lo, "to": hi if math.isfinite(hi) else None, "pixels": float(inside.double().mean()),
                         "psnr": -10.0 * math.log10(float(errors[inside].mean())),
                         "squared_error": float(errors[inside].sum() / errors.sum())})
    return rows


@torch.no_grad()
def main(args: Args) -> None:
    run = load_any_run(args.load)
    data = run_data(run)
    if data.data != "poster" or any((p / "transforms.json").is_file() for p in real_poster_candidates()):
        raise SplatuError("this study needs a run on the built-in poster stand-in", f"in {args.load}",
                          "train one with `splatu train --data poster` (without the real capture installed)")
    scene, model = load_scene(data), run.models[0]
    background, degree = eval_background(run.config), run.config.model.sh_degree
    world, cameras = build_scene(), {c.name: c for c in camera_path(data.poster)}
    coverage = view_coverage(model, scene.train.cameras, run.config.uncertainty.threshold, degree)
    errors, gaps, gradients, highlights = [], [], [], []
    for i, camera in enumerate(scene.eval.cameras):
        target = scene.eval.images[i]
        original = cameras[Path(scene.eval.names[i]).stem]
        full = render(world, original, data.poster.supersample)
        if float((full.rgb - target.double()).abs().max()) > STORED_TOLERANCE:
            raise SplatuError("the stand-in on disk is not the one this generator makes", f"in {args.load}",
                              "retrain on the current stand-in (`splatu train --data poster`)")
        matte = render(world, original, data.poster.supersample, specular=False)
        gap = angular_gap(model.means, coverage, camera.center())
        out = model.render(camera, degree, background, extra_features=gap[:, None])
        observed = scene.eval.observed[i].reshape(target.shape[:2]).bool()
        errors.append(((out.rgb.clamp(0, 1) - target) ** 2).mean(-1)[observed].double())
        # the gap of what the pixel sees: the composite without its empty-space share, over the coverage
        seen_gap = (out.extra[..., 0] - (1.0 - out.alpha)) / out.alpha.clamp_min(1e-6)
        gaps.append(torch.where(out.alpha > 1e-3, seen_gap, 1.0)[observed] * 180.0)
        gradients.append(gradient_magnitude(target)[observed])
        highlights.append(((full.rgb - matte.rgb).abs().mean(-1) > HIGHLIGHT)[observed])
    error = torch.cat(errors)
    tables = {
        "angular gap (degrees)": binned(error, torch.cat(gaps), GAP_EDGES),
        "ground-truth gradient (per pixel)": binned(error, torch.cat(gradients), GRADIENT_EDGES),
        "highlight (0: none, 1: lit)": binned(error, torch.cat(highlights).float(), (0.0, 0.5, 1.5)),
    }
    record = {"run": str(args.load), "command": f"python benchmarks/unseen_error.py --load {args.load}",
              "eval_views": len(scene.eval), "observed_pixels": int(error.numel()),
              "psnr_observed_pooled": -10.0 * math.log10(float(error.mean())), "tables": tables,
              "measured": measured_on()}
    print(f"{record['observed_pixels']} observed pixels in {len(scene.eval)} eval views, pooled PSNR "
          f"{record['psnr_observed_pooled']:.2f} dB")
    for title, rows in tables.items():
        print(f"\n| {title} | pixels | PSNR dB | squared error |\n|---|---|---|---|")
        for row in rows:
            upper = "∞" if row["to"] is None else f"{row['to']:g}"
            print(f"| [{row['from']:g}, {upper}) | {row['pixels']:.1%} | {row['psnr']:.2f} | "
                  f"{row['squared_error']:.1%} |")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(record, indent=2))
    print(f"\nwrote {args.output}")


if __name__ == "__main__":
    try:
        main(tyro.cli(Args))
    except SplatuError as err:  # a missing run or another scene: one line, as every splatu command prints it
        sys.exit(f"error: {err}")
