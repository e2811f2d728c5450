"""Benchmark `splatu.rasterizer.rasterize` against a straightforward dense per-tile torch rasterizer.

    python benchmarks/rasterizer.py [--quick] [--json PATH] [--compile] [--malloc-defaults]

Scenes (fixed seeds) look like trained ones: 2D stds drawn log-uniformly over 1/3–10 px, each axis
jittered by e^±0.3, and opacities uniform over (0.005, 0.995). The projected 3σ radii (`radii`, with
3DGS's 0.3 px² blur, which floors them at 2 px) read 2 / 3 / 8 / 31–32 / 50 px at the minimum / 5th
percentile / median / 95th percentile / maximum on both cases; about 6% exceed 30 px.
Each (case, implementation) runs in its own subprocess so that `peak_rss_mb` is that run's own peak.
Times are wall-clock medians of the runs (`--runs` of them for ours and the baseline alike, after one
warm-up).
`contributing_pairs` counts pixel–Gaussian pairs with α ≥ 1/255 reached before termination, by the 3DGS
rules in float64 in a subprocess of its own (count_contributing_pairs), not by our rasterizer;
`ours_contributing_pairs` is our rasterizer's own count of them, in float32 (equal, or off by a few pairs at
the thresholds).
`speedup_vs_reference` = (reference forward + backward) / (ours forward + backward).
`reference_candidate_pairs` counts the pixel–Gaussian pairs the baseline evaluates (every pixel of every
tile × every Gaussian binned to it), and `reference_ns_per_candidate_pair` its forward + backward time per
candidate: the unit in which the issue priced eager prototypes (0.5–1 µs per candidate pair).
`ms_footprint` is the part of our forward spent listing each depth round's entries (footprint.py's
block_entries); the rest of it is the projection and the compositing, which since 0afbe8c includes sorting
each round by block as it is reached (before, the footprint sorted every round, and its times are not
comparable across that commit).
Both run with glibc malloc's thresholds fixed as every splatu command fixes them
(splatu.allocator), unless --malloc-defaults.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from splatu.allocator import keep_freed_memory
from splatu.provenance import measured_on

REPO = Path(__file__).resolve().parents[1]
TILE = 16


@dataclass(frozen=True)
class Case:
    name: str
    gaussians: int
    width: int
    height: int
    seed: int


CASES = [
    Case("20k Gaussians at 256x256", 20_000, 256, 256, seed=0),
    Case("100k Gaussians at 512x384", 100_000, 512, 384, seed=1),
]
QUICK_CASE = Case("3k Gaussians at 128x96", 3_000, 128, 96, seed=2)
"""--quick runs this smaller case only, so that ours plus the slow baseline finish in under a minute."""


def make_scene(case: Case) -> tuple[Tensor, ...]:
    """means, quats, log-scales, opacities, colours, world_to_camera, K for one case (float32)."""
    g = torch.Generator().manual_seed(case.seed)
    n, width, height = case.gaussians, case.width, case.height
    fx = 0.8 * width
    K = torch.tensor([[fx, 0.0, width / 2], [0.0, fx, height / 2], [0.0, 0.0, 1.0]])
    z = 2.0 + 4.0 * torch.rand(n, generator=g)
    x = (2 * torch.rand(n, generator=g) - 1) * 0.55 * width / fx * z
    y = (2 * torch.rand(n, generator=g) - 1) * 0.55 * height / fx * z
    std_px = torch.exp(torch.empty(n).uniform_(math.log(1 / 3), math.log(10), generator=g))
    log_scales = torch.log(std_px * z / fx)[:, None] + torch.empty(n, 3).uniform_(-0.3, 0.3, generator=g)
    quats = torch.randn(n, 4, generator=g)
    opacities = torch.empty(n).uniform_(0.005, 0.995, generator=g)
    colours = torch.rand(n, 3, generator=g)
    return torch.stack([x, y, z], -1), quats, log_scales, opacities, colours, torch.eye(4), K


def loss_of(image: Tensor, alpha: Tensor) -> Tensor:
    """A fixed loss touching every output pixel, so the backward does its full work."""
    return image.square().sum() + alpha.sum()


# ---------------------------------------------------------------------------------------------
# The baseline: a straightforward dense per-tile rasterizer, plain autograd, loop over tiles.
# ---------------------------------------------------------------------------------------------


def tile_ranges(mean2d: Tensor, half_x: Tensor, half_y: Tensor, tiles_x: int, tiles_y: int) -> tuple[Tensor, ...]:
    """First and last tile column and row each Gaussian's box (mean ± half-widths) touches (lo > hi: none)."""
    x_lo = ((mean2d[:, 0] - half_x) / TILE).floor().clamp(0, tiles_x)
    x_hi = ((mean2d[:, 0] + half_x) / TILE).floor().clamp(-1, tiles_x - 1)
    y_lo = ((mean2d[:, 1] - half_y) / TILE).floor().clamp(0, tiles_y)
    y_hi = ((mean2d[:, 1] + half_y) / TILE).floor().clamp(-1, tiles_y - 1)
    return x_lo, x_hi, y_lo, y_hi


