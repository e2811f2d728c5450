"""Which pixels each Gaussian can reach, as depth-ordered lists per image row segment ("block").

A Gaussian can only pass the α ≥ 1/255 test where σ ≤ ln(255·o), an ellipse. We cut that ellipse
into exact per-row x-intervals, then into blocks of `block_width` pixels of one row. The entries
(block, Gaussian) are ordered by depth round (an equal slab of the depth order), then block, then
depth. Entries are far fewer than pixel–Gaussian pairs (about one per row per `block_width`
pixels), and they are sorted one round at a time, by block alone (see block_entries). Rounds let
the compositor skip the deeper part of a block's list once all of its pixels have terminated,
which in a deep scene is most of it.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch
from torch import Tensor

from splatu.rasterizer.errors import RasterInputError
from splatu.rasterizer.kernels import kernel

FOOTPRINT_SLACK = 1e-4
"""Relative widening of the exact footprint so rounding never drops a pair; extra pairs fail the α test."""

MAX_ENTRIES = torch.iinfo(torch.int32).max
"""Entries and row records are counted with int32 indices (see _expand)."""


MAX_ROUNDS = 16
ROUND_MIN_ENTRIES = 1 << 18
"""Depth rounds: equal slabs of the depth order, at most MAX_ROUNDS and at least ROUND_MIN_ENTRIES
entries per round on average, because each round has a fixed cost (about a dozen small ops and
kernel launches per chunk) that rivals its work below that size. Measured on the benchmark scenes
(benchmarks/rasterizer.py), in evaluated pixel–Gaussian elements per contributing pair: 20k case
1.72 with its 4 rounds (2.36 in one round), 100k case 1.54 with 16 (3.83 in one). A training render of
the poster stand-in (~300k entries) is one round, so rounds neither help nor cost there."""


@dataclass
class BlockEntries:
    """(block, Gaussian) entries sorted by (depth round, block, depth, index); one block = `block_width` pixels."""

    gaussian: Tensor  # (Q,) int64 Gaussian index into the full (N,) arrays
    block: Tensor  # (Q,) int64 block id = row * blocks_per_row + column block
    round_bounds: list[int]  # entries [round_bounds[r], round_bounds[r + 1]) form depth round r
    block_width: int
    blocks_per_row: int
    num_blocks: int


def block_entries(
    means2d: Tensor, cov2d: Tensor, det: Tensor, opacities: Tensor, depths: Tensor, visible: Tensor,
    width: int, height: int, block_width: int,
) -> BlockEntries:
    """List, for every block of pixels, the Gaussians whose α ≥ 1/255 region touches it, front to back."""
    blocks_per_row = (width + block_width - 1) // block_width
    num_blocks = height * blocks_per_row
    with torch.no_grad():
        f64 = torch.float64
        o = opacities.to(f64)
        candidate = visible & (o * 255.0 >= 1.0)
        ids = torch.nonzero(candidate).squeeze(1)
        order = torch.sort(depths.to(f64)[ids], stable=True).indices  # ties keep index order
        ids = ids.index_select(0, order)

        mx, my = means2d.index_select(0, ids).to(f64).unbind(1)
        _, cxy, cyy = cov2d.index_select(0, ids).unbind(-1)
        det_g = det.index_select(0, ids)
        s = torch.log(o.index_select(0, ids) * 255.0).clamp_min(0.0) * (1 + FOOTPRINT_SLACK) + FOOTPRINT_SLACK

        # Rows whose pixel centre y + 0.5 lies within the ellipse's vertical extent.
        ry = torch.sqrt(2.0 * s * cyy)
        y_lo = torch.ceil((my - ry - 0.5).clamp(-1.0, height + 1.0)).clamp(0, height).long()
        y_hi = torch.floor((my + ry - 0.5).clamp(-2.0, height)).clamp(-1, height - 1).long()
        rec_g, y = _expand(y_lo, (y_hi - y_lo + 1).clamp_min(0))
        j_lo, blocks_per = kernel("row_block_spans")(
            y, rec_g, mx, my, 2.0 * s * cyy, det_g / cyy.square(), cxy / cyy, width, block_width
        )

        # Entries come out in depth order, so a depth round is a contiguous run of them, and a stable
        # sort of each round by block alone leaves every block's list front to back. torch's CPU sort
        # of a 1-D integer tensor of ≥ 32,768 elements is a parallel radix sort, one pass per key
        # byte, and one round's keys fit in cache. The change from one int64 sort of all 6.3M entries of
        # the 100k benchmark case to a sort per round (which also fused the row spans) took its footprint
        # pass alone to 0.18–0.24× the time. int16 keys (any image of < 32,768 blocks) halve the passes
        # again: a stable sort of 395k keys took 2.65 ms as int16 against 5.03 ms as int32 (scratch
        # timings, torch 2.13 CPU, 2 threads; docs/results.md).
        ent_rec, unsorted_block = _expand((y * blocks_per_row + j_lo).int(), blocks_per)
        rounds = max(1, min(MAX_ROUNDS, ent_rec.numel() // ROUND_MIN_ENTRIES))
        depth_round = torch.div(torch.arange(ids.numel(), device=ids.device) * rounds, max(1, ids.numel()),
                                rounding_mode="floor")
        per_round = torch.zeros(rounds, dtype=torch.long, device=ids.device)
        per_round.index_add_(0, depth_round.index_select(0, rec_g), blocks_per)
        round_bounds = [0, *torch.cumsum(per_round, 0).tolist()]
        unsorted_gaussian = ids.int().index_select(0, rec_g).index_select(0, ent_rec)
        key = unsorted_block.short() if num_blocks <= torch.iinfo(torch.int16).max else unsorted_block
        block = torch.empty(round_bounds[-1], dtype=torch.long, device=ids.device)
        gaussian = torch.empty_like(block)
        for begin, end in itertools.pairwise(round_bounds):
            sorted_block, order = torch.sort(key[begin:end], stable=True)
            block[begin:end] = sorted_block
            gaussian[begin:end] = unsorted_gaussian[begin:end].index_select(0, order)
    return BlockEntries(
        gaussian=gaussian, block=block, round_bounds=round_bounds,
        block_width=block_width, blocks_per_row=blocks_per_row, num_blocks=num_blocks,
    )


def _expand(start: Tensor, counts: Tensor) -> tuple[Tensor, Tensor]:
    """Ranges start[m], start[m] + 1, … of counts[m] items each, concatenated: (owner m, value) per item.

    The value is start[owner] + (item − first item of owner), computed as one gather of start − first
    plus the item index, in start's dtype. The owners are int32: torch's repeat_interleave making 5.7M owners
    took 21 ms as int32 against 61–83 ms as int64 (scratch timings, torch 2.13 CPU; docs/results.md).
    """
    total = int(counts.sum())
    if total > MAX_ENTRIES:
        raise RasterInputError(
            f"the footprints of the Gaussians make {total:,} entries, more than the {MAX_ENTRIES:,} int32 indices hold",
            "in the call to rasterize",
            "render at a lower resolution, or with fewer or smaller Gaussians",
        )
    owner = torch.repeat_interleave(counts.int(), output_size=total)
    shifted = (start - (torch.cumsum(counts, 0) - counts)).to(start.dtype)
    return owner, shifted.index_select(0, owner) + torch.arange(total, dtype=start.dtype, device=start.device)
