"""Front-to-back alpha compositing over block entries, with an analytic backward.

Entries (see footprint.py) are sorted by (depth round, block, depth). Evaluating every entry at the
`block_width` pixels of its block gives a (B, Q) matrix whose row x, over a block's entries, is
exactly that pixel's depth-ordered Gaussian list. Transmittance is then a segmented exclusive
cumulative sum of log(1 − α) along q (float64, so long lists keep precision), and 3DGS's early
stop is the mask "inclusive log T ≥ ln 1e-4" (monotone along a list).

A block's list is composited in depth rounds (see footprint.py), in chunks of bounded size. Each
pixel carries its log T from one chunk to the next, so a block whose pixels have all terminated is
dropped from later rounds: exact, because its remaining pairs could only fail the stop test.

The backward is the closed form of the 3DGS one, vectorised: for a pixel's loss
L = Σ_i w_i g_i + T_final h, with g_i = gC·f_i + g_alpha + g_depthnum·z_i and h = gC·background,
dL/dα_i = T_i g_i − (S_i + T_final h) / (1 − α_i), where S_i = Σ_{j behind i} w_j g_j.
The backward walks the chunks in reverse, carrying each pixel's Σ w g of the chunks behind.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import torch
from torch import Tensor

from splatu.rasterizer.footprint import BlockEntries
from splatu.rasterizer.kernels import LOG_T_MIN, kernel
from splatu.rasterizer.projection import conic_rows

COMPACT_AT_MOST_LIVE = 0.8
"""A chunk's live entries (≥ 1 kept pair) are gathered into compact arrays only when at most this fraction of
its entries is live. The first chunk of a render is often nearly all live (99.98% on the 20k benchmark case),
and there the gathers cost more than the dead entries would. A dead entry adds exact zeros to every sum, as its
w and T are 0 and its inputs finite (`rasterize` refuses NaN and Inf, which would spread as 0·NaN)."""


@dataclass
class GaussianParams:
    """Per-Gaussian screen-space quantities the compositor reads, all (N, ·) in one dtype but `log_conics`."""

    means2d: Tensor
    log_conics: Tensor  # (ln A, S, ln Q), float64, see projection.py
    swapped: Tensor  # (N,) bool: cov_xx > cov_yy, so (v, w) = (dy, dx) in the sheared form (projection.py)
    opacities: Tensor
    features_ext: Tensor  # (N, C+2): features, depth z, 1

    @functools.cached_property
    def conic_planes(self) -> Tensor:
        """(3, N): the rows A, S, Q in the render's dtype, each contiguous, made once per render. A compiled kernel
        reading a (Q, 3) conic's columns loads them one by one at stride 3, inside its loop over the block's pixels:
        the backward's entry_gradients took 9.9 against 6.2 ms per trained-model render for that alone (a scratch
        timing)."""
        return conic_rows(self.log_conics, self.means2d.dtype)


@dataclass
class PixelAccumulators:
    """Per-pixel Σ w·f_ext in block layout (B, num_blocks, C+2) and per-Gaussian contributions (N,); the summed
    contributions are float64 until the render ends."""

    image_ext: Tensor
    contrib_sum: Tensor
    contrib_max: Tensor
    pairs: int = 0


@dataclass
class GaussianGrads:
    """Gradient accumulators for the compositor's inputs, packed channel-first (C+2 + 1 + 3 + 2 + 2, N) so that
    each chunk scatters into them once, along N: features_ext | opacity | log conic | means2d | absgrad.
    torch's CPU index_add_ of (Q, 13) rows along dim 0 took 8× the time of the same values as (13, Q) along
    dim 1 (35.6 against 4.2 ms for 900k entries into 20k Gaussians, a scratch timing)."""

    packed: Tensor

    WIDTHS = (1, 3, 2, 2)
    """Rows after the C+2 feature gradients: opacity, (ln A, S, ln Q), means2d, absgrad."""

    @classmethod
    def zeros(cls, like: Tensor, channels_ext: int) -> GaussianGrads:
        """Zero accumulators for the N Gaussians of `like` (N, ·), in its dtype and device."""
        return cls(like.new_zeros(channels_ext + sum(cls.WIDTHS), like.shape[0]))

    def split(self, channels_ext: int) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """(features_ext, opacities, log_conics, means2d, absgrad) as (N, ·) views."""
        f, o, c, m, a = self.packed.split([channels_ext, *self.WIDTHS], dim=0)
        return f.t(), o.squeeze(0), c.t(), m.t(), a.t()


@dataclass
class EntryView:
    """Some entries (a chunk, or its live subset) with their Gaussians' parameters gathered per entry; the last
    dim of every field runs over the entries."""

    gaussian: Tensor
    block: Tensor
    t0: Tensor  # per entry, see kernels.entry_geometry
    w0: Tensor
    p: Tensor
    r: Tensor
    sheared_conic: Tensor  # (3, Q): rows A, S, Q
    opacity: Tensor
    in_image_cols: Tensor

    def subset(self, index: Tensor) -> EntryView:
        """These entries at the ascending positions `index`: a sequential pass over each field, much cheaper
        than gathering the same fields from the Gaussians again by random index."""
        return EntryView(**{f.name: getattr(self, f.name).index_select(-1, index) for f in dataclasses.fields(self)})


@dataclass
class ChunkState:
    """What one chunk's forward leaves for its backward: its live entries (≥ 1 kept pair), or all of its entries
    when nearly all are live."""

    view: EntryView  # those entries, in order, with their offsets, conics and opacities as the forward formed them
    transmittance: Tensor  # (B, Q') T before each pair, 0 where the pair does not contribute
    alpha_raw: Tensor  # (B, Q') o·exp(−σ) before the 0.99 clamp


@dataclass
class Segments:
    """For a block-sorted entry list: each entry's run of equal blocks (segment), and the blocks present."""

    segment: Tensor  # (Q,) index of each entry's run of equal blocks, into the (K,) fields
    blocks: Tensor  # (K,) the distinct blocks, in order
    block_first: Tensor  # (K,) index of each block's first entry
    block_last: Tensor  # (K,) index of each block's last entry


