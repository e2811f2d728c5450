"""Which change to training moves poster's unseen-angle PSNR? One `fast` training per lever, on the built-in stand-in.

    python benchmarks/unseen_levers.py --lever none
    python benchmarks/unseen_levers.py --lever filter-3d --weight 0.2
    python benchmarks/unseen_levers.py --lever true-depth --weight 1

The target under study is 28 dB on the observed pixels of the held-out contiguous block (the unseen angle);
`fast` read 26.46 dB there (the `none` row, measured before commit 6e1ac8f changed density control; 26.53
at 588755b). Each lever but the oracle is our version of a published fix for novel views, applied to this process's
training only (the script patches the trainer while it trains, and puts everything back after):

- `filter-3d W`: Mip-Splatting's 3D smoothing filter. Each Gaussian's covariance gets + W/ν² on every axis,
  where ν is the highest sampling rate (focal / depth, pixels per unit) any training camera has of its mean,
  and its opacity is scaled by sqrt(det Σ / det Σ'), which keeps opacity × volume. It caps a Gaussian's
  frequency at what the training views could resolve; a mean no training camera has in view gets the lowest
  rate of the others, the strongest filter, as in Mip-Splatting. The filter is recomputed whenever refinement
  replaces the Gaussians, and every 100 renders in between (Mip-Splatting recomputes it at each refinement).
  It is applied at render time only: the run's checkpoints and PLY hold the unfiltered Gaussians, so only the
  evaluation inside the training scores the filtered model.
- `depth-smoothness W`: W × the edge-aware total variation of the rendered depth (over the view's median
  depth), with each difference down-weighted by exp(−10 |Δ image|), on pixels that are at least half opaque.
  It is a depth-smoothness prior like RegNeRF's for sparse views, but on the training views (RegNeRF smooths
  patches rendered from unobserved viewpoints) and edge-aware.
- `opacity-entropy W`: W × the mean binary entropy of the opacities. It pushes every Gaussian to be opaque
  or gone, so a surface is one layer rather than a stack of translucent ones.
- `true-depth W`: **an oracle, not a method.** W × the mean relative error |D − D_true| / D_true of the rendered
  depth against the stand-in's ground truth, at full resolution, on pixels that are at least half opaque. It
  asks whether geometry limits the unseen block: no real capture has D_true.

Writes benchmarks/results/unseen_levers.json, keeping the rows of levers this invocation did not rerun. Each row
records its date and CPU.
"""

from __future__ import annotations

import dataclasses
import fcntl
import json
import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import torch
import tyro
from torch import Tensor

import splatu.model
from splatu import trainer, training_step
from splatu.camera import Camera
from splatu.data.resolve import load_scene
from splatu.model import GaussianModel
from splatu.provenance import measured_on
from splatu.run_dir import new_run_dir
from splatu.train_config import preset_config

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "unseen_levers.json"
Lever = Literal["none", "filter-3d", "depth-smoothness", "opacity-entropy", "true-depth"]

FRUSTUM_MARGIN = 0.15
"""A mean counts as in a camera's view up to this fraction of the image beyond its border (Mip-Splatting)."""
FILTER_REFRESH_RENDERS = 100
"""The 3D filter is recomputed after this many renders, as well as whenever the Gaussians change in number."""
EDGE_SHARPNESS = 10.0
"""Depth differences across an image step of Δ (in [0, 1] colour units) count exp(−10 Δ) in depth-smoothness."""


@dataclass
class Args:
    lever: Lever = "none"
    """The change to training (see the module docstring)."""
    weight: float = 0.0
    """Its strength: the filter's variance in pixels² for filter-3d, the loss weight for the others."""
    preset: str = "fast"
    """Training preset."""
    seed: int = 0
    output_dir: Path = Path("outputs/benchmarks/unseen_levers")
    """Where the trainings are written."""


# --- the levers, as pure functions ---------------------------------------------------------------------------

def max_sampling_rate(means: Tensor, cameras: Sequence[Camera]) -> Tensor:
    """(N,) the largest focal / depth (pixels per scene unit) over the cameras that have each mean in view.

    A mean no camera has in view gets the smallest rate of the others, the strongest filter (Mip-Splatting).
    """
    best = torch.zeros(means.shape[0], dtype=means.dtype)
    for camera in cameras:
        uv, z = camera.to(dtype=means.dtype).project(means)
        margin_x, margin_y = FRUSTUM_MARGIN * camera.width, FRUSTUM_MARGIN * camera.height
        in_view = ((z > camera.near) & (uv[:, 0] > -margin_x) & (uv[:, 0] < camera.width + margin_x)
                   & (uv[:, 1] > -margin_y) & (uv[:, 1] < camera.height + margin_y))
        best = torch.maximum(best, torch.where(in_view, float(camera.K[0, 0]) / z.clamp_min(camera.near), 0.0))
    seen = best > 0
    return torch.where(seen, best, best[seen].min() if bool(seen.any()) else 1.0)