def tile_weights(proj, hit: Tensor, opacities: Tensor, tx: int, ty: int) -> Tensor:
    """Blending weights (len(hit), 256) of the depth-sorted Gaussians `hit` at tile (tx, ty)'s pixels, by the 3DGS
    rules: α = min(o·e^−σ, 0.99), skipped below 1/255, and a pixel stops before the Gaussian taking T below 1e-4."""
    from splatu.rasterizer.projection import conic_rows

    local_y, local_x = torch.meshgrid(torch.arange(TILE), torch.arange(TILE), indexing="ij")
    px = (tx * TILE + local_x + 0.5).reshape(-1).to(proj.means2d.dtype)
    py = (ty * TILE + local_y + 0.5).reshape(-1).to(proj.means2d.dtype)
    dx = px[None, :] - proj.means2d[hit, 0:1]
    dy = py[None, :] - proj.means2d[hit, 1:2]
    A, S, Q = conic_rows(proj.log_conics[hit], proj.means2d.dtype)[:, :, None]
    swapped = proj.swapped[hit, None]
    v, w = torch.where(swapped, dy, dx), torch.where(swapped, dx, dy)
    sigma = 0.5 * (A * (v - S * w) ** 2 + Q * w * w)
    alpha = torch.clamp(opacities[hit, None] * torch.exp(-sigma), max=0.99)
    alpha = torch.where((sigma >= 0) & (alpha >= 1 / 255), alpha, torch.zeros_like(alpha))
    t_incl = torch.cumprod(1 - alpha, dim=0)
    t_excl = torch.cat([torch.ones_like(t_incl[:1]), t_incl[:-1]], dim=0)
    return torch.where(t_incl >= 1e-4, t_excl * alpha, torch.zeros_like(alpha))


def reference_rasterize(means, quats, log_scales, opacities, colours, world_to_camera, K, width, height):
    """Project, bin Gaussians to the 16×16 tiles their 3σ box touches, composite each tile densely.
    Returns the image, the alpha map and the number of pixel–Gaussian pairs evaluated."""
    from splatu.rasterizer.projection import project_gaussians

    proj = project_gaussians(means, quats, log_scales, world_to_camera, K, width, height, 0.01, 1e10, True)
    ids = torch.nonzero(proj.visible).squeeze(1)
    ids = ids[torch.sort(proj.depths.detach()[ids], stable=True).indices]
    radius = proj.radii[ids].float()
    tiles_x, tiles_y = math.ceil(width / TILE), math.ceil(height / TILE)
    x_lo, x_hi, y_lo, y_hi = tile_ranges(proj.means2d.detach()[ids], radius, radius, tiles_x, tiles_y)
    rows, candidates = [], 0
    for ty in range(tiles_y):
        row_image, row_alpha = [], []
        for tx in range(tiles_x):
            hit = ids[(x_lo <= tx) & (x_hi >= tx) & (y_lo <= ty) & (y_hi >= ty)]
            candidates += hit.numel() * TILE * TILE
            weight = tile_weights(proj, hit, opacities, tx, ty)
            row_image.append((weight[:, :, None] * colours[hit, None, :]).sum(0).reshape(TILE, TILE, 3))
            row_alpha.append(weight.sum(0).reshape(TILE, TILE))
        rows.append((torch.cat(row_image, dim=1), torch.cat(row_alpha, dim=1)))
    image = torch.cat([r[0] for r in rows], dim=0)[:height, :width]
    alpha_map = torch.cat([r[1] for r in rows], dim=0)[:height, :width]
    return image, alpha_map, candidates


