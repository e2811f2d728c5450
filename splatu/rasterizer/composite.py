"""Front-to-back alpha compositing over block entries, with an analytic backward.

Entries (see footprint.py) are sorted by (block, depth). Evaluating every entry at the
`block_width` pixels of its block gives a (B, Q) matrix whose row x, over a block's entries, is
exactly that pixel's depth-ordered Gaussian list. Transmittance is then a segmented exclusive
cumulative sum of log(1 − α) along q (float64, so long lists keep precision), and 3DGS's early
stop is the mask "inclusive log T ≥ ln 1e-4" (monotone along a list).

The backward is the closed form of the 3DGS one, vectorised: for a pixel's loss
L = Σ_i w_i g_i + T_final h, with g_i = gC·f_i + g_alpha + g_depthnum·z_i and h = gC·background,
dL/dα_i = T_i g_i − (S_i + T_final h) / (1 − α_i), where S_i = Σ_{j behind i} w_j g_j.
Entries are processed in chunks of whole blocks so that peak memory stays bounded.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
from torch import Tensor

from splatu.rasterizer.footprint import BlockEntries
from splatu.rasterizer.kernels import kernel


@dataclass
class GaussianParams:
    """Per-Gaussian screen-space quantities the compositor reads, all (N, ·) in one dtype."""

    means2d: Tensor
    conics: Tensor
    opacities: Tensor
    features_ext: Tensor  # (N, C+2): features, depth z, 1


@dataclass
class PixelAccumulators:
    """Per-pixel Σ w·f_ext in block layout (B, num_blocks, C+2) and per-Gaussian contributions (N,)."""

    image_ext: Tensor
    contrib_sum: Tensor
    contrib_max: Tensor
    pairs: int = 0


@dataclass
class GaussianGrads:
    """Gradient accumulators (N, ·) for the compositor's inputs, plus the absgrad side output."""

    means2d: Tensor
    conics: Tensor
    opacities: Tensor
    features_ext: Tensor
    absgrad: Tensor


@dataclass
class ChunkState:
    """What one chunk's forward leaves for its backward."""

    start: int
    end: int
    transmittance: Tensor  # (B, Q) T before each pair, 0 where the pair does not contribute
    alpha_raw: Tensor  # (B, Q) o·exp(−σ) before the 0.99 clamp


@dataclass
class EntryView:
    """Entries [start, end) with their Gaussians' screen-space parameters gathered per entry."""

    gaussian: Tensor
    block: Tensor
    block_start: Tensor  # local to the chunk
    block_last: Tensor  # local to the chunk
    u: Tensor
    dy: Tensor
    conic: Tensor
    opacity: Tensor
    in_image_cols: Tensor


