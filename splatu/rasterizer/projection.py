"""EWA projection of 3D Gaussians to 2D screen-space ellipses, differentiable by autograd.

Follows the 3DGS conventions: camera-space mean t = R m + tvec (OpenCV axes), the Jacobian of the
perspective projection at t with t.x/t.z and t.y/t.z clamped before forming J to the image's own range widened
by 0.3·tan(half-FoV) on each side (±1.3·tan(half-FoV) for a centred principal point, as 3DGS writes it),
cov2d = J W Σ Wᵀ Jᵀ + blur·I (3DGS: 0.3 px², the default), conic = inv(cov2d) with det clamped ≥ 1e-10. `antialiased`
also scales each opacity by sqrt(det(J W Σ Wᵀ Jᵀ) / det(cov2d)), Mip-Splatting's 2D filter,
so that a Gaussian smaller than a pixel fades with its footprint's area instead of being widened to the blur at full
opacity.

The conic is handed on in sheared form (A, S, Q) along the footprint's longer screen axis. With (v, w) = (dx, dy)
when cov_yy ≥ cov_xx and (dy, dx) otherwise (`swapped`), σ = ½(dx, dy)·conic·(dx, dy)ᵀ = ½A·(v − S·w)² + ½Q·w²,
where A = cov_ww/det, S = cov_xy/cov_ww and Q = 1/cov_ww. Both terms are non-negative, so σ never forms as a small
difference of huge terms, as ½a·dx² + b·dx·dy + ½c·dy² does in float32 for a long thin Gaussian centred far
off-screen (at 3,000 px, terms of 10⁷ cancelled to about 1 and moved α by up to 0.53 at a pixel). Shearing along
the longer axis (w) keeps |S| ≤ 1 (and A, Q ≤ 1/blur), so the form is as well conditioned at every orientation; with
w = dy always, a needle near the x axis has S up to about 0.9 × its long-axis std in px.

A and Q are handed on as logs, in float64 (`log_conics`): the compositor differentiates ln A and ln Q, whose gradients
Σ gσ·½A·t² and Σ gσ·½Q·w² are bounded by the pixels' own (σ·e^−σ ≤ 1/e). dL/dA = ½Σ gσ·t² itself exceeded float32
for a footprint seen from ~1e18 px away (a mean just past the near plane, far to the side), and made every gradient
inf or NaN. A and Q still reach the kernels rounded once from float64.

Culling rule (exact, shared with the brute-force reference): a Gaussian is culled when
z ≤ near, z ≥ far, or its box [mx ± r] × [my ± r] with r = ceil(3·sqrt(λ_max(cov2d))) lies
entirely off-screen: mx + r ≤ 0 or mx − r ≥ width or my + r ≤ 0 or my − r ≥ height.

All covariance algebra runs in float64 whatever the input dtype: an enormous or degenerate Σ
then stays finite (det is formed from non-negative Cauchy–Binet terms, so it cannot cancel to
a negative number), and results are cast back to the input dtype. A footprint matrix T = J W R S
past 2^MAX_FOOTPRINT_EXPONENT px is scaled down to it whole (see there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from splatu.rasterizer.kernels import compiled

MAX_SCALE = 1e30
"""Scales are clamped here so float64 covariance products stay finite; no real scene comes close."""

MIN_QUATERNION_NORM = 1e-18
"""A shorter quaternion gets the gradient of one this long in its direction: the exact gradient grows as 1/|q| and
passes float32's range below |q| ≈ 1e-37 (float64's below 1e-308)."""

MAX_FOOTPRINT_EXPONENT = 250
"""A footprint matrix T larger than 2²⁵⁰ px (1.8e75) is multiplied by the power of two that brings it there, so that
det(T Tᵀ) ~ |T|⁴ stays within float64: at 1e77 px (a mean 1e-20 in front of a camera of focal length 1e30 px) it
was inf, and every gradient NaN. Its α changes only where its mean is also ~1e75 px or more away (float32 clamps
offsets at 4.6e18 px anyway, see kernels.entry_geometry)."""

LOW_PASS = 0.3
"""The 3DGS screen-space blur added to cov2d (about one pixel), in px²."""


@dataclass
class Projection:
    means2d: Tensor  # (N, 2) pixels, input dtype, differentiable
    log_conics: Tensor  # (N, 3) (ln A, S, ln Q): the sheared conic (module docstring), float64, differentiable
    swapped: Tensor  # (N,) bool: cov_xx > cov_yy, so (v, w) = (dy, dx) in the sheared form
    depths: Tensor  # (N,) camera-space z, input dtype, differentiable
    cov2d: Tensor  # (N, 3) (xx, xy, yy), float64, detached: for footprints
    det: Tensor  # (N,) det(cov2d), float64, detached
    radii: Tensor  # (N,) int32, 0 when culled
    visible: Tensor  # (N,) bool
    opacity_scale: Tensor | None  # (N,) sqrt(det(cov2d − blur·I) / det(cov2d)), differentiable; None unless antialiased


def quaternion_to_rotation(quats: Tensor) -> Tensor:
    """Rotation matrices (N, 3, 3) from wxyz quaternions of any scale; a zero quaternion maps to the identity."""
    q = unit_quaternions(quats)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*q.shape[:-1], 3, 3)


def unit_quaternions(quats: Tensor) -> Tensor:
    """q/|q| for wxyz quaternions (..., 4) of any scale, and 0 for q = 0, with a finite gradient for every q.

    Each quaternion is first multiplied by the power of two that brings its largest component into [1, 2), in two
    factors (2¹⁰⁷⁴, for the smallest float64 denormal, is itself beyond float64): exact, so a unit quaternion's result
    is the same to the bit, while |q|² of q·1e-13 cannot underflow nor that of q·1e200 overflow. The backward is the
    exact Jacobian (I − q̂q̂ᵀ)/|q|, written out, with |q| floored at MIN_QUATERNION_NORM. A rotation, even in q̂,
    then has gradient 0 at q = 0, where no direction is better than its opposite.
    """
    with torch.no_grad():
        largest = quats.abs().amax(-1, keepdim=True)
        exponent = torch.where(largest > 0, -torch.floor(torch.log2(largest)), 0.0)
        half = torch.floor(exponent / 2)
        scaled = quats * torch.exp2(half) * torch.exp2(exponent - half)
        norm = scaled.norm(dim=-1, keepdim=True)  # in [1, 4) unless q = 0 (or just under 1 where log2 rounded up)
        unit = scaled / norm.clamp_min(0.5)  # the clamp only keeps q = 0 at 0
        length = norm * torch.exp2(-half) * torch.exp2(half - exponent)  # |q|: may round to 0 or inf, both safe below
    tangent = (quats - quats.detach()) / length.clamp_min(MIN_QUATERNION_NORM)  # 0, but its gradient is 1 / |q|
    return unit + tangent - unit * (unit * tangent).sum(-1, keepdim=True)


def conic_rows(log_conics: Tensor, dtype: torch.dtype) -> Tensor:
    """(3, N): the sheared conic's rows A, S, Q in the render's dtype, from the float64 (ln A, S, ln Q) that the
    projection hands on (module docstring); A and Q are rounded once, from float64."""
    log_a, shear, log_q = log_conics.t()
    return torch.stack([log_a.exp(), shear, log_q.exp()]).to(dtype)


def project_gaussians(
    means: Tensor, quats: Tensor, scales: Tensor, world_to_camera: Tensor, K: Tensor,
    width: int, height: int, near: float, far: float, log_scales: bool, blur: float = LOW_PASS,
    antialiased: bool = False,
) -> Projection:
    """Project every Gaussian; culled ones get finite placeholder values and radius 0.

    When it is differentiated, it runs compiled if the rasterizer's kernels are (`kernels.set_compile`): its ~50
    float64 elementwise steps and their autograd backward then fuse (a training-sized render took 0.94× the time;
    docs/results.md, "Rasterizer"). A no-grad render (evaluation) stays eager rather than compile a second,
    inference-only graph for a handful of views.
    """
    differentiated = torch.is_grad_enabled() and any(t.requires_grad for t in (means, quats, scales))
    project = compiled(_projected) if differentiated else _projected
    return Projection(*project(means, quats, scales, world_to_camera, K, width, height, near, far, log_scales, blur,
                               antialiased))


def _projected(
    means: Tensor, quats: Tensor, scales: Tensor, world_to_camera: Tensor, K: Tensor,
    width: int, height: int, near: float, far: float, log_scales: bool, blur: float, antialiased: bool,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    """`Projection`'s fields, in order: a pure tensor function, so that torch.compile can take it whole."""
    out_dtype = means.dtype
    f64 = torch.float64
    W2C = world_to_camera.to(f64)
    Kd = K.to(f64)
    fx, fy = Kd[0, 0], Kd[1, 1]
    cx, cy = Kd[0, 2], Kd[1, 2]
    R_cam = W2C[:3, :3]
    t_cam = means.to(f64) @ R_cam.T + W2C[:3, 3]
    z = t_cam[:, 2]
    with torch.no_grad():
        in_depth = (z > near) & (z < far)
    # Culled-by-depth Gaussians divide by 1 instead of ~0, so neither values nor gradients blow up.
    z_safe = torch.where(in_depth, z, torch.ones_like(z))
    u = fx * t_cam[:, 0] / z_safe + cx
    v = fy * t_cam[:, 1] / z_safe + cy

    # the image's own x/z range, [-cx/fx, (width - cx)/fx], widened by 0.3 of the half field of view on each side:
    # 3DGS's ±1.3·tan(half-FoV) about the axis, shifted by the principal point's offset from the centre (0 when
    # centred, which leaves 3DGS's arithmetic bit for bit), so a crop's or a tile's Gaussians are not bent
    lim_x, lim_y = 1.3 * (0.5 * width / fx), 1.3 * (0.5 * height / fy)
    shift_x, shift_y = (cx - 0.5 * width) / fx, (cy - 0.5 * height) / fy
    tx = torch.maximum(torch.minimum(t_cam[:, 0] / z_safe, lim_x - shift_x), -lim_x - shift_x) * z_safe
    ty = torch.maximum(torch.minimum(t_cam[:, 1] / z_safe, lim_y - shift_y), -lim_y - shift_y) * z_safe
    zero = torch.zeros_like(z_safe)
    J = torch.stack(
        [fx / z_safe, zero, -fx * tx / (z_safe * z_safe), zero, fy / z_safe, -fy * ty / (z_safe * z_safe)], dim=-1
    ).reshape(-1, 2, 3)

    if log_scales:
        s = torch.exp(scales.to(f64).clamp(max=math.log(MAX_SCALE)))
    else:
        s = scales.to(f64).clamp(-MAX_SCALE, MAX_SCALE)
    M = quaternion_to_rotation(quats.to(f64)) * s[:, None, :]  # R S
    JW = J @ R_cam  # (N, 2, 3), one (2N, 3) @ (3, 3) product
    T = (JW[:, :, :, None] * M[:, None, :, :]).sum(2)  # J W R S; cov2d = T Tᵀ + blur I (no tiny-matrix bmm)
    with torch.no_grad():  # 0 unless T passes 2^MAX_FOOTPRINT_EXPONENT px (and for T = 0: its log2 is −inf)
        excess = (torch.floor(torch.log2(T.abs().amax((1, 2)))) - MAX_FOOTPRINT_EXPONENT).clamp_min(0.0)
    T = T * torch.exp2(-excess)[:, None, None]
    a = (T[:, 0] * T[:, 0]).sum(-1)
    b = (T[:, 0] * T[:, 1]).sum(-1)
    c = (T[:, 1] * T[:, 1]).sum(-1)
    minors = torch.stack(
        [
            T[:, 0, 0] * T[:, 1, 1] - T[:, 0, 1] * T[:, 1, 0],
            T[:, 0, 0] * T[:, 1, 2] - T[:, 0, 2] * T[:, 1, 0],
            T[:, 0, 1] * T[:, 1, 2] - T[:, 0, 2] * T[:, 1, 1],
        ],
        dim=-1,
    )
    det = ((minors * minors).sum(-1) + blur * (a + c) + blur * blur).clamp_min(1e-10)
    cxx, cyy = a + blur, c + blur
    swapped = cxx > cyy
    cww = torch.where(swapped, cxx, cyy)
    log_conics = torch.stack([torch.log(cww / det), b / cww, -torch.log(cww)], dim=-1)

    with torch.no_grad():
        half_diff = 0.5 * (cxx - cyy)
        lam_max = 0.5 * (cxx + cyy) + torch.sqrt(half_diff * half_diff + b * b)
        radius = torch.ceil(3.0 * torch.sqrt(lam_max))
        # tested uncapped: a footprint wider than the cap, centred further off-screen, still covers the image
        on_screen = (u + radius > 0) & (u - radius < width) & (v + radius > 0) & (v - radius < height)
        visible = in_depth & on_screen
        radii = torch.where(visible, radius.clamp(max=2.0**30), torch.zeros_like(radius)).to(torch.int32)
        cov2d = torch.stack([cxx, b, cyy], dim=-1).detach()

    # culled means may lie beyond float32's range (a mean at x = 1e38 behind the camera); they are never drawn,
    # so they read 0, and depths saturate rather than overflow to ±inf
    largest = torch.finfo(out_dtype).max
    means2d = torch.where(visible[:, None], torch.stack([u, v], dim=-1), 0.0).clamp(-largest, largest)
    # |minors| = sqrt(det(T Tᵀ)) (Cauchy–Binet): its gradient stays bounded where a flat footprint makes it 0
    opacity_scale = (torch.linalg.vector_norm(minors, dim=-1) / det.sqrt()).to(out_dtype) if antialiased else None
    return (means2d.to(out_dtype), log_conics, swapped, z.clamp(-largest, largest).to(out_dtype),
            cov2d, det.detach(), radii, visible, opacity_scale)
