"""Real spherical harmonics up to degree 3, with the 3DGS constants and sign convention.

Colour and uncertainty are both view-dependent functions on the sphere stored as SH
coefficients, so both go through `eval_sh`. The basis matches 3DGS / gsplat exactly so
that coefficients mean the same thing here as in the field (REFERENCE.md §2).

Every basis function of degree l ≥ 1 is written as a homogeneous polynomial of degree l
in (x, y, z). Evaluated at the zero vector it is therefore exactly 0, and `eval_sh` of a
zero-length direction returns the DC term alone, which is the mean of the function over
the sphere: the principled answer when a direction is undefined (e.g. a Gaussian sitting
on the camera centre).
"""

from __future__ import annotations

import torch
from torch import Tensor

MAX_SH_DEGREE = 3

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def num_sh_bases(degree: int) -> int:
    """Number of coefficients of a real SH expansion up to `degree` (0..3)."""
    if not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree must be in 0..{MAX_SH_DEGREE}, got {degree}")
    return (degree + 1) ** 2


def sh_degree_of(num_bases: int) -> int:
    """The degree whose expansion has `num_bases` coefficients: the inverse of `num_sh_bases`."""
    degree = round(max(num_bases, 0) ** 0.5) - 1
    if not 0 <= degree <= MAX_SH_DEGREE or num_sh_bases(degree) != num_bases:
        raise ValueError(f"{num_bases} is not the coefficient count of any SH degree 0..{MAX_SH_DEGREE}")
    return degree


def safe_normalize(v: Tensor, eps: float = 1e-12) -> Tensor:
    """Unit vectors along the last axis; vectors shorter than `eps` become exactly zero.

    Both branches are computed with finite inputs, so the gradient is finite everywhere:
    zero at the zero vector (the output is constant 0 there). Each vector is first divided by its largest
    component, so the squared norm cannot overflow (float32 would at a length of 1.8e19) or underflow; v/|v|
    does not depend on that factor, so holding it constant leaves the gradient exact.
    """
    largest = v.detach().abs().amax(dim=-1, keepdim=True)
    scaled = v / torch.where(largest > 0, largest, 1.0)  # components in [-1, 1], the largest ±1
    squared_norm = (scaled * scaled).sum(dim=-1, keepdim=True)
    long_enough = largest * squared_norm.sqrt() > eps
    inverse_norm = torch.where(long_enough, torch.rsqrt(torch.where(long_enough, squared_norm, 1.0)), 0.0)
    return scaled * inverse_norm


def sh_basis(dirs: Tensor, degree: int) -> Tensor:
    """Real SH basis Y_k(d) for k < (degree+1)^2, shape (..., (degree+1)^2).

    `dirs` is used as given (callers normalise): the polynomials are the 3DGS ones, so a
    zero vector gives (C0, 0, 0, ...).
    """
    num_sh_bases(degree)
    x, y, z = dirs.unbind(-1)
    terms = [torch.full_like(x, C0)]
    if degree >= 1:
        terms += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        xy, yz, xz = x * y, y * z, x * z
        terms += [
            C2[0] * xy,
            C2[1] * yz,
            C2[2] * (2.0 * zz - xx - yy),
            C2[3] * xz,
            C2[4] * (xx - yy),
        ]
    if degree >= 3:
        terms += [
            C3[0] * y * (3.0 * xx - yy),
            C3[1] * xy * z,
            C3[2] * y * (4.0 * zz - xx - yy),
            C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            C3[4] * x * (4.0 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(terms, dim=-1)


def eval_sh(coeffs: Tensor, dirs: Tensor, degree: int) -> Tensor:
    """Evaluate SH functions: sum_k coeffs[..., k, :] * Y_k(normalize(d)), shape (..., C).

    coeffs is (..., K, C) with K ≥ (degree+1)^2; coefficients beyond the active `degree`
    are ignored, which is how training raises the SH degree gradually. Leading dimensions
    of coeffs and dirs broadcast. C is free: 3 for colour, 1 for uncertainty.
    """
    n = num_sh_bases(degree)
    if coeffs.shape[-2] < n:
        raise ValueError(f"degree {degree} needs {n} SH coefficients, got {coeffs.shape[-2]}")
    if degree == 0:  # view-independent: skip the ~20 autograd nodes of the direction entirely
        shape = torch.broadcast_shapes(coeffs.shape[:-2], dirs.shape[:-1]) + coeffs.shape[-1:]
        return (C0 * coeffs[..., 0, :]).expand(shape)
    basis = sh_basis(safe_normalize(dirs), degree).to(coeffs.dtype)
    return (basis.unsqueeze(-2) @ coeffs[..., :n, :]).squeeze(-2)


def rgb_to_sh(rgb: Tensor) -> Tensor:
    """DC coefficient whose evaluation gives colour `rgb` (3DGS offsets colour by 0.5)."""
    return (rgb - 0.5) / C0


def sh_to_rgb(sh: Tensor) -> Tensor:
    """Colour of a DC-only expansion: the inverse of `rgb_to_sh`."""
    return sh * C0 + 0.5
