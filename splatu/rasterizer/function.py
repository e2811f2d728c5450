"""The custom autograd Function around the block compositor, and its no-grad fast path.

Projection stays outside (plain autograd); this Function takes the projected quantities, so the
caller's `means2d` is a true input and its signed gradient is visible through `retain_grad`.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from splatu.rasterizer.composite import (
    ChunkState,
    GaussianGrads,
    GaussianParams,
    PixelAccumulators,
    backward_chunk,
    chunks,
    forward_chunk,
)
from splatu.rasterizer.footprint import BlockEntries


def _run_forward(
    g: GaussianParams, entries: BlockEntries, width: int, max_elements: int, keep_state: bool,
    counted: Tensor | None,
) -> tuple[PixelAccumulators, list[ChunkState]]:
    n, channels_ext = g.features_ext.shape
    dtype, device = g.means2d.dtype, g.means2d.device
    acc = PixelAccumulators(
        image_ext=torch.zeros(entries.block_width, entries.num_blocks, channels_ext, dtype=dtype, device=device),
        # float64: a Gaussian that covers a 4096×3072 frame summed 0.58% short in float32 (a numerics review)
        contrib_sum=torch.zeros(n, dtype=torch.float64, device=device),
        contrib_max=torch.zeros(n, dtype=dtype, device=device),
    )
    log_t = torch.zeros(entries.block_width, entries.num_blocks, dtype=torch.float64, device=device)
    height = entries.num_blocks // entries.blocks_per_row
    in_image = to_blocks(torch.ones(height, width, dtype=torch.bool, device=device), entries)
    states = []
    for chunk in chunks(entries, log_t, in_image, max_elements):
        state = forward_chunk(entries, chunk, g, width, acc, log_t, counted, keep_state)
        if state is not None:
            states.append(state)
    acc.contrib_sum = acc.contrib_sum.to(dtype)
    return acc, states


def to_image(block_layout: Tensor, width: int, height: int) -> Tensor:
    """(B, num_blocks, ...) → (H, W, ...)."""
    return block_layout.transpose(0, 1).reshape(height, -1, *block_layout.shape[2:])[:, :width]


def to_blocks(image: Tensor, entries: BlockEntries) -> Tensor:
    """(H, W, ...) → (B, num_blocks, ...), zero-padding the last block of each row."""
    height, width = image.shape[:2]
    padded_width = entries.blocks_per_row * entries.block_width
    if padded_width != width:
        image = torch.cat([image, image.new_zeros(height, padded_width - width, *image.shape[2:])], dim=1)
    blocks = image.reshape(entries.num_blocks, entries.block_width, *image.shape[2:])
    return blocks.transpose(0, 1).contiguous()


def _finish(image_ext: Tensor, background: Tensor, width: int, height: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Image with background, alpha and Σ w·z in (H, W) layout, and T_final in block layout (B, num_blocks)."""
    channels = background.shape[0]
    alpha = image_ext[:, :, channels + 1]
    t_final = 1.0 - alpha
    image = image_ext[:, :, :channels] + t_final[:, :, None] * background
    return (to_image(image, width, height), to_image(alpha, width, height),
            to_image(image_ext[:, :, channels], width, height), t_final)


class CompositeFunction(torch.autograd.Function):
    """(means2d, log_conics, opacities, extended features, background) → image, alpha, Σ w·z, contributions;
    `swapped` (which axis each sheared conic runs along) has no gradient. The float64 `log_conics` get their
    gradient in the render's dtype, which autograd casts."""

    @staticmethod
    def forward(
        ctx: Any, means2d: Tensor, log_conics: Tensor, opacities: Tensor, features_ext: Tensor,
        background: Tensor, swapped: Tensor, entries: BlockEntries, width: int, height: int, absgrad: Tensor,
        max_elements: int, counted: Tensor | None,
    ) -> tuple[Tensor, ...]:
        g = GaussianParams(means2d, log_conics, swapped, opacities, features_ext)
        acc, states = _run_forward(g, entries, width, max_elements, keep_state=True, counted=counted)
        image, alpha, depth_num, t_final = _finish(acc.image_ext, background, width, height)
        # the backward reads the Gaussians' parameters from the saved states, as the forward formed them
        ctx.save_for_backward(means2d, features_ext, background)
        ctx.states, ctx.entries, ctx.t_final, ctx.absgrad = states, entries, t_final, absgrad
        pairs = torch.tensor(acc.pairs)
        ctx.mark_non_differentiable(acc.contrib_sum, acc.contrib_max, pairs)
        return image, alpha, depth_num, acc.contrib_sum, acc.contrib_max, pairs

    @staticmethod
    def backward(ctx: Any, g_image: Tensor, g_alpha: Tensor, g_depth_num: Tensor, *_: Tensor) -> tuple:
        means2d, features_ext, background = ctx.saved_tensors
        entries = ctx.entries
        up_ext = to_blocks(torch.cat([g_image, g_depth_num[..., None], g_alpha[..., None]], dim=-1), entries)
        channels = background.shape[0]
        up_image = up_ext[:, :, :channels]
        behind = (ctx.t_final * (up_image * background).sum(-1)).to(torch.float64)
        channels_ext = features_ext.shape[1]
        grads = GaussianGrads.zeros(means2d, channels_ext)
        up_planes = up_ext.permute(2, 0, 1).contiguous()
        for state in reversed(ctx.states):
            backward_chunk(state, features_ext, up_planes, behind, grads)
        grad_features_ext, grad_opacities, grad_log_conics, grad_means2d, absgrad = grads.split(channels_ext)
        ctx.absgrad += absgrad
        grad_background = (ctx.t_final[:, :, None] * up_image).sum((0, 1))
        return (grad_means2d, grad_log_conics, grad_opacities, grad_features_ext, grad_background,
                None, None, None, None, None, None, None)


def composite(
    g: GaussianParams, background: Tensor, entries: BlockEntries, width: int, height: int,
    absgrad: Tensor, max_elements: int, contribution_mask: Tensor | None,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, int]:
    """image (H,W,C), alpha (H,W), Σ w·z (H,W), contrib_sum, contrib_max, pair count; no-grad path saves nothing.
    `contribution_mask` (H, W, bool) limits contrib_sum and contrib_max to its pixels."""
    counted = None if contribution_mask is None else to_blocks(contribution_mask.to(g.means2d.dtype), entries)
    inputs = (g.means2d, g.log_conics, g.opacities, g.features_ext, background)
    if torch.is_grad_enabled() and any(x.requires_grad for x in inputs):
        image, alpha, depth_num, csum, cmax, pairs = CompositeFunction.apply(
            *inputs, g.swapped, entries, width, height, absgrad, max_elements, counted
        )
        return image, alpha, depth_num, csum, cmax, int(pairs)
    acc, _ = _run_forward(g, entries, width, max_elements, keep_state=False, counted=counted)
    image, alpha, depth_num, _ = _finish(acc.image_ext, background, width, height)
    return image, alpha, depth_num, acc.contrib_sum, acc.contrib_max, acc.pairs
