"""Render time with compiled kernels when one process alternates float32 and float64 and the channel count.

    .venv/bin/python benchmarks/mixed_dtypes.py [--rounds 6]

Each round renders (forward + backward) 2,000 random Gaussians at 128x96 with 1 to 5 feature channels, each in
float32 then float64: ten variants, each a graph of the backward kernels, as training (float32), the baselines'
extra features and float64 renders give one process. It prints the median time of each variant over every round
but the first (which compiles) and whether dynamo hit its recompile limit, past which it runs a kernel eager.
Run it at two commits to compare them.
"""

from __future__ import annotations

import logging
import statistics
import time
from dataclasses import dataclass

import torch
import tyro

from splatu.rasterizer import rasterize
from splatu.rasterizer.kernels import set_compile

WIDTH, HEIGHT, GAUSSIANS, FOCAL = 128, 96, 2000, 100.0


@dataclass
class Args:
    rounds: int = 6
    """Rounds of the ten variants; the first compiles and is not timed."""


class LimitHits(logging.Handler):
    """Collects the functions dynamo names when it hits its recompile limit (it says so only in its log)."""

    def __init__(self) -> None:
        super().__init__()
        self.functions: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        lines = record.getMessage().splitlines()
        if "recompile_limit" in lines[0] and len(lines) > 1:
            self.functions.append(lines[1].strip())


def scene(generator: torch.Generator) -> dict[str, torch.Tensor]:
    """Gaussians a few px wide spread over the view of an identity camera, float64."""
    depth = 3.0 + 2.0 * torch.rand(GAUSSIANS, generator=generator, dtype=torch.float64)
    spread = torch.tensor([WIDTH, HEIGHT], dtype=torch.float64) * 0.8 / FOCAL
    xy = (torch.rand(GAUSSIANS, 2, generator=generator, dtype=torch.float64) - 0.5) * spread * depth[:, None]
    return {
        "means": torch.cat([xy, depth[:, None]], dim=1),
        "quats": torch.randn(GAUSSIANS, 4, generator=generator, dtype=torch.float64),
        "scales": (1.0 + 3.0 * torch.rand(GAUSSIANS, 3, generator=generator, dtype=torch.float64))
        * depth[:, None] / FOCAL,
        "opacities": 0.3 + 0.5 * torch.rand(GAUSSIANS, generator=generator, dtype=torch.float64),
        "features": torch.rand(GAUSSIANS, 1, generator=generator, dtype=torch.float64),
    }


def render_seconds(base: dict[str, torch.Tensor], channels: int, dtype: torch.dtype) -> float:
    """One forward + backward render of `base` with `channels` feature channels in `dtype`."""
    leaves = {name: value.to(dtype) for name, value in base.items()}
    leaves["features"] = leaves["features"].repeat(1, channels)
    for value in leaves.values():
        value.requires_grad_(True)
    intrinsics = torch.tensor([[FOCAL, 0, WIDTH / 2], [0, FOCAL, HEIGHT / 2], [0, 0, 1]], dtype=torch.float64)
    started = time.perf_counter()
    out = rasterize(leaves["means"], leaves["quats"], leaves["scales"], leaves["opacities"], leaves["features"],
                    torch.eye(4, dtype=torch.float64), intrinsics, WIDTH, HEIGHT,
                    background=torch.zeros(channels, dtype=dtype))
    (out.image.sum() + out.alpha.sum() + out.depth.sum()).backward()
    return time.perf_counter() - started


def main(args: Args) -> None:
    hits = LimitHits()
    logging.getLogger("torch._dynamo").addHandler(hits)
    set_compile(True)
    base = scene(torch.Generator().manual_seed(0))
    times: dict[tuple[int, str], list[float]] = {}
    for round_index in range(args.rounds):
        for channels in range(1, 6):
            for dtype in (torch.float32, torch.float64):
                seconds = render_seconds(base, channels, dtype)
                if round_index > 0:
                    times.setdefault((channels, str(dtype).removeprefix("torch.")), []).append(seconds)
    print("dynamo's recompile limit hit in:", ", ".join(hits.functions) or "none")
    for (channels, dtype), seconds in times.items():
        print(f"{channels} channels {dtype}: median {1000 * statistics.median(seconds):.1f} ms")
    medians = [statistics.median(seconds) for seconds in times.values()]
    print(f"median of the variants' medians: {1000 * statistics.median(medians):.1f} ms")


if __name__ == "__main__":
    main(tyro.cli(Args))
