"""Real SH basis: orthonormal, the 3DGS closed forms and signs, rotation-closed, safe at d = 0."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from splatu.sh import (
    C0,
    C1,
    C2,
    C3,
    eval_sh,
    num_sh_bases,
    rgb_to_sh,
    safe_normalize,
    sh_basis,
    sh_degree_of,
    sh_to_rgb,
)

# Written out again from REFERENCE.md §2 so a typo in splatu/sh.py cannot hide here.
REF_C0 = 0.28209479177387814
REF_C1 = 0.4886025119029199
REF_C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396]
REF_C3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
          -0.4570457994644658, 1.445305721320277, -0.5900435899266435]


def closed_form_basis(d: torch.Tensor) -> torch.Tensor:
    """The 16 3DGS basis functions, one Cartesian formula each, (M, 16)."""
    x, y, z = d.unbind(-1)
    return torch.stack([
        torch.full_like(x, REF_C0),
        -REF_C1 * y, REF_C1 * z, -REF_C1 * x,
        REF_C2[0] * x * y, REF_C2[1] * y * z, REF_C2[2] * (2 * z**2 - x**2 - y**2), REF_C2[3] * x * z,
        REF_C2[4] * (x**2 - y**2),
        REF_C3[0] * y * (3 * x**2 - y**2), REF_C3[1] * x * y * z, REF_C3[2] * y * (4 * z**2 - x**2 - y**2),
        REF_C3[3] * z * (2 * z**2 - 3 * x**2 - 3 * y**2), REF_C3[4] * x * (4 * z**2 - x**2 - y**2),
        REF_C3[5] * z * (x**2 - y**2), REF_C3[6] * x * (x**2 - 3 * y**2),
    ], dim=-1)


def random_unit(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    d = torch.randn(n, 3, generator=g, dtype=torch.float64)
    return d / d.norm(dim=-1, keepdim=True)


def sphere_quadrature(n_theta: int = 24, n_phi: int = 48) -> tuple[torch.Tensor, torch.Tensor]:
    """Directions and weights integrating polynomials of degree ≤ 2·n_theta−1 exactly on S²."""
    cos_t, w_t = np.polynomial.legendre.leggauss(n_theta)
    phi = np.arange(n_phi) * (2 * math.pi / n_phi)
    ct, ph = np.meshgrid(cos_t, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], axis=-1).reshape(-1, 3)
    weights = np.repeat(w_t, n_phi) * (2 * math.pi / n_phi)
    return torch.from_numpy(dirs), torch.from_numpy(weights)


def random_rotation(seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    q, r = torch.linalg.qr(torch.randn(3, 3, generator=g, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r))
    return q * torch.sign(torch.linalg.det(q))


def test_constants_match_reference_and_analytic_normalisation():
    assert C0 == REF_C0 and C1 == REF_C1 and list(C2) == REF_C2 and list(C3) == REF_C3
    pi = math.pi
    analytic = {
        C0: 0.5 / math.sqrt(pi),
        C1: math.sqrt(3 / (4 * pi)),
        C2[0]: 0.5 * math.sqrt(15 / pi),
        C2[2]: 0.25 * math.sqrt(5 / pi),
        C2[4]: 0.25 * math.sqrt(15 / pi),
        C3[0]: -0.25 * math.sqrt(35 / (2 * pi)),
        C3[1]: 0.5 * math.sqrt(105 / pi),
        C3[2]: -0.25 * math.sqrt(21 / (2 * pi)),
        C3[3]: 0.25 * math.sqrt(7 / pi),
        C3[5]: 0.25 * math.sqrt(105 / pi),
    }
    for constant, exact in analytic.items():
        assert math.isclose(constant, exact, rel_tol=1e-15), (constant, exact)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_num_sh_bases(degree):
    assert num_sh_bases(degree) == (degree + 1) ** 2
    assert sh_basis(random_unit(5, 0), degree).shape == (5, (degree + 1) ** 2)


@pytest.mark.parametrize("degree", [-1, 4])
def test_unsupported_degree_raises(degree):
    with pytest.raises(ValueError, match="degree"):
        num_sh_bases(degree)
    with pytest.raises(ValueError, match="degree"):
        eval_sh(torch.zeros(1, 25, 1), torch.ones(1, 3), degree)


def test_basis_is_orthonormal_on_the_sphere():
    dirs, weights = sphere_quadrature()
    assert weights.sum().item() == pytest.approx(4 * math.pi, rel=1e-12)
    Y = sh_basis(dirs, 3)
    gram = Y.T @ (weights[:, None] * Y)
    assert torch.allclose(gram, torch.eye(16, dtype=torch.float64), atol=1e-6), (gram - torch.eye(16)).abs().max()


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_basis_matches_closed_forms(degree):
    d = random_unit(500, seed=degree)
    n = num_sh_bases(degree)
    torch.testing.assert_close(sh_basis(d, degree), closed_form_basis(d)[:, :n], rtol=0, atol=1e-14)


def test_degree_one_sign_convention():
    """REFERENCE: degree 1 is −C1·y·sh1 + C1·z·sh2 − C1·x·sh3."""
    coeffs = torch.zeros(3, 4, 1, dtype=torch.float64)
    coeffs[:, 1:, 0] = torch.eye(3, dtype=torch.float64)  # only sh1, only sh2, only sh3
    d = torch.tensor([0.6, 0.0, 0.8], dtype=torch.float64)
    out = eval_sh(coeffs, d, 1)[:, 0]
    torch.testing.assert_close(out, torch.tensor([-C1 * 0.0, C1 * 0.8, -C1 * 0.6], dtype=torch.float64))


@pytest.mark.parametrize("band", [1, 2, 3])
def test_each_band_is_closed_under_rotation_and_keeps_its_energy(band):
    """f(Rᵀd) of a band-l function is again band-l with the same coefficient norm."""
    lo, hi = band**2, (band + 1) ** 2
    g = torch.Generator().manual_seed(band)
    coeffs = torch.zeros(16, dtype=torch.float64)
    coeffs[lo:hi] = torch.randn(hi - lo, generator=g, dtype=torch.float64)
    R = random_rotation(seed=10 + band)
    d = random_unit(400, seed=20 + band)
    rotated_values = sh_basis(d @ R, 3) @ coeffs  # row d @ R is Rᵀ d
    basis = sh_basis(d, 3)
    fit = torch.linalg.lstsq(basis, rotated_values[:, None]).solution[:, 0]
    residual = (basis @ fit - rotated_values).abs().max()
    assert residual < 1e-10
    outside = torch.cat([fit[:lo], fit[hi:]]).abs().max()
    assert outside < 1e-10
    assert fit[lo:hi].norm().item() == pytest.approx(coeffs.norm().item(), rel=1e-10)
    assert not torch.allclose(fit[lo:hi], coeffs[lo:hi], atol=1e-3)  # the rotation really changed it


def test_active_degree_ignores_extra_coefficients():
    d = random_unit(50, seed=3)
    coeffs = torch.randn(50, 16, 3, dtype=torch.float64)
    for degree in range(4):
        n = num_sh_bases(degree)
        changed = coeffs.clone()
        changed[:, n:] = torch.randn(50, 16 - n, 3, dtype=torch.float64)
        torch.testing.assert_close(eval_sh(coeffs, d, degree), eval_sh(changed, d, degree), rtol=0, atol=0)
        torch.testing.assert_close(eval_sh(coeffs[:, :n], d, degree), eval_sh(coeffs, d, degree))
        expected = torch.einsum("mk,mkc->mc", closed_form_basis(d)[:, :n], coeffs[:, :n])
        torch.testing.assert_close(eval_sh(coeffs, d, degree), expected, rtol=0, atol=1e-13)
    with pytest.raises(ValueError, match="coefficients"):
        eval_sh(coeffs[:, :4], d, 2)


@pytest.mark.parametrize("channels", [1, 3, 7])
def test_any_number_of_channels(channels):
    d = random_unit(40, seed=channels)
    coeffs = torch.randn(40, 16, channels, dtype=torch.float64)
    out = eval_sh(coeffs, d, 3)
    assert out.shape == (40, channels)
    expected = torch.einsum("nk,nkc->nc", closed_form_basis(d), coeffs)
    torch.testing.assert_close(out, expected, rtol=0, atol=1e-13)


def test_direction_length_does_not_matter_and_leading_dims_broadcast():
    d = random_unit(30, seed=5)
    coeffs = torch.randn(30, 9, 2, dtype=torch.float64)
    torch.testing.assert_close(eval_sh(coeffs, 7.5 * d, 2), eval_sh(coeffs, d, 2))
    one_direction = eval_sh(coeffs, d[0], 2)
    torch.testing.assert_close(one_direction, eval_sh(coeffs, d[:1].expand(30, 3), 2))
    for degree in (0, 2):  # one set of coefficients seen along many directions
        shared = eval_sh(coeffs[0], d, degree)
        assert shared.shape == (30, 2)
        torch.testing.assert_close(shared, eval_sh(coeffs[:1].expand(30, 9, 2), d, degree))


def test_zero_length_direction_gives_dc_and_finite_gradients():
    coeffs = torch.randn(4, 16, 3, dtype=torch.float64, requires_grad=True)
    dirs = torch.tensor([[0.0, 0.0, 0.0], [1e-300, 0.0, 0.0], [0.0, -1e-30, 0.0], [0.0, 0.0, 0.0]],
                        dtype=torch.float64, requires_grad=True)
    out = eval_sh(coeffs, dirs, 3)
    torch.testing.assert_close(out, C0 * coeffs[:, 0].detach())
    out.square().sum().backward()
    assert torch.isfinite(dirs.grad).all() and torch.isfinite(coeffs.grad).all()
    assert (coeffs.grad[:, 1:] == 0).all()


def test_zero_length_direction_float32():
    coeffs = torch.randn(2, 16, 1, requires_grad=True)
    dirs = torch.zeros(2, 3, requires_grad=True)
    out = eval_sh(coeffs, dirs, 3)
    out.sum().backward()
    assert torch.isfinite(out).all() and torch.isfinite(dirs.grad).all() and torch.isfinite(coeffs.grad).all()


def test_safe_normalize():
    v = torch.tensor([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64, requires_grad=True)
    u = safe_normalize(v)
    torch.testing.assert_close(u.detach(), torch.tensor([[0.6, 0.8, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64))
    u.sum().backward()
    assert torch.isfinite(v.grad).all()
    assert (v.grad[1] == 0).all()


def test_safe_normalize_keeps_very_long_directions_and_an_exact_gradient():
    """The float32 squared norm overflowed beyond a length of 1.8e19, so such a direction became zero (DC only)."""
    long = torch.tensor([[1e20, 0.0, 0.0], [3e30, -4e30, 0.0], [3e-10, 4e-10, 0.0]])
    expected = torch.tensor([[1.0, 0.0, 0.0], [0.6, -0.8, 0.0], [0.6, 0.8, 0.0]])
    torch.testing.assert_close(safe_normalize(long), expected)
    v = torch.tensor([[3.0, -4.0, 12.0], [1e-3, 2e-3, -5e-4], [7e5, 0.0, 1.0]], dtype=torch.float64,
                     requires_grad=True)
    assert torch.autograd.gradcheck(safe_normalize, (v,))


def test_sh_degree_of_inverts_num_sh_bases_and_names_a_bad_count():
    """0 and 25 coefficients used to report 'SH degree must be in 0..3, got -1 / 4' instead of the count."""
    assert [sh_degree_of(num_sh_bases(d)) for d in range(4)] == [0, 1, 2, 3]
    for count in (-4, 0, 3, 25):
        with pytest.raises(ValueError, match=f"^{count} is not the coefficient count of any SH degree 0..3"):
            sh_degree_of(count)


def test_gradients_match_finite_differences():
    d = random_unit(6, seed=8).requires_grad_(True)
    coeffs = torch.randn(6, 16, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda c, x: eval_sh(c, x, 3), (coeffs, d))


def test_rgb_sh_round_trip_and_dc_evaluation():
    rgb = torch.rand(10, 3, dtype=torch.float64)
    torch.testing.assert_close(sh_to_rgb(rgb_to_sh(rgb)), rgb)
    dc_only = rgb_to_sh(rgb)[:, None, :]
    torch.testing.assert_close(eval_sh(dc_only, random_unit(10, 1), 0) + 0.5, rgb)
    torch.testing.assert_close(rgb_to_sh(torch.tensor([0.5])), torch.tensor([0.0]))