def chunk_bounds(entries: BlockEntries, max_elements: int) -> list[tuple[int, int]]:
    """Split the entry list into slices of whole blocks with about max_elements (Q·B) each."""
    total = entries.block.numel()
    rows = max(1, max_elements // entries.block_width)
    bounds, pos = [], 0
    while pos < total:
        end = min(pos + rows, total)
        if end < total:
            start_of_block = int(entries.block_start[end])
            end = start_of_block if start_of_block > pos else int(entries.block_last[end]) + 1
        bounds.append((pos, end))
        pos = end
    return bounds


def view_entries(entries: BlockEntries, start: int, end: int, g: GaussianParams, width: int) -> EntryView:
    gaussian = entries.gaussian[start:end]
    block = entries.block[start:end]
    dtype = g.means2d.dtype
    x0 = (block % entries.blocks_per_row) * entries.block_width
    row = torch.div(block, entries.blocks_per_row, rounding_mode="floor")
    mean = g.means2d.index_select(0, gaussian)
    return EntryView(
        gaussian=gaussian,
        block=block,
        block_start=entries.block_start[start:end] - start,
        block_last=entries.block_last[start:end] - start,
        u=x0.to(dtype) + 0.5 - mean[:, 0],
        dy=row.to(dtype) + 0.5 - mean[:, 1],
        conic=g.conics.index_select(0, gaussian),
        opacity=g.opacities.index_select(0, gaussian),
        in_image_cols=width - x0,
    )


def forward_chunk(
    entries: BlockEntries, start: int, end: int, g: GaussianParams, width: int, acc: PixelAccumulators
) -> ChunkState:
    """Composite entries [start, end) into the accumulators; return what the backward needs."""
    v = view_entries(entries, start, end, g, width)
    alpha_raw, log_one_minus = kernel("alpha_and_log_one_minus")(
        v.u, v.dy, v.conic, v.opacity, v.in_image_cols, entries.block_width
    )
    cumulative = torch.cumsum(log_one_minus, 1)
    transmittance, weight, weight_sum, weight_max = kernel("blend")(log_one_minus, cumulative, v.block_start, alpha_raw)
    first, last = int(v.block[0]), int(v.block[-1])
    acc.image_ext[:, first : last + 1] += _sum_per_pixel(weight, v.block - first, last - first + 1,
                                                         g.features_ext.index_select(0, v.gaussian))
    acc.contrib_sum.index_add_(0, v.gaussian, weight_sum)
    acc.contrib_max.scatter_reduce_(0, v.gaussian, weight_max, reduce="amax")
    acc.pairs += int(torch.count_nonzero(transmittance))
    return ChunkState(start, end, transmittance, alpha_raw)


def _sum_per_pixel(weight: Tensor, local_block: Tensor, num_blocks: int, features_ext: Tensor) -> Tensor:
    """Σ over each pixel's entries of w·f_ext, (B, num_blocks, C+2), as one sparse (CSR) × dense product.

    Row (x, b) of the sparse matrix holds w[x, q] for the entries q of block b, which are contiguous,
    so its values are `weight` as stored and no (B, Q, C+2) product is ever materialised (~12× faster
    than a scatter-add of that product, measured).
    """
    block_width, entries = weight.shape
    counts = torch.bincount(local_block, minlength=num_blocks)
    starts = torch.cumsum(counts, 0) - counts
    offsets = torch.arange(block_width, device=weight.device)[:, None] * entries
    crow = torch.cat([(offsets + starts).reshape(-1), torch.tensor([block_width * entries], device=weight.device)])
    cols = torch.arange(entries, device=weight.device).repeat(block_width)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta state")
        matrix = torch.sparse_csr_tensor(crow, cols, weight.reshape(-1), size=(block_width * num_blocks, entries),
                                         check_invariants=False)
    return (matrix @ features_ext).reshape(block_width, num_blocks, -1)


def backward_chunk(
    entries: BlockEntries, state: ChunkState, g: GaussianParams, width: int,
    up_ext: Tensor, behind_background: Tensor, grads: GaussianGrads,
) -> None:
    """Accumulate the gradient contributions of one chunk's entries into `grads`.

    `up_ext` (B, num_blocks, C+2) holds the upstream gradients of colour, Σ w·z and alpha per pixel;
    `behind_background` (B, num_blocks) is T_final · (gC · background).
    """
    v = view_entries(entries, state.start, state.end, g, width)
    per_weight, weighted, grad_features_ext = kernel("upstream_per_weight")(
        up_ext, v.block, state.transmittance, state.alpha_raw, g.features_ext.index_select(0, v.gaussian)
    )
    grads.features_ext.index_add_(0, v.gaussian, grad_features_ext)
    weighted_cumulative = torch.cumsum(weighted, 1)
    grad_opacity, m0, m1, m2, abs_x, abs_y = kernel("entry_gradients")(
        weighted_cumulative, v.block_last, v.block, behind_background,
        state.transmittance, state.alpha_raw, per_weight, v.u, v.dy, v.conic, v.opacity,
    )
    a, b, c = v.conic.unbind(-1)
    dy = v.dy
    grads.opacities.index_add_(0, v.gaussian, grad_opacity)
    grads.conics.index_add_(0, v.gaussian, torch.stack([0.5 * m2, dy * m1, 0.5 * dy * dy * m0], dim=-1))
    grads.means2d.index_add_(0, v.gaussian, torch.stack([-(a * m1 + b * dy * m0), -(b * m1 + c * dy * m0)], dim=-1))
    grads.absgrad.index_add_(0, v.gaussian, torch.stack([abs_x, abs_y], dim=-1))