def segments(block: Tensor) -> Segments:
    """The runs of equal block ids in a block-sorted entry list (a chunk, or its live entries)."""
    starts = torch.ones_like(block, dtype=torch.bool)
    starts[1:] = block[1:] != block[:-1]
    block_first = torch.nonzero(starts).squeeze(1)
    sizes = torch.diff(block_first, append=block_first.new_tensor([block.numel()]))
    block_last = block_first + sizes - 1
    which = torch.repeat_interleave(torch.arange(block_first.numel(), device=block.device), sizes)
    return Segments(which, block.index_select(0, block_first), block_first, block_last)


def chunks(
    entries: BlockEntries, log_t: Tensor, in_image: Tensor, max_elements: int,
) -> Iterator[tuple[Tensor, Tensor]]:
    """Yield the (block, Gaussian) ids of the entries to composite, round by round in block order, in pieces of about
    max_elements (Q·B).

    From the second round on, blocks whose in-image pixels all have log T < ln 1e-4 are skipped;
    `log_t` must be up to date with every chunk yielded before (the caller composites in between).
    """
    step = max(1, max_elements // entries.block_width)
    for r in range(len(entries.round_bounds) - 1):
        alive = None if r == 0 else ((log_t >= LOG_T_MIN) & in_image).any(0)
        block, gaussian = entries.round_entries(r, alive)
        for offset in range(0, block.numel(), step):
            yield block[offset : offset + step], gaussian[offset : offset + step]


def columns(values: Tensor, index: Tensor) -> Tensor:
    """values[:, index] for a (B, Q) tensor, as a gather with a broadcast index: torch's CPU index_select
    along dim 1 copies one column at a time, 8× slower picking 8,192 columns of an (8, 320k) float64 chunk."""
    return torch.gather(values, 1, index.expand(values.shape[0], -1))


def view_entries(entries: BlockEntries, block: Tensor, gaussian: Tensor, g: GaussianParams, width: int) -> EntryView:
    t0, w0, p, r, sheared_conic, opacity, in_image_cols = kernel("entry_geometry")(
        block, gaussian, g.means2d, g.conic_planes, g.swapped, g.opacities,
        entries.blocks_per_row, entries.block_width, width,
    )
    return EntryView(gaussian, block, t0, w0, p, r, sheared_conic, opacity, in_image_cols)


def forward_chunk(
    entries: BlockEntries, chunk: tuple[Tensor, Tensor], g: GaussianParams, width: int, acc: PixelAccumulators,
    log_t: Tensor, counted: Tensor | None, keep_state: bool,
) -> ChunkState | None:
    """Composite some entries into the accumulators and advance each pixel's carried log T (B, num_blocks).

    Entries whose pixels have all terminated (or that fail the α test everywhere) keep no pair; even
    within the rounds they are a large part of a chunk. They have w = 0 and zero gradient at every
    pixel, so once the transmittance pass has found them, everything else (image sums,
    contributions, the saved state and the whole backward) runs on the live entries only, unless
    nearly all are live (COMPACT_AT_MOST_LIVE).
    `counted` (B, num_blocks, 0 or 1) limits the contributions to some pixels; the image is unaffected.
    Returns what the backward needs, or None without `keep_state`.
    """
    v = view_entries(entries, *chunk, g, width)
    alpha_raw, log_one_minus = kernel("alpha_and_log_one_minus")(
        v.t0, v.w0, v.p, v.r, v.sheared_conic, v.opacity, v.in_image_cols, entries.block_width
    )
    cumulative = running_sum(log_one_minus)
    seg = segments(v.block)
    exclusive_at_first = columns(cumulative, seg.block_first) - columns(log_one_minus, seg.block_first)
    transmittance, weight, weight_sum, weight_max, kept_pairs = kernel("blend")(
        log_one_minus, cumulative, seg.segment, log_t.index_select(1, seg.blocks) - exclusive_at_first, alpha_raw
    )
    block_total = columns(cumulative, seg.block_last) - exclusive_at_first
    log_t.index_add_(1, seg.blocks, block_total)
    live = torch.nonzero(weight_max > 0).squeeze(1)
    if counted is not None:
        counted_weight = weight * counted.index_select(1, v.block)
        weight_sum, weight_max = counted_weight.sum(0, dtype=torch.float64), counted_weight.amax(0)
    compact = live.numel() <= COMPACT_AT_MOST_LIVE * v.block.numel()
    gaussian, block = v.gaussian, v.block
    if compact:
        gaussian, block, weight = gaussian.index_select(0, live), block.index_select(0, live), columns(weight, live)
        weight_sum, weight_max = weight_sum.index_select(0, live), weight_max.index_select(0, live)
    if block.numel():
        first, last = int(block[0]), int(block[-1])
        acc.image_ext[:, first : last + 1] += _sum_per_pixel(weight, block - first, last - first + 1,
                                                             g.features_ext.index_select(0, gaussian))
    acc.contrib_sum.index_add_(0, gaussian, weight_sum)
    acc.contrib_max.scatter_reduce_(0, gaussian, weight_max, reduce="amax")
    acc.pairs += int(kept_pairs.sum())
    if not keep_state:
        return None
    if compact:
        return ChunkState(v.subset(live), columns(transmittance, live), columns(alpha_raw, live))
    return ChunkState(v, transmittance, alpha_raw)


def running_sum(values: Tensor) -> Tensor:
    """Inclusive running sum along q of a (B, Q) float64 tensor, row by row (callers only take differences
    within one block of one row).

    torch's CPU cumsum runs the rows in parallel, but one flat sum over all rows in a single thread: 0.64 against
    1.36 ms at (8, 320k) (a scratch timing). Inside a render, `benchmarks/rasterizer_ab.py --base a25005b`
    read 0.985, 0.978 and 0.983 (20k, training-sized and 100k cases, 25 pairs) for this against the flat sum.
    """
    return torch.cumsum(values, 1)


def _sum_per_pixel(weight: Tensor, local_block: Tensor, num_blocks: int, features_ext: Tensor) -> Tensor:
    """Σ over each pixel's entries of w·f_ext, (B, num_blocks, C+2), as one sparse (CSR) × dense product.

    Row (x, b) of the sparse matrix holds w[x, q] for the entries q of block b, which are contiguous,
    so its values are `weight` as stored and no (B, Q, C+2) product is ever materialised, as a scatter-add
    of that product would need.
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
    state: ChunkState, features_ext: Tensor, up_planes: Tensor, behind: Tensor, grads: GaussianGrads,
) -> None:
    """Accumulate the gradient contributions of one chunk's entries into `grads`; chunks go back to front.

    `up_planes` (C+2, B, num_blocks) holds the upstream gradients of colour, Σ w·z and alpha per pixel, channel
    by channel.
    `behind` (B, num_blocks, float64) holds per pixel T_final · (gC · background) plus Σ w g of the
    chunks behind this one; this chunk's own Σ w g is added to it on the way out.
    """
    v = state.view
    per_weight, weighted, grad_features_ext = kernel("upstream_per_weight")(
        up_planes, v.block, state.transmittance, state.alpha_raw, features_ext.index_select(0, v.gaussian)
    )
    weighted_cumulative = running_sum(weighted)
    seg = segments(v.block)
    per_entry = kernel("entry_gradients")(
        weighted_cumulative, seg.segment,
        columns(weighted_cumulative, seg.block_last) + behind.index_select(1, seg.blocks),
        state.transmittance, state.alpha_raw, per_weight,
        v.t0, v.w0, v.p, v.r, v.sheared_conic, v.opacity, grad_features_ext,
    )
    grads.packed.index_add_(1, v.gaussian, per_entry)
    block_total = (columns(weighted_cumulative, seg.block_last)
                   - columns(weighted_cumulative, seg.block_first) + columns(weighted, seg.block_first))
    behind.index_add_(1, seg.blocks, block_total)
