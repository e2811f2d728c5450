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
of the squared error. Two more columns and one figure separate geometry from view-dependent colour:
- the PSNR of the same model rendered with its colour SH's DC term only (no view dependence at all);
- the median relative error of the rendered depth (Σ w·z / alpha, where alpha > 0.5) against the stand-in's
  true depth. A Gaussian renders at its centre's depth over its whole footprint, so this error also includes a
  tilted Gaussian's extent, not only misplaced geometry;
- how far the Gaussians sit from the true surface: in every training view, the signed relative offset
  (z − z_true) / z_true of each Gaussian whose maximum blending weight there is ≥ MIN_WEIGHT, with z_true read at
  the pixel its mean projects to. An offset δ moves texture by about f·δ·sin(angle) pixels (f the focal length
  in pixels) in a view at that angle, so it hurts more the further a view is from the training views.
One more column needs no model at all: the **true-geometry reprojection**. Each observed pixel's true surface
point takes its colour from the training view whose ray to it is closest in angle to the eval view's, among
the views that see it unoccluded (exact visibility rays, as the observed mask; bilinear sampling of the stored
8-bit image). It is what copying the training images onto perfect geometry gives: moved highlights,
foreshortened texture, resampling and aliasing included. It is a reference, not a bound: a model can blend
several views, or do worse.
With --ground-truth-floor N it also scores the stored ground truth against N×N rays per pixel, to tell whether
the images' own aliasing limits the PSNR. Prints the tables and writes benchmarks/results/unseen_error.json.
"""

from __future__ import annotations

import itertools
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import tyro
from torch import Tensor

from splatu.baselines.angle import angular_gap, view_coverage
from splatu.baselines.load import load_any_run, run_data
from splatu.camera import Camera
from splatu.data.poster.generate import build_scene, camera_path
from splatu.data.poster.geometry import PosterScene
from splatu.data.poster.raycast import blocked
from splatu.data.poster.render import render
from splatu.data.resolve import load_scene, real_poster_candidates
from splatu.data.scene import Views
from splatu.errors import SplatuError
from splatu.model import GaussianModel, ModelRender
from splatu.provenance import measured_on
from splatu.train_config import eval_background

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
GAP_EDGES = (0.0, 5.0, 10.0, 20.0, 30.0, 180.0)
GRADIENT_EDGES = (0.0, 0.01, 0.03, 0.1, math.inf)
HIGHLIGHT = 2.0 / 255.0
MIN_WEIGHT = 0.3
"""A Gaussian that supplies at least this share of some pixel's colour in a view decides where that texture lands;
fainter ones barely move the image, and many sit off the surface without harm."""
OFFSET_QUANTILES = (0.1, 0.25, 0.5, 0.75, 0.9)
STORED_TOLERANCE = 1.5 / 255.0
"""The re-rendered ground truth must match the stored 8-bit images this closely, or the stand-in is another one."""


@dataclass
class PixelErrors:
    """Per observed pixel: squared error (mean over channels) of the render, of its DC-only render and of the
    true-geometry reprojection, and the relative depth error |d̂ − d| / d (NaN where the render is less than half
    opaque)."""

    squared: Tensor
    squared_dc: Tensor
    squared_reprojected: Tensor
    depth: Tensor


def nearest_view_colours(world: PosterScene, points: Tensor, viewer: Tensor, cameras: list[Camera],
                         images: Tensor) -> Tensor:
    """(N, 3) the colour of each surface point (N, 3) in the training view whose ray to it is closest in angle to
    the ray from `viewer`, among the views (cameras, images (V, H, W, 3)) that see it unoccluded; NaN where none do.

    Views are tried per point in order of angle, so a point is settled by the first view that sees it: the loop
    visits a rank only while some point is still unsettled, and tests visibility only for those.
    """
    points = points.double()
    centres = torch.stack([c.center().double() for c in cameras])
    world_to_camera = torch.stack([c.world_to_camera.double() for c in cameras])
    K = torch.stack([c.K.double() for c in cameras])
    near = torch.tensor([c.near for c in cameras], dtype=torch.float64)
    to_viewer = torch.nn.functional.normalize(viewer.double() - points, dim=-1)
    cosines = torch.stack([(torch.nn.functional.normalize(centre - points, dim=-1) * to_viewer).sum(-1)
                           for centre in centres], dim=1)
    order = cosines.argsort(dim=1, descending=True, stable=True)
    colours = torch.full((points.shape[0], 3), math.nan, dtype=images.dtype)
    pending = torch.arange(points.shape[0])
    for rank in range(len(cameras)):
        if pending.numel() == 0:
            break
        view = order[pending, rank]
        p = (world_to_camera[view, :3, :3] @ points[pending, :, None]).squeeze(-1) + world_to_camera[view, :3, 3]
        z = p[:, 2].clamp_min(1e-12)
        u = K[view, 0, 0] * p[:, 0] / z + K[view, 0, 2]
        v = K[view, 1, 1] * p[:, 1] / z + K[view, 1, 2]
        height, width = images.shape[1:3]
        inside = (p[:, 2] > near[view]) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        inside[inside.clone()] = ~blocked(world, centres[view[inside]], points[pending[inside]])
        colours[pending[inside]] = bilinear(images, view[inside], u[inside] - 0.5, v[inside] - 0.5)
        pending = pending[~inside]
    return colours


def bilinear(images: Tensor, view: Tensor, x: Tensor, y: Tensor) -> Tensor:
    """(M, 3) images[view] (V, H, W, 3) sampled at continuous pixel-index coordinates (x, y), edges clamped."""
    height, width = images.shape[1:3]
    x0, y0 = x.floor(), y.floor()
    fx, fy = (x - x0)[:, None].to(images.dtype), (y - y0)[:, None].to(images.dtype)

    def at(xs: Tensor, ys: Tensor) -> Tensor:
        return images[view, ys.long().clamp(0, height - 1), xs.long().clamp(0, width - 1)]

    top = torch.lerp(at(x0, y0), at(x0 + 1, y0), fx)  # a + f (b − a): exact on flat colour
    return torch.lerp(top, torch.lerp(at(x0, y0 + 1), at(x0 + 1, y0 + 1), fx), fy)


def relative_depth_error(render: ModelRender, true_depth: Tensor) -> Tensor:
    """(H, W) |rendered depth − true depth| / true depth, NaN where the render is less than half opaque (its depth
    is then mostly a guess)."""
    error = (render.depth - true_depth).abs() / true_depth
    return torch.where(render.alpha > 0.5, error, math.nan)


@torch.no_grad()
def surface_offsets(model: GaussianModel, views: Views) -> Tensor:
    """Signed relative depth offsets from the true surface, over every view, of the Gaussians with a maximum blending
    weight ≥ MIN_WEIGHT in that view (the weights need no colour, so the render is DC only on black)."""
    offsets = []
    for camera, true_depth in zip(views.cameras, views.depths, strict=True):
        strong = model.render(camera, 0, model.means.new_zeros(3)).raster.contrib_max >= MIN_WEIGHT
        uv, z = camera.project(model.means[strong])
        pixel = uv.floor().long()
        inside = ((pixel[:, 0] >= 0) & (pixel[:, 0] < camera.width) & (pixel[:, 1] >= 0)
                  & (pixel[:, 1] < camera.height) & (z > 0))
        surface = true_depth[pixel[inside, 1], pixel[inside, 0]]
        offsets.append(((z[inside] - surface) / surface).double())  # the stand-in's room gives every pixel a depth
    return torch.cat(offsets)


def offset_summary(offsets: Tensor) -> dict[str, Any]:
    """How many (Gaussian, view) offsets, their median magnitude and their OFFSET_QUANTILES (signed); None and {}
    if there are none."""
    if offsets.numel() == 0:
        return {"gaussian_views": 0, "median_abs": None, "quantiles": {}}
    values = offsets.numpy()
    return {"gaussian_views": int(values.size), "median_abs": float(np.median(np.abs(values))),
            "quantiles": {f"{q:g}": float(np.quantile(values, q)) for q in OFFSET_QUANTILES}}


@dataclass
class Args:
    load: Path = Path("outputs/poster/splatu/latest")
    """A run trained on the built-in poster stand-in."""
    output: Path = RESULTS / "unseen_error.json"
    ground_truth_floor: int = 0
    """If > 0, also re-render every eval view with this many² rays per pixel (the stand-in uses 2²) and report the
    PSNR of the stored ground truth against it: how far its own aliasing and 8-bit rounding sit from a finely
    integrated pixel. 8 takes several minutes."""


def gradient_magnitude(image: Tensor) -> Tensor:
    """(H, W) central-difference gradient magnitude of the channel mean, 0 on the border."""
    grey = image.mean(-1)
    gy, gx = torch.zeros_like(grey), torch.zeros_like(grey)
    gy[1:-1] = (grey[2:] - grey[:-2]) / 2
    gx[:, 1:-1] = (grey[:, 2:] - grey[:, :-2]) / 2
    return (gx * gx + gy * gy).sqrt()


def squared_error(rgb: Tensor, target: Tensor) -> Tensor:
    """(H, W) float64 squared error, mean over channels, of a render clipped to [0, 1] as the images are."""
    return ((rgb.clamp(0, 1) - target) ** 2).mean(-1).double()


def pooled_psnr(squared_errors: Tensor) -> float:
    return -10.0 * math.log10(float(squared_errors.mean()))


def binned(pixels: PixelErrors, values: Tensor, edges: tuple[float, ...]) -> list[dict[str, float | None]]:
    """Per [lo, hi) bin of `values`: share of pixels, pooled PSNR (full colour and DC only), share of the
    squared error, and the median relative depth error of its pixels that have one (None if none do)."""
    rows = []
    for lo, hi in itertools.pairwise(edges):
        inside = (values >= lo) & (values < hi)
        if inside.any():
            depth = pixels.depth[inside]
            depth = depth[torch.isfinite(depth)]
            rows.append({"from": lo, "to": hi if math.isfinite(hi) else None, "pixels": float(inside.double().mean()),
                         "psnr": pooled_psnr(pixels.squared[inside]),
                         "psnr_dc_only": pooled_psnr(pixels.squared_dc[inside]),
                         "psnr_reprojected": pooled_psnr(pixels.squared_reprojected[inside]),
                         "squared_error": float(pixels.squared[inside].sum() / pixels.squared.sum()),
                         "depth_error": float(np.median(depth.numpy())) if depth.numel() else None})
    return rows


@torch.no_grad()
def main(args: Args) -> None:
    if args.ground_truth_floor < 0:
        raise SplatuError(f"--ground-truth-floor {args.ground_truth_floor} is negative", "in the options",
                          "pass 0 (off) or the rays per pixel side, e.g. 8")
    run = load_any_run(args.load)
    data = run_data(run)
    if data.data != "poster" or any((p / "transforms.json").is_file() for p in real_poster_candidates()):
        raise SplatuError("this study needs a run on the built-in poster stand-in", f"in {args.load}",
                          "train one with `splatu train --data poster` (without the real capture installed)")
    scene, model = load_scene(data), run.models[0]
    background, degree = eval_background(run.config), run.config.model.sh_degree
    world, cameras = build_scene(), {c.name: c for c in camera_path(data.poster)}
    coverage = view_coverage(model, scene.train.cameras, run.config.uncertainty.threshold)
    train_cameras = [cameras[Path(name).stem] for name in scene.train.names]  # the generator's frame, not the run's
    squared, squared_dc, squared_reprojected, depth_errors, gaps, gradients, highlights, floor = ([] for _ in range(8))
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
        dc_only = model.render(camera, 0, background)
        observed = scene.eval.observed[i].reshape(target.shape[:2]).bool()
        squared.append(squared_error(out.rgb, target)[observed])
        squared_dc.append(squared_error(dc_only.rgb, target)[observed])
        copied = nearest_view_colours(world, full.points[observed.reshape(-1)], original.center(), train_cameras,
                                      scene.train.images)
        unseen = int(torch.isnan(copied[:, 0]).sum())
        if unseen:  # the observed mask comes from the same visibility test, so this would be a bug, not noise
            raise RuntimeError(f"{unseen} observed pixels of {scene.eval.names[i]} are seen by no training view in the "
                               "reprojection, though the observed mask says otherwise")
        squared_reprojected.append(squared_error(copied, target[observed]))
        depth_errors.append(relative_depth_error(out, scene.eval.depths[i])[observed].double())
        # the gap of what the pixel sees: the composite without its empty-space share, over the coverage
        seen_gap = (out.extra[..., 0] - (1.0 - out.alpha)) / out.alpha.clamp_min(1e-6)
        gaps.append(torch.where(out.alpha > 1e-3, seen_gap, 1.0)[observed] * 180.0)
        gradients.append(gradient_magnitude(target)[observed])
        highlights.append(((full.rgb - matte.rgb).abs().mean(-1) > HIGHLIGHT)[observed])
        if args.ground_truth_floor:
            fine = render(world, original, args.ground_truth_floor)
            floor.append(squared_error(fine.rgb, target.double())[observed])
    pixels = PixelErrors(torch.cat(squared), torch.cat(squared_dc), torch.cat(squared_reprojected),
                         torch.cat(depth_errors))
    offsets = surface_offsets(model, scene.train)
    tables = {
        "angular gap (degrees)": binned(pixels, torch.cat(gaps), GAP_EDGES),
        "ground-truth gradient (per pixel)": binned(pixels, torch.cat(gradients), GRADIENT_EDGES),
        "highlight (0: none, 1: lit)": binned(pixels, torch.cat(highlights).float(), (0.0, 0.5, 1.5)),
    }
    command = f"python benchmarks/unseen_error.py --load {args.load}"
    if args.output != Args().output:
        command += f" --output {args.output}"
    if args.ground_truth_floor:
        command += f" --ground-truth-floor {args.ground_truth_floor}"
    record = {"run": str(args.load), "command": command,
              "eval_views": len(scene.eval), "observed_pixels": int(pixels.squared.numel()),
              "psnr_observed_pooled": pooled_psnr(pixels.squared),
              "psnr_observed_pooled_dc_only": pooled_psnr(pixels.squared_dc),
              "psnr_observed_pooled_reprojected": pooled_psnr(pixels.squared_reprojected), "tables": tables,
              "surface_offset": offset_summary(offsets),
              "ground_truth_vs_supersampled": ({"rays_per_pixel": args.ground_truth_floor ** 2,
                                                "psnr_observed_pooled": pooled_psnr(torch.cat(floor))}
                                               if floor else None),
              "measured": measured_on()}
    print(f"{record['observed_pixels']} observed pixels in {len(scene.eval)} eval views, pooled PSNR "
          f"{record['psnr_observed_pooled']:.2f} dB ({record['psnr_observed_pooled_dc_only']:.2f} dB DC only; the "
          f"true-geometry reprojection: {record['psnr_observed_pooled_reprojected']:.2f} dB)")
    if floor:
        print(f"the stored ground truth against {args.ground_truth_floor ** 2} rays per pixel: "
              f"{record['ground_truth_vs_supersampled']['psnr_observed_pooled']:.2f} dB")
    offset = record["surface_offset"]
    if offset["gaussian_views"]:
        print(f"Gaussians with a blending weight >= {MIN_WEIGHT:g} in a training view ({offset['gaussian_views']} "
              f"(Gaussian, view) pairs): relative depth offset from the true surface, median |·| "
              f"{offset['median_abs']:.2%}, quantiles "
              + ", ".join(f"{q}: {v:+.2%}" for q, v in offset["quantiles"].items()))
    for title, rows in tables.items():
        print(f"\n| {title} | pixels | PSNR dB | PSNR dB, DC only | PSNR dB, reprojected | squared error "
              "| median depth error |\n|---|---|---|---|---|---|---|")
        for row in rows:
            upper = "∞" if row["to"] is None else f"{row['to']:g}"
            depth = "-" if row["depth_error"] is None else f"{row['depth_error']:.2%}"
            print(f"| [{row['from']:g}, {upper}) | {row['pixels']:.1%} | {row['psnr']:.2f} | "
                  f"{row['psnr_dc_only']:.2f} | {row['psnr_reprojected']:.2f} | {row['squared_error']:.1%} | {depth} |")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(record, indent=2))
    print(f"\nwrote {args.output}")


if __name__ == "__main__":
    try:
        main(tyro.cli(Args))
    except SplatuError as err:  # a missing run or another scene: one line, as every splatu command prints it
        sys.exit(f"error: {err}")
