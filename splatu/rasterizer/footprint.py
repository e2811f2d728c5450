"""Which pixels each Gaussian can reach, as depth-ordered lists per image row segment ("block").

A Gaussian can only pass the α ≥ 1/255 test where σ ≤ ln(255·o), an ellipse. We cut that ellipse
into exact per-row x-intervals, then into blocks of `block_width` pixels of one row. The entries
(block, Gaussian) are listed by depth round (an equal slab of the depth order), and the compositor
takes each round ordered by block, then depth (BlockEntries.round_entries). Entries are far fewer
than pixel–Gaussian pairs (about one per row per `block_width` pixels). Rounds let the compositor
skip the deeper part of a block's list once all of its pixels have terminated, which in a deep scene
is most of it; those entries are then never sorted.
"""

from __future__ import annotations

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
    """(block, Gaussian) entries in depth rounds, each round in depth order; `round_entries` sorts one by block.

    A round is sorted only when the compositor reaches it, and only on the blocks it still has to composite: in a
    deep scene most of the later rounds' entries lie on blocks whose pixels have all terminated, and they are never
    sorted or gathered (on the 100k benchmark case, 3.8M of the 6.3M entries)."""

    key: Tensor  # (Q,) block id = row * blocks_per_row + column block: int16 below 32,768 blocks, else int32
    gaussian: Tensor  # (Q,) int32 Gaussian index into the full (N,) arrays
    round_bounds: list[int]  # entries [round_bounds[r], round_bounds[r + 1]) form depth round r
    block_width: int
    blocks_per_row: int
    num_blocks: int

    def round_entries(self, r: int, keep_block: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Round r's entries on the blocks `keep_block` marks (bool per block; None: every block), sorted by block and
        front to back within one (a stable sort of depth-ordered entries): block ids and Gaussians, int64 (the
        compositor's index ops ran slower with int32 indices)."""
        begin, end = self.round_bounds[r], self.round_bounds[r + 1]
        key, gaussian = self.key[begin:end], self.gaussian[begin:end]
        if keep_block is not None:
            kept = torch.nonzero(keep_block.index_select(0, key.int())).squeeze(1)
            if kept.numel() < key.numel():
                key, gaussian = key.index_select(0, kept), gaussian.index_select(0, kept)
        # torch's CPU sort of a 1-D integer tensor of ≥ 32,768 elements is a parallel radix sort, one pass per key
        # byte, and one round's keys fit in cache. int16 keys (any image of < 32,768 blocks) halve the passes: a
        # stable sort of 395k keys took 2.65 ms as int16 against 5.03 ms as int32 (scratch timings, torch 2.13 CPU,
        # 2 threads; docs/results.md).
        block, order = torch.sort(key, stable=True)
        return block.long(), gaussian.index_select(0, order).long()


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

        # Entries come out in depth order, so a depth round is a contiguous run of them, and a stable sort of
        # each round by block alone (BlockEntries.round_entries) leaves every block's list front to back. The
        # change from one int64 sort of all 6.3M entries of the 100k benchmark case to a sort per round (which
        # also fused the row spans) took its footprint pass alone to 0.18–0.24× the time (docs/results.md).
        ent_rec, unsorted_block = _expand((y * blocks_per_row + j_lo).int(), blocks_per)
        rounds = max(1, min(MAX_ROUNDS, ent_rec.numel() // ROUND_MIN_ENTRIES))
        depth_round = torch.div(torch.arange(ids.numel(), device=ids.device) * rounds, max(1, ids.numel()),
                                rounding_mode="floor")
        per_round = torch.zeros(rounds, dtype=torch.long, device=ids.device)
        per_round.index_add_(0, depth_round.index_select(0, rec_g), blocks_per)
        round_bounds = [0, *torch.cumsum(per_round, 0).tolist()]
        gaussian = ids.int().index_select(0, rec_g).index_select(0, ent_rec)
        key = unsorted_block.short() if num_blocks <= torch.iinfo(torch.int16).max else unsorted_block
    return BlockEntries(
        key=key, gaussian=gaussian, round_bounds=round_bounds,
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
