"""The public entry point: world-space Gaussians + a pinhole camera → image, alpha, depth and per-Gaussian stats.

A Gaussian reaches every pixel where its α passes 1/255 (the exact ellipse of `footprint`), not only the 16×16
tiles its 3σ box touches as in 3DGS's CUDA rasterizer: so the output equals the per-pixel brute-force reference
(tests/reference_rasterizer.py). The two differ only beyond that box, where σ ≥ 4.5 and so α ≤ 0.0111·o.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from splatu.rasterizer.composite import GaussianParams
from splatu.rasterizer.errors import RasterInputError, require_finite, require_float32_range, require_shape
from splatu.rasterizer.footprint import block_entries
from splatu.rasterizer.function import composite
from splatu.rasterizer.projection import LOW_PASS, project_gaussians

BLOCK_WIDTH = 8
"""Pixels per block (one row segment). Narrower blocks waste fewer evaluated elements on a small footprint's
row, at the cost of more entries to sort and composite."""

MIN_BLUR = 1e-3
"""The smallest screen blur, px²: it keeps det(cov2d) ≥ 1e-6, above projection's 1e-10 clamp, and the sheared
conic's A, Q ≤ 1/blur well conditioned, for a footprint flat or a point."""

MIN_NEAR = torch.finfo(torch.float32).smallest_normal
"""The nearest allowed near plane, float32's smallest normal number (1.2e-38): with a near of 1e-300, a float64 depth
of 1e-200 got through, and its f·x/z² overflowed float64 in the gradients (NaN)."""

MAX_CHUNK_ELEMENTS = 1 << 22
"""Entries × block width composited at once; bounds peak memory on large scenes."""


@dataclass
class RasterOutput:
    image: Tensor  # (H, W, C) Σ_i w_i f_i + T_final · background
    alpha: Tensor  # (H, W) 1 − T_final = Σ_i w_i
    depth: Tensor  # (H, W) Σ_i w_i z_i / alpha where alpha > 0, else 0
    radii: Tensor  # (N,) int32 ceil(3·sqrt(λ_max(cov2d))), 0 when culled
    means2d: Tensor  # (N, 2) projected means in pixels, differentiable (call .retain_grad() to read its gradient)
    means2d_absgrad: Tensor  # (N, 2) zeros after forward; backward adds Σ_pixels |dL_p/dmeans2d|
    contrib_sum: Tensor  # (N,) Σ_pixels w_i(p), no grad
    contrib_max: Tensor  # (N,) max_pixels w_i(p), no grad
    depths: Tensor  # (N,) camera-space z of each mean, no grad
    num_contributing_pairs: int  # pixel–Gaussian pairs with α ≥ 1/255 reached before termination


def rasterize(
    means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, features: Tensor,
    world_to_camera: Tensor, K: Tensor, width: int, height: int, *,
    near: float = 0.01, far: float = 1e10, background: Tensor | None = None, log_scales: bool = False,
    contribution_mask: Tensor | None = None, blur: float = LOW_PASS, antialiased: bool = False,
) -> RasterOutput:
    """Render N Gaussians with exact 3DGS semantics (EWA splatting, α-blending front to back, early stop).

    `blur` is the px² added to each 2D covariance (3DGS: 0.3). `antialiased` scales each opacity by
    sqrt(det Σ₂ / det(Σ₂ + blur·I)), Mip-Splatting's 2D filter (used there with blur 0.1), as gsplat's
    "antialiased" mode does; a fully flat footprint then has opacity 0.

    `contribution_mask` (H, W) bool limits `contrib_sum` and `contrib_max` to its pixels (a scene's mask files:
    what a Gaussian shows only where nothing is trained or scored does not count as seen); the image is the same.
    """
    n = means.shape[0] if means.dim() == 2 else -1
    channels = features.shape[1] if features.dim() == 2 else -1
    require_shape("means", means, (None, 3))
    require_shape("quats", quats, (n, 4))
    require_shape("scales", scales, (n, 3))
    require_shape("opacities", opacities, (n,))
    require_shape("features", features, (n, None))
    require_shape("world_to_camera", world_to_camera, (4, 4))
    require_shape("K", K, (3, 3))
    if channels < 1 or width < 1 or height < 1:
        raise RasterInputError(
            f"rasterize got {channels} feature channels and a {width}x{height} image",
            "in the call to rasterize",
            "pass at least one feature channel and a positive image size",
        )
    dtype, device = means.dtype, means.device
    if dtype not in (torch.float32, torch.float64):  # the kernels' offset bounds and float64 sums assume these
        raise RasterInputError(
            f"rasterize got `means` of dtype {dtype}",
            "in the call to rasterize",
            "pass float32 or float64 tensors (the rasterizer casts the other inputs to the dtype of `means`)",
        )
    if background is None:
        background = torch.zeros(channels, dtype=dtype, device=device)
    require_shape("background", background, (channels,))
    named = {"means": means, "quats": quats, "scales": scales, "opacities": opacities, "features": features,
             "world_to_camera": world_to_camera, "K": K, "background": background}
    for name, tensor in named.items():
        require_finite(name, tensor)
    for name in ("means", "world_to_camera", "K"):
        require_float32_range(name, named[name])
    if contribution_mask is not None:
        require_shape("contribution_mask", contribution_mask, (height, width))
    if not (math.isfinite(near) and near >= MIN_NEAR and far > near):  # far may be inf; NaN fails every comparison
        raise RasterInputError(f"rasterize got near = {near}, far = {far}", "in the call to rasterize",
                               f"pass {MIN_NEAR:.1e} ≤ near < far (3DGS uses near 0.01; far may be inf)")
    if not (math.isfinite(blur) and blur >= MIN_BLUR):
        raise RasterInputError(f"rasterize got blur = {blur}", "in the call to rasterize",
                               f"pass a blur of at least {MIN_BLUR} px² (3DGS uses 0.3, Mip-Splatting's 2D filter 0.1)")

    proj = project_gaussians(means, quats, scales, world_to_camera, K, width, height, near, far, log_scales, blur,
                             antialiased)
    opacities = opacities.to(dtype) if proj.opacity_scale is None else opacities.to(dtype) * proj.opacity_scale
    entries = block_entries(
        proj.means2d.detach(), proj.cov2d, proj.det, opacities.detach(), proj.depths.detach(), proj.visible,
        width, height, BLOCK_WIDTH,
    )
    absgrad = torch.zeros(n, 2, dtype=dtype, device=device)
    ones = torch.ones(n, 1, dtype=dtype, device=device)
    features_ext = torch.cat([features.to(dtype), proj.depths[:, None], ones], dim=1)
    params = GaussianParams(proj.means2d, proj.log_conics, proj.swapped, opacities, features_ext)
    image, alpha, depth_num, contrib_sum, contrib_max, pairs = composite(
        params, background.to(dtype), entries, width, height, absgrad, MAX_CHUNK_ELEMENTS, contribution_mask
    )
    return RasterOutput(
        image=image,
        alpha=alpha,
        # 0 where nothing was drawn, and no gradient there: 1/1e-10 times a depth once made 0·inf = NaN
        depth=torch.where(alpha > 0, depth_num / alpha.clamp_min(1e-10), 0.0),
        radii=proj.radii,
        means2d=proj.means2d,
        means2d_absgrad=absgrad,
        contrib_sum=contrib_sum,
        contrib_max=contrib_max,
        depths=proj.depths.detach(),
        num_contributing_pairs=pairs,
    )