def filtered(log_scales: Tensor, opacities: Tensor, variance: Tensor) -> tuple[Tensor, Tensor]:
    """Log-scales and opacities of the Gaussians convolved with an isotropic Gaussian of `variance` (N,)."""
    squared = torch.exp(2.0 * log_scales)
    widened = squared + variance[:, None]
    return 0.5 * torch.log(widened), opacities * torch.sqrt(torch.prod(squared / widened, dim=-1))


def depth_smoothness(depth: Tensor, alpha: Tensor, image: Tensor) -> Tensor:
    """Edge-aware total variation of depth / median depth over neighbouring pixels that are both half opaque."""
    opaque = alpha.detach() > 0.5
    if not bool(opaque.any()):
        return depth.new_zeros(())
    relative = depth / depth.detach()[opaque].median().clamp_min(1e-6)
    total = depth.new_zeros(())
    for dim in (0, 1):
        step = relative.diff(dim=dim).abs() * torch.exp(-EDGE_SHARPNESS * image.diff(dim=dim).abs().mean(-1))
        both = opaque.narrow(dim, 1, opaque.shape[dim] - 1) & opaque.narrow(dim, 0, opaque.shape[dim] - 1)
        total = total + (step * both).sum() / both.sum().clamp_min(1)
    return total


def opacity_entropy(opacity_logits: Tensor) -> Tensor:
    """Mean binary entropy (nats) of the opacities: ln 2 at 0.5, 0 at 0 or 1."""
    o = torch.sigmoid(opacity_logits).clamp(1e-6, 1.0 - 1e-6)
    return -(o * o.log() + (1.0 - o) * (1.0 - o).log()).mean()


def true_depth_error(depth: Tensor, alpha: Tensor, true_depth: Tensor) -> Tensor:
    """Mean |depth − true| / true over pixels that are at least half opaque and have a true depth."""
    valid = (alpha.detach() > 0.5) & torch.isfinite(true_depth) & (true_depth > 0)
    if not bool(valid.any()):
        return depth.new_zeros(())
    return ((depth - true_depth).abs() / true_depth)[valid].mean()


# --- applying one to a training ----------------------------------------------------------------------------

@contextmanager
def applied(lever: Lever, weight: float, cameras: Sequence[Camera]) -> Iterator[None]:
    """Train with `lever` inside this block: patches the trainer's loss, or the model's rasterizer call, and
    restores them on the way out, whatever happens."""
    patches: list[tuple[Any, str, Any]] = []

    def patch(owner: Any, name: str, replacement: Any) -> None:
        patches.append((owner, name, getattr(owner, name)))
        setattr(owner, name, replacement)

    if lever == "filter-3d":
        patch(splatu.model, "rasterize", _filtering_rasterize(splatu.model.rasterize, weight, cameras))
    elif lever != "none":
        regularised = _with_regulariser(training_step.photometric_loss, lever, weight, patch)
        patch(training_step, "photometric_loss", regularised)
    try:
        yield
    finally:
        for owner, name, original in reversed(patches):
            setattr(owner, name, original)


def _filtering_rasterize(rasterize: Callable, variance_px: float, cameras: Sequence[Camera]) -> Callable:
    cache: dict[str, Any] = {"means": None, "round": None, "renders": 0}

    def filtering(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, *args: Any, **kwargs: Any):
        if not kwargs.get("log_scales"):
            raise ValueError("filter-3d expects the model's log-scales")
        refresh = cache["renders"] // FILTER_REFRESH_RENDERS
        cache["renders"] += 1
        if cache["means"] is not means or cache["round"] != refresh:  # refinement replaces the means Parameter
            cache["variance"] = variance_px / max_sampling_rate(means.detach(), cameras).square()
            cache["means"], cache["round"] = means, refresh
        scales, opacities = filtered(scales, opacities, cache["variance"].to(scales))
        return rasterize(means, quats, scales, opacities, *args, **kwargs)

    return filtering


