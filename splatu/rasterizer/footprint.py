"""Which pixels each Gaussian can reach, as depth-ordered lists per image row segment ("block").

A Gaussian can only pass the α ≥ 1/255 test where σ ≤ ln(255·o), an ellipse. We cut that ellipse
into exact per-row x-intervals, then into blocks of `block_width` pixels of one row. The output is a
list of (block, Gaussian) entries sorted by block and, within a block, by (depth, index), the
order in which the pixels of that block must composite their Gaussians. Entries are far fewer than
pixel–Gaussian pairs (about one per row per `block_width` pixels), so this sort is cheap, and the
compositor evaluates each entry densely over the block's pixels without any per-pair sort.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0
"""3DGS skips a Gaussian at a pixel where its α is below this."""

FOOTPRINT_SLACK = 1e-4
"""Relative widening of the exact footprint so rounding never drops a pair; extra pairs fail the α test."""


@dataclass
class BlockEntries:
    """(block, Gaussian) entries sorted by (block, depth, index); one block = `block_width` pixels of a row."""

    gaussian: Tensor  # (Q,) int64 Gaussian index into the full (N,) arrays
    block: Tensor  # (Q,) int64 block id = row * blocks_per_row + column block
    block_start: Tensor  # (Q,) int64 position in the entry list of the first entry of the same block
    block_last: Tensor  # (Q,) int64 position of the last entry of the same block
    block_width: int
    blocks_per_row: int
    num_blocks: int


def block_entries(
    means2d: Tensor, cov2d: Tensor, det: Tensor, opacities: Tensor, depths: Tensor, visible: Tensor,
    width: int, height: int, block_width: int,
) -> BlockEntries:
    """List, for every block of pixels, the Gaussians whose α ≥ 1/255 region touches it, front to back."""
    blocks_per_row = (width + block_width - 1) // block_width
    with torch.no_grad():
        f64 = torch.float64
        o = opacities.to(f64)
        candidate = visible & (o * 255.0 >= 1.0)
        ids = torch.nonzero(candidate).squeeze(1)
        order = torch.sort(depths.to(f64)[ids], stable=True).indices  # ties keep index order
        ids = ids[order]

        mx, my = means2d[ids, 0].to(f64), means2d[ids, 1].to(f64)
        _, cxy, cyy = cov2d[ids].unbind(-1)
        det_g = det[ids]
        s = torch.log(o[ids] * 255.0).clamp_min(0.0) * (1 + FOOTPRINT_SLACK) + FOOTPRINT_SLACK

        # Rows whose pixel centre y + 0.5 lies within the ellipse's vertical extent.
        ry = torch.sqrt(2.0 * s * cyy)
        y_lo = torch.ceil((my - ry - 0.5).clamp(-1.0, height + 1.0)).clamp(0, height).long()
        y_hi = torch.floor((my + ry - 0.5).clamp(-2.0, height)).clamp(-1, height - 1).long()
        rows_per = (y_hi - y_lo + 1).clamp_min(0)
        rec_g, rec_local = _expand(rows_per)
        y = y_lo[rec_g] + rec_local

        # Exact x-interval of the ellipse on each row.
        dy = y.to(f64) + 0.5 - my[rec_g]
        half = torch.sqrt(((2.0 * s[rec_g] * cyy[rec_g] - dy * dy) * det_g[rec_g]).clamp_min(0.0)) / cyy[rec_g]
        xc = mx[rec_g] + cxy[rec_g] / cyy[rec_g] * dy
        x_lo = torch.ceil((xc - half - 0.5).clamp(-1.0, width + 1.0)).clamp(0, width).long()
        x_hi = torch.floor((xc + half - 0.5).clamp(-2.0, width)).clamp(-1, width - 1).long()
        j_lo = torch.div(x_lo, block_width, rounding_mode="floor")
        j_hi = torch.div(x_hi, block_width, rounding_mode="floor")
        blocks_per = torch.where(x_hi >= x_lo, j_hi - j_lo + 1, torch.zeros_like(j_lo))
        ent_rec, ent_local = _expand(blocks_per)
        block = y[ent_rec] * blocks_per_row + j_lo[ent_rec] + ent_local
        gaussian_rank = rec_g[ent_rec]  # entries are generated in depth order

        by_block = torch.argsort(block.to(torch.int32), stable=True)  # block ids < H·W: int32 sorts faster
        block = block[by_block]
        gaussian = ids[gaussian_rank[by_block]]
        num_blocks = height * blocks_per_row
        counts = torch.bincount(block, minlength=num_blocks)
        starts = torch.cumsum(counts, 0) - counts
        block_start = starts.index_select(0, block)
        block_last = block_start + counts.index_select(0, block) - 1
    return BlockEntries(
        gaussian=gaussian, block=block, block_start=block_start, block_last=block_last,
        block_width=block_width, blocks_per_row=blocks_per_row, num_blocks=num_blocks,
    )


def _expand(counts: Tensor) -> tuple[Tensor, Tensor]:
    """For counts (M,), the owner index and the 0-based position within the owner of each of sum(counts) items."""
    owner = torch.repeat_interleave(torch.arange(counts.numel(), device=counts.device), counts)
    first = torch.cumsum(counts, 0) - counts
    return owner, torch.arange(owner.numel(), device=counts.device) - first[owner]