@torch.no_grad()
def count_contributing_pairs(means, quats, log_scales, opacities, colours, world_to_camera, K, width, height) -> int:
    """Pixel–Gaussian pairs with α ≥ 1/255 reached before termination, by the 3DGS rules in float64, independent
    of our rasterizer: each Gaussian is evaluated at every pixel of every tile its whole α ≥ 1/255 ellipse
    (σ ≤ ln(255·o), beyond the 3σ box for o > 0.09) touches, so no pair is lost to a bound."""
    from splatu.rasterizer.projection import project_gaussians

    scene = [t.double() for t in (means, quats, log_scales, world_to_camera, K)]
    proj = project_gaussians(*scene, width, height, 0.01, 1e10, True)
    opacities = opacities.double()
    reach_sq = 2 * torch.log(255 * opacities.clamp_min(1 / 255))  # Mahalanobis² where α falls to 1/255
    ids = torch.nonzero(proj.visible & (reach_sq > 0)).squeeze(1)
    ids = ids[torch.sort(proj.depths[ids], stable=True).indices]
    half_x = (reach_sq[ids] * proj.cov2d[ids, 0]).sqrt() + 1  # the ellipse's bounding box, a pixel to spare
    half_y = (reach_sq[ids] * proj.cov2d[ids, 2]).sqrt() + 1
    tiles_x, tiles_y = math.ceil(width / TILE), math.ceil(height / TILE)
    x_lo, x_hi, y_lo, y_hi = tile_ranges(proj.means2d[ids], half_x, half_y, tiles_x, tiles_y)
    local_y, local_x = torch.meshgrid(torch.arange(TILE), torch.arange(TILE), indexing="ij")
    pairs = 0
    for ty in range(tiles_y):
        for tx in range(tiles_x):
            inside = ((tx * TILE + local_x < width) & (ty * TILE + local_y < height)).reshape(-1)
            hit = ids[(x_lo <= tx) & (x_hi >= tx) & (y_lo <= ty) & (y_hi >= ty)]
            pairs += int((tile_weights(proj, hit, opacities, tx, ty)[:, inside] > 0).sum())
    return pairs


# ---------------------------------------------------------------------------------------------


def record_footprint_times(package: str = "splatu") -> list[float]:
    """Make `package`'s rasterizer record the wall time of each footprint pass (block_entries) into the
    returned list."""
    module = importlib.import_module(f"{package}.rasterizer.rasterize")
    block_entries, spent = module.block_entries, []

    def timed(*args):
        start = time.perf_counter()
        entries = block_entries(*args)
        spent.append(time.perf_counter() - start)
        return entries

    module.block_entries = timed
    return spent


def peak_rss_mb() -> float:
    """This process's own peak resident set, MB (Linux's VmHWM): ru_maxrss would also hold the peak of the
    parent that spawned it, which Linux carries across fork and exec."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM line in /proc/self/status")


def time_runs(case: Case, implementation: str, runs: int) -> dict:
    """Median forward/backward (and, for ours, footprint) wall times of `runs` renders after one warm-up
    (runs=0: the one render itself), and this process's peak RSS."""
    from splatu.rasterizer import rasterize

    scene = make_scene(case)
    footprint_seconds = record_footprint_times() if implementation == "ours" else []
    forward_ms, backward_ms, pairs = [], [], 0
    for run in range(runs + 1):
        leaves = [t.clone().requires_grad_(i < 5) for i, t in enumerate(scene)]
        start = time.perf_counter()
        if implementation == "ours":
            out = rasterize(*leaves, case.width, case.height, log_scales=True)
            image, alpha, pairs = out.image, out.alpha, out.num_contributing_pairs
        else:
            image, alpha, pairs = reference_rasterize(*leaves, case.width, case.height)
        middle = time.perf_counter()
        loss_of(image, alpha).backward()
        end = time.perf_counter()
        if run > 0 or runs == 0:
            forward_ms.append(1e3 * (middle - start))
            backward_ms.append(1e3 * (end - middle))
    timed_footprints = footprint_seconds[1:] if runs else footprint_seconds
    return {
        "ms_forward": statistics.median(forward_ms),
        "ms_backward": statistics.median(backward_ms),
        "ms_footprint": 1e3 * statistics.median(timed_footprints) if timed_footprints else None,
        "pairs": pairs,  # ours: contributing pairs; the baseline: the candidate pairs it evaluates
        "peak_rss_mb": peak_rss_mb(),
    }