def _with_regulariser(photometric_loss: Callable, lever: Lever, weight: float, patch: Callable) -> Callable:
    """The trainer's photometric loss plus weight × the lever's term, read off the render being trained on."""
    seen: dict[str, Any] = {}
    render, get = GaussianModel.render, training_step.TrainImages.get

    def recording_render(model: GaussianModel, *args: Any, **kwargs: Any):
        seen["model"], seen["render"] = model, render(model, *args, **kwargs)
        return seen["render"]

    def recording_get(images: training_step.TrainImages, index: int, level: int, *args: Any):
        seen["views"], seen["index"], seen["level"] = images.views, index, level
        return get(images, index, level, *args)

    patch(GaussianModel, "render", recording_render)
    patch(training_step.TrainImages, "get", recording_get)

    def loss(rgb: Tensor, target: Tensor, ssim_lambda: float) -> Tensor:
        base, out = photometric_loss(rgb, target, ssim_lambda), seen["render"]
        if lever == "depth-smoothness":
            return base + weight * depth_smoothness(out.depth, out.alpha, target)
        if lever == "opacity-entropy":
            return base + weight * opacity_entropy(seen["model"].opacity_logits)
        if lever == "true-depth":
            if seen["level"] != 0:  # ground truth exists at full resolution only
                return base
            return base + weight * true_depth_error(out.depth, out.alpha, seen["views"].depths[seen["index"]])
        raise ValueError(f"no regulariser for lever {lever!r}")

    return loss


def _rounded(seconds: float | None) -> float | None:
    """A time to a tenth of a second; None stays None (a compile time the kernels' clock could not take)."""
    return None if seconds is None else round(seconds, 1)


def train_with(args: Args) -> dict:
    """One training of `args.preset` on poster with the lever on; returns its results row."""
    config = dataclasses.replace(preset_config(args.preset), output_dir=args.output_dir, progress=False,
                                 seed=args.seed)
    scene = load_scene(config.data)
    if scene.eval.observed is None or scene.train.depths is None:
        raise SystemExit("error: this study needs the built-in poster stand-in (its observed masks and true depth), "
                         "and the poster found lacks them (the real capture?); move the real capture out of "
                         "data/nerfstudio/poster and $SPLATU_DATA/poster while it runs")
    run_dir = new_run_dir(config.output_dir, scene.name, config.method)
    started = time.perf_counter()
    with applied(args.lever, args.weight, scene.train.cameras):
        summary = trainer.train_run(config, scene, run_dir, wall_start=started)
    evals = summary["eval"]
    return {"lever": args.lever, "weight": args.weight, "preset": args.preset, "seed": args.seed,
            "gaussians": summary["num_gaussians"], "train_seconds": round(summary["train_seconds"], 1),
            "train_compile_seconds": _rounded(summary["train_compile_seconds"]),
            "unseen_observed_psnr": evals["eval"]["psnr_observed"], "unseen_psnr": evals["eval"]["psnr"],
            "every_8th_psnr": evals["interp"]["psnr"], "run_dir": str(run_dir),
            **{k: v for k, v in measured_on().items() if k in ("date", "cpu")}}


def merged(row: dict, previous: list[dict]) -> list[dict]:
    """`previous` without the row for the same (lever, weight, preset, seed), then `row`."""
    key = ("lever", "weight", "preset", "seed")
    return [r for r in previous if any(r[k] != row[k] for k in key)] + [row]


def table(rows: list[dict]) -> str:
    lines = [f"{'lever':<18}{'weight':>8}{'preset':>9}{'seed':>6}{'Gaussians':>11}"
             f"{'unseen, observed':>18}{'every-8th':>11}{'train s':>9}"]
    for r in rows:
        lines.append(f"{r['lever']:<18}{r['weight']:>8g}{r['preset']:>9}{r['seed']:>6}{r['gaussians']:>11}"
                     f"{r['unseen_observed_psnr']:>18.2f}{r['every_8th_psnr']:>11.2f}{r['train_seconds']:>9.0f}")
    return "\n".join(lines)


def main(args: Args) -> None:
    if args.lever != "none" and not (math.isfinite(args.weight) and args.weight > 0):
        raise SystemExit(f"error: --weight must be positive for --lever {args.lever} (got {args.weight})")
    row = train_with(args)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    with open(args.output_dir / "results.lock", "w") as lock:  # invocations may run side by side
        fcntl.flock(lock, fcntl.LOCK_EX)
        rows = merged(row, json.loads(RESULTS.read_text()) if RESULTS.is_file() else [])
        RESULTS.write_text(json.dumps(rows, indent=2) + "\n")
    print(table(rows))
    print(f"written to {RESULTS}")


if __name__ == "__main__":
    main(tyro.cli(Args))