def run_worker(case_index: int, implementation: str, runs: int, compile_kernels: bool, threads: int,
               malloc_defaults: bool) -> dict:
    """Measure one (case, implementation) in a fresh subprocess; returns its JSON result (case -1: quick)."""
    cmd = [sys.executable, __file__, "--worker", implementation, "--case", str(case_index), "--runs", str(runs),
           "--threads", str(threads)]
    if compile_kernels:
        cmd.append("--compile")
    if malloc_defaults:
        cmd.append("--malloc-defaults")
    done = subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=REPO)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="only a 3k-Gaussian 128x96 case, one run each (< 60 s)")
    parser.add_argument("--reference-all", action="store_true",
                        help="also time the baseline on the 100k case (slow, several GB); default: 20k case only")
    parser.add_argument("--json", type=Path, default=REPO / "benchmarks" / "results" / "rasterizer.json",
                        help="where to write the results")
    parser.add_argument("--compile", action="store_true", help="run our kernels through torch.compile")
    parser.add_argument("--runs", type=int, default=3, help="timed runs per measurement (after one warm-up)")
    parser.add_argument("--threads", type=int, default=0,
                        help="torch threads in each measurement (0: torch's default); 1 is steadier on a busy machine")
    parser.add_argument("--malloc-defaults", action="store_true",
                        help="leave glibc malloc's thresholds at their defaults (splatu's commands fix them)")
    parser.add_argument("--worker", choices=["ours", "reference", "count"], help=argparse.SUPPRESS)
    parser.add_argument("--case", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args()

    if args.worker:
        if args.threads:
            torch.set_num_threads(args.threads)
        if not args.malloc_defaults:
            keep_freed_memory()  # as in training and every splatu command
        if args.compile:
            from splatu.rasterizer.kernels import set_compile

            set_compile(True)
        case = QUICK_CASE if args.case < 0 else CASES[args.case]
        if args.worker == "count":
            print(json.dumps({"pairs": count_contributing_pairs(*make_scene(case), case.width, case.height)}))
            return
        start = time.perf_counter()
        result = time_runs(case, args.worker, args.runs)
        result["seconds_total"] = time.perf_counter() - start
        print(json.dumps(result))
        return

    cases = [(-1, QUICK_CASE)] if args.quick else list(enumerate(CASES))
    runs = 0 if args.quick else args.runs
    results = []
    for index, case in cases:
        ours = run_worker(index, "ours", runs, args.compile, args.threads, args.malloc_defaults)
        ours_total = ours["ms_forward"] + ours["ms_backward"]
        pairs = run_worker(index, "count", 0, False, args.threads, args.malloc_defaults)["pairs"]
        reference = None
        if index <= 0 or args.reference_all:
            reference = run_worker(index, "reference", runs, False, args.threads,
                                   args.malloc_defaults)
        results.append({
            "name": case.name,
            "gaussians": case.gaussians,
            "width": case.width,
            "height": case.height,
            "ms_forward": round(ours["ms_forward"], 1),
            "ms_backward": round(ours["ms_backward"], 1),
            "ms_footprint": None if ours["ms_footprint"] is None else round(ours["ms_footprint"], 1),
            "contributing_pairs": pairs,
            "ours_contributing_pairs": ours["pairs"],
            "ns_per_pair": round(1e6 * ours_total / max(pairs, 1), 1),
            "speedup_vs_reference": None if reference is None else round(
                (reference["ms_forward"] + reference["ms_backward"]) / ours_total, 2),
            "peak_rss_mb": round(ours["peak_rss_mb"], 1),
            "reference_ms_forward_plus_backward": None if reference is None else round(
                reference["ms_forward"] + reference["ms_backward"], 1),
            "reference_peak_rss_mb": None if reference is None else round(reference["peak_rss_mb"], 1),
            "reference_candidate_pairs": None if reference is None else reference["pairs"],
            "reference_ns_per_candidate_pair": None if reference is None else round(
                1e6 * (reference["ms_forward"] + reference["ms_backward"]) / max(reference["pairs"], 1), 1),
            "kernels": "torch.compile" if args.compile else "eager",
            "malloc": "glibc defaults" if args.malloc_defaults else "splatu.allocator",
            "threads": args.threads or torch.get_num_threads(),
            "first_call_seconds": round(ours["seconds_total"] - (runs * ours_total) / 1e3, 1),
        })
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"cases": results, "measured_on": measured_on()}, indent=2) + "\n")
    keys = ["ms_forward", "ms_footprint", "ms_backward", "contributing_pairs", "ns_per_pair", "speedup_vs_reference",
            "peak_rss_mb"]
    print(f"{'case':<28}" + "".join(f"{k:>22}" for k in keys))
    for r in results:
        print(f"{r['name']:<28}" + "".join(f"{r[k]!s:>22}" for k in keys))
    print(f"kernels: {results[0]['kernels']}; written to {args.json}")


if __name__ == "__main__":
    main()
