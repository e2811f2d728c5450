"""The fast rasterizer matches the float64 brute-force reference exactly on random scenes.

The first tests pin the reference itself to hand-computed values; the rest compare the fast
rasterizer (run in float64) with it: images, alpha, depth, per-Gaussian contributions, radii,
pair counts, and the gradients of every differentiable input.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from functools import cache

import pytest
import torch

from tests.reference_rasterizer import (
    ALPHA_MAX,
    GaussianScene,
    ReferenceOutput,
    project,
    random_scene,
    reference_rasterize,
)

D = torch.float64
TOL = 1e-5


def axis_scene(means: list[list[float]], opacities: list[float], scale: float = 0.1, width: int = 8,
               height: int = 6, features: list[list[float]] | None = None) -> GaussianScene:
    """Isotropic Gaussians seen by a camera at the origin (identity pose), f = 10 px."""
    n = len(means)
    return GaussianScene(
        means=torch.tensor(means, dtype=D),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n, dtype=D),
        scales=torch.full((n, 3), scale, dtype=D),
        opacities=torch.tensor(opacities, dtype=D),
        features=torch.tensor(features, dtype=D) if features else torch.ones(n, 1, dtype=D),
        world_to_camera=torch.eye(4, dtype=D),
        K=torch.tensor([[10.0, 0.0, width / 2], [0.0, 10.0, height / 2], [0.0, 0.0, 1.0]], dtype=D),
        width=width,
        height=height,
    )


# ---------------------------------------------------------------- the reference, by hand


def test_reference_single_gaussian_matches_closed_form():
    scene = axis_scene([[0.0, 0.0, 2.0]], [0.5])
    out = scene.render(reference_rasterize)
    variance = (10 * 0.1 / 2) ** 2 + 0.3  # (f·s/z)² plus the low-pass blur
    for row, col in [(3, 4), (0, 0), (5, 7)]:
        dx, dy = col + 0.5 - 4.0, row + 0.5 - 3.0
        expected = 0.5 * math.exp(-0.5 * (dx * dx + dy * dy) / variance)
        expected = expected if expected >= 1 / 255 else 0.0
        assert out.image[row, col, 0].item() == pytest.approx(expected, abs=1e-12)
        assert out.alpha[row, col].item() == pytest.approx(expected, abs=1e-12)
    assert out.depth[3, 4].item() == pytest.approx(2.0)
    assert out.radii.tolist() == [math.ceil(3 * math.sqrt(variance))]
    torch.testing.assert_close(out.means2d, torch.tensor([[4.0, 3.0]], dtype=D))


def test_reference_composites_front_to_back_whatever_the_index_order():
    scene = axis_scene([[0.0, 0.0, 3.0], [0.0, 0.0, 2.0]], [0.6, 0.5], features=[[1.0], [10.0]])
    out = scene.render(reference_rasterize)
    a_front, a_back = out.weights[3, 4, 1].item(), out.weights[3, 4, 0].item()
    alpha_front = 0.5 * math.exp(-0.5 * 0.5 / ((10 * 0.1 / 2) ** 2 + 0.3))
    assert a_front == pytest.approx(alpha_front)
    assert a_back == pytest.approx((1 - alpha_front) * 0.6 * math.exp(-0.5 * 0.5 / ((10 * 0.1 / 3) ** 2 + 0.3)))
    assert out.image[3, 4, 0].item() == pytest.approx(10 * a_front + a_back)
    assert out.depth[3, 4].item() == pytest.approx((2 * a_front + 3 * a_back) / (a_front + a_back))


def test_reference_early_termination_and_alpha_clamp():
    # 20 coincident layers centred on pixel (3, 4): α = 0.5 each, so T = 2^-k and the 14th
    # layer would take T below 1e-4: it and all later ones are not added.
    scene = axis_scene([[0.1, 0.1, 2.0]] * 20, [0.5] * 20, scale=1e-3)
    out = scene.render(reference_rasterize)
    assert out.alpha[3, 4].item() == pytest.approx(1 - 2.0**-13)
    assert int((out.weights[3, 4] > 0).sum()) == 13
    opaque = axis_scene([[0.1, 0.1, 2.0]], [1.0], scale=1e-3).render(reference_rasterize)
    assert opaque.alpha[3, 4].item() == pytest.approx(ALPHA_MAX)


def test_reference_skips_faint_gaussians_and_culls():
    faint = axis_scene([[0.1, 0.1, 2.0]], [0.99 / 255]).render(reference_rasterize)
    assert faint.num_contributing_pairs == 0 and faint.alpha.abs().max() == 0
    culled = axis_scene([[0.0, 0.0, 0.01], [0.0, 0.0, -1.0], [50.0, 0.0, 2.0]], [0.9] * 3)
    out = culled.render(reference_rasterize)
    assert out.radii.tolist() == [0, 0, 0] and out.num_contributing_pairs == 0


def test_reference_jacobian_clamp():
    """Beyond 1.3× the half field of view, J is formed at the clamped x/z."""
    scene = axis_scene([[5.0, 0.0, 2.0]], [0.9])
    proj = project(scene.means, scene.quats, scene.scales, scene.world_to_camera, scene.K, 8, 6, 0.01, 1e10)
    x_over_z = 1.3 * 0.5 * 8 / 10.0  # clamped from 2.5
    jx = torch.tensor([10 / 2.0, 0.0, -10 * x_over_z / 2.0], dtype=D)
    expected = 0.01 * (jx @ jx) + 0.3
    assert proj.cov2d[0, 0, 0].item() == pytest.approx(expected)


@pytest.mark.parametrize(("x", "clamped_to"),
                         [(-2.0, -2.0), (-1.55, -1.55), (-3.0, -2.52), (-1.0, -1.48), (2.0, -1.48)])
def test_reference_jacobian_clamp_follows_an_off_centre_principal_point(x, clamped_to):
    """A tile of a wider photo (cx = 24 on an 8-px width, f = 10) sees x/z from -2.4 to -1.6: the clamp is that range
    widened by 0.3·(half width / f) = 0.12 on each side, [-2.52, -1.48] (not ±0.52 about the axis, which would clamp
    every Gaussian on the tile)."""
    scene = axis_scene([[x, 0.0, 1.0]], [0.9])
    scene.K[0, 2] = 24.0
    proj = project(scene.means, scene.quats, scene.scales, scene.world_to_camera, scene.K, 8, 6, 0.01, 1e10)
    jx = torch.tensor([10.0, 0.0, -10.0 * clamped_to], dtype=D)
    assert proj.cov2d[0, 0, 0].item() == pytest.approx(0.01 * (jx @ jx) + 0.3)


def test_an_off_centre_principal_point_projects_as_the_same_camera_centred_on_a_wider_image(fast):
    """A tile of a photo is the photo's camera with cx moved: the left third of a centred 72-px-wide camera (f = 10,
    cx = 36, x/z from -3.6 to 3.6) is a 24-px camera with cx = 36, which sees x/z from -3.6 to -1.2. Its Gaussians
    render as in the wide image; the clamp at ±1.3 half fields of view about the axis (±1.56) bent every one."""
    means = [[x, y, 2.0] for x in (-7.0, -6.0, -5.0, -4.0, -3.0, -2.6) for y in (-0.6, 0.0, 0.6)]
    tile = axis_scene(means, [0.7] * 18, scale=0.08, width=24, height=16)
    wide = axis_scene(means, [0.7] * 18, scale=0.08, width=72, height=16)
    tile.K[0, 2] = 36.0
    torch.testing.assert_close(tile.render(fast.rasterize).image, wide.render(fast.rasterize).image[:, :24])


# ---------------------------------------------------------------- fast vs reference


@dataclass(frozen=True)
class Case:
    seed: int
    n: int
    width: int
    height: int
    anisotropy: float = 10.0
    log_scales: bool = False
    far: float = 1e10
    background: bool = True
    opaque: bool = False
    antialiased: bool = False
    principal_point: tuple[float, float] = (0.5, 0.5)
    """(cx, cy) as fractions of the width and height: off-centre for a crop, off the image for a tile of a photo."""

    def options(self) -> dict:
        """Rasterizer keywords: log scales, and Mip-Splatting's 2D filter (blur 0.1 px², opacity compensated)."""
        return {"log_scales": self.log_scales} | ({"blur": 0.1, "antialiased": True} if self.antialiased else {})


CASES = [
    Case(0, 1, 24, 20, anisotropy=1.0),
    Case(1, 2, 24, 20),
    Case(2, 5, 20, 24, anisotropy=30.0),
    Case(3, 10, 24, 20, log_scales=True),
    Case(4, 20, 17, 13),
    Case(5, 40, 24, 20, anisotropy=3.0, background=False),
    Case(6, 60, 24, 20),
    Case(7, 100, 24, 20, far=4.0),
    Case(8, 200, 24, 20, opaque=True),
    Case(9, 150, 13, 21, anisotropy=100.0),
    Case(10, 30, 23, 7),
    Case(11, 80, 16, 16, log_scales=True),
    Case(12, 200, 16, 12, anisotropy=1.0, opaque=True),
    Case(13, 3, 5, 9),
    Case(14, 50, 24, 20, anisotropy=100.0),
    Case(15, 25, 19, 23, background=False),
    Case(16, 150, 20, 16, anisotropy=5.0, opaque=True),
    Case(17, 8, 24, 20),
    Case(18, 90, 22, 11, far=3.5),
    Case(19, 45, 24, 20, opaque=True, log_scales=True),
    Case(20, 60, 24, 20, antialiased=True),
    Case(21, 150, 20, 16, anisotropy=100.0, log_scales=True, antialiased=True),
    Case(22, 200, 16, 12, opaque=True, antialiased=True),
    Case(23, 120, 24, 20, principal_point=(0.2, 0.75)),
    Case(24, 150, 20, 16, anisotropy=30.0, principal_point=(-0.5, 1.5)),
]
IDS = [f"seed{c.seed}-n{c.n}-{c.width}x{c.height}{'-antialiased' if c.antialiased else ''}"
       + ("" if c.principal_point == (0.5, 0.5) else "-principal-point-{}-{}".format(*c.principal_point))
       for c in CASES]


def case_scene(case: Case) -> GaussianScene:
    opacity_range = (0.6, 0.9999) if case.opaque else (0.02, 0.98)
    scene = random_scene(case.seed, case.n, case.width, case.height, anisotropy=case.anisotropy,
                         opacity_range=opacity_range)
    scene.far = case.far
    scene.K[0, 2], scene.K[1, 2] = case.principal_point[0] * case.width, case.principal_point[1] * case.height
    if not case.background:
        scene.background = None
    if case.log_scales:
        scene.scales = scene.scales.log()
    return scene


def loss_weights(case: Case) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Fixed random weights so the scalar loss exercises every pixel and channel differently."""
    g = torch.Generator().manual_seed(1000 + case.seed)
    shape = (case.height, case.width)
    return (torch.randn(*shape, 3, generator=g, dtype=D), torch.randn(*shape, generator=g, dtype=D),
            torch.randn(*shape, generator=g, dtype=D))


def weighted_loss(out, weights) -> torch.Tensor:
    w_image, w_alpha, w_depth = weights
    return (out.image * w_image).sum() + (out.alpha * w_alpha).sum() + 0.1 * (out.depth * w_depth).sum()


@dataclass
class Rendered:
    out: object
    grads: dict[str, torch.Tensor]
    means2d_grad: torch.Tensor | None
    means2d_absgrad: torch.Tensor | None


def render_with_grads(case: Case, rasterize_fn) -> Rendered:
    scene = case_scene(case)
    params = scene.leaves()
    out = scene.render(rasterize_fn, params, **case.options())
    if out.means2d.requires_grad:
        out.means2d.retain_grad()
    weighted_loss(out, loss_weights(case)).backward()
    grads = {name: p.grad if p.grad is not None else torch.zeros_like(p) for name, p in params.items()}
    if isinstance(out, ReferenceOutput):
        absgrad = out.means2d_absgrad()
        signed = torch.stack([torch.zeros(2, dtype=D) if m is None or m.grad is None else m.grad.sum(0)
                              for m in out.per_pixel_means2d])
        return Rendered(out, grads, signed, absgrad)
    return Rendered(out, grads, out.means2d.grad, out.means2d_absgrad)


@cache
def reference_case(case: Case) -> Rendered:
    return render_with_grads(case, reference_rasterize)


@cache
def fast_case(case: Case) -> Rendered:
    from splatu.rasterizer import rasterize

    return render_with_grads(case, rasterize)


def assert_close(actual: torch.Tensor, expected: torch.Tensor, what: str, atol: float = TOL, rtol: float = 0.0):
    actual = actual.detach().to(D)
    expected = expected.detach().to(D)
    assert actual.shape == expected.shape, f"{what}: shape {tuple(actual.shape)} != {tuple(expected.shape)}"
    err = (actual - expected).abs()
    bound = atol + rtol * expected.abs()
    if not (err <= bound).all():
        worst = int((err - bound).flatten().argmax())
        index = tuple(int(i) for i in torch.unravel_index(torch.tensor(worst), err.shape))
        raise AssertionError(f"{what}: max |diff| {err.max().item():.3g} at {index}: "
                             f"fast {actual[index].item():.10g} vs reference {expected[index].item():.10g}")


def test_cases_exercise_every_rule():
    """The random cases reach early termination, the Jacobian clamp, and each culling rule."""
    terminated = clamped = beyond_far = off_screen = 0
    for case in CASES:
        scene, ref = case_scene(case), reference_case(case).out
        t = scene.means @ scene.world_to_camera[:3, :3].T + scene.world_to_camera[:3, 3]
        (fx, _, cx), (_, fy, cy) = scene.K[:2].tolist()
        margin_x, margin_y = 0.3 * 0.5 * scene.width / fx, 0.3 * 0.5 * scene.height / fy
        in_depth = (t[:, 2] > scene.near) & (t[:, 2] < scene.far)
        x, y = t[:, 0] / t[:, 2], t[:, 1] / t[:, 2]
        beyond = ((x < -cx / fx - margin_x) | (x > (scene.width - cx) / fx + margin_x)
                  | (y < -cy / fy - margin_y) | (y > (scene.height - cy) / fy + margin_y))
        terminated += int(ref.terminated.any())
        clamped += int((beyond & (ref.radii > 0)).sum())
        beyond_far += int((t[:, 2] >= scene.far).sum())
        off_screen += int((in_depth & (ref.radii == 0)).sum())
    assert terminated >= 4 and clamped >= 50 and beyond_far >= 50 and off_screen >= 50, (
        terminated, clamped, beyond_far, off_screen)


def test_culling_box_boundary(fast):
    """A box mean2d ± r that only touches the image edge (mx + r = 0 or mx − r = width) is culled.

    Zero scales leave cov2d = 0.3·I, so r = ceil(3·sqrt(0.3)) = 2 exactly; the centres land on
    exact binary values (fx·x/z + cx with integers).
    """
    scene = axis_scene([[-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [-0.95, 0.0, 1.0], [0.95, 0.0, 1.0]], [0.9] * 4,
                       scale=0.0, width=8, height=6)
    scene.K = torch.tensor([[10.0, 0.0, 8.0], [0.0, 10.0, 3.0], [0.0, 0.0, 1.0]], dtype=D)
    scene.means[1, 0] = 0.2  # mx = 10 = width + r
    scene.means[3, 0] = 0.15  # mx = 9.5: overlaps the image by half a pixel
    got, ref = scene.render(fast.rasterize), scene.render(reference_rasterize)
    torch.testing.assert_close(ref.means2d[:, 0], torch.tensor([-2.0, 10.0, -1.5, 9.5], dtype=D))
    assert ref.radii.tolist() == [0, 0, 2, 2]
    assert got.radii.tolist() == ref.radii.tolist()
    assert_close(got.image, ref.image, "image")


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_image_alpha_depth_match_reference(fast, case):
    got, ref = fast_case(case).out, reference_case(case).out
    assert_close(got.image, ref.image, "image")
    assert_close(got.alpha, ref.alpha, "alpha")
    assert_close(got.depth, ref.depth, "depth")


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_float32_matches_reference_closely(fast, case):
    """The training dtype. Rounding could in principle flip a pair at α = 1/255; on these seeds none
    flips (measured), so the same pairs contribute and the values agree to float32 precision."""
    scene = case_scene(case)
    got = scene.render(fast.rasterize, dtype=torch.float32, **case.options())
    ref = reference_case(case).out
    assert got.image.dtype == torch.float32
    assert got.num_contributing_pairs == ref.num_contributing_pairs
    assert torch.equal(got.radii, ref.radii)
    for name in ("image", "alpha", "depth", "contrib_max"):
        assert_close(getattr(got, name), getattr(ref, name), f"float32 {name}", atol=2e-5)
    assert_close(got.contrib_sum, ref.contrib_sum, "float32 contrib_sum", atol=2e-4)


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_per_gaussian_outputs_match_reference(fast, case):
    got, ref = fast_case(case).out, reference_case(case).out
    assert got.radii.dtype == torch.int32
    assert torch.equal(got.radii, ref.radii), f"radii differ at {torch.nonzero(got.radii != ref.radii).flatten()}"
    visible = ref.radii > 0
    assert_close(got.means2d[visible], ref.means2d[visible], "means2d", atol=1e-8)
    assert_close(got.depths[visible], ref.depths[visible], "depths", atol=1e-10)
    assert_close(got.contrib_sum, ref.contrib_sum, "contrib_sum")
    assert_close(got.contrib_max, ref.contrib_max, "contrib_max")
    assert got.num_contributing_pairs == ref.num_contributing_pairs


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_gradients_match_autograd_through_reference(fast, case):
    got, ref = fast_case(case), reference_case(case)
    for name, expected in ref.grads.items():
        scale = max(1.0, expected.abs().max().item())
        assert_close(got.grads[name], expected, f"d loss / d {name}", atol=1e-7 * scale, rtol=1e-6)


@pytest.mark.parametrize("case", CASES[::3], ids=IDS[::3])
def test_gradients_of_a_loss_on_the_image_alone_match_reference(fast, case):
    """Training's loss reads the image only, so Σ w·z and alpha get zero upstream gradients (their channels of
    the extended features then have none); the gradients and the absolute 2D-mean gradients match the reference."""
    w_image = loss_weights(case)[0]
    rendered = {}
    for name, rasterize_fn in (("fast", fast.rasterize), ("reference", reference_rasterize)):
        scene = case_scene(case)
        params = scene.leaves()
        out = scene.render(rasterize_fn, params, **case.options())
        (out.image * w_image).sum().backward()
        absgrad = out.means2d_absgrad() if isinstance(out, ReferenceOutput) else out.means2d_absgrad
        rendered[name] = ({n: p.grad if p.grad is not None else torch.zeros_like(p) for n, p in params.items()},
                          absgrad)
    (got, got_absgrad), (ref, ref_absgrad) = rendered["fast"], rendered["reference"]
    for name, expected in ref.items():
        scale = max(1.0, expected.abs().max().item())
        assert_close(got[name], expected, f"d image loss / d {name}", atol=1e-7 * scale, rtol=1e-6)
    assert_close(got_absgrad, ref_absgrad, "absgrad", atol=1e-7 * max(1.0, ref_absgrad.abs().max().item()), rtol=1e-6)


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_means2d_gradients_match_reference(fast, case):
    got, ref = fast_case(case), reference_case(case)
    visible = ref.out.radii > 0
    assert got.means2d_absgrad is not None, "means2d_absgrad is not filled by backward"
    scale = max(1.0, ref.means2d_absgrad.abs().max().item())
    assert_close(got.means2d_absgrad[visible], ref.means2d_absgrad[visible], "means2d_absgrad",
                 atol=1e-7 * scale, rtol=1e-6)
    assert got.means2d_grad is not None, "means2d.grad is not available after retain_grad()"
    assert_close(got.means2d_grad[visible], ref.means2d_grad[visible], "means2d grad", atol=1e-7 * scale, rtol=1e-6)


@pytest.mark.parametrize("case", CASES[::4], ids=IDS[::4])
def test_weights_sum_to_alpha_per_pixel(fast, case):
    """One-hot features make the image the per-pixel weights w_i: they sum to 1 − T_final."""
    scene = case_scene(case)
    scene.features = torch.eye(case.n, dtype=D)
    scene.background = None
    out = scene.render(fast.rasterize, **case.options())
    weights = out.image
    assert_close(weights.sum(-1), out.alpha, "sum_i w_i vs alpha", atol=1e-10)
    assert_close(weights.sum((0, 1)), out.contrib_sum, "sum_p w vs contrib_sum", atol=1e-10)
    assert_close(weights.amax((0, 1)), out.contrib_max, "max_p w vs contrib_max", atol=1e-10)
    assert_close(weights, reference_case(case).out.weights, "per-pixel weights")
    assert int((weights > 0).sum()) == out.num_contributing_pairs


def test_gradcheck_tiny_scene(fast):
    scene = random_scene(seed=77, n=3, width=6, height=5, anisotropy=3.0)
    params = scene.leaves()

    def render(means, quats, scales, opacities, features):
        out = fast.rasterize(means, quats, scales, opacities, features, scene.world_to_camera, scene.K,
                             scene.width, scene.height, background=scene.background)
        return out.image, out.alpha, out.depth

    assert torch.autograd.gradcheck(render, tuple(params.values()), eps=1e-7, atol=1e-6, fast_mode=True)


OPAQUE = [c for c in CASES if c.opaque]


@pytest.fixture
def one_gaussian_rounds(monkeypatch):
    """A depth round per Gaussian and chunks of three entries; returns (entries listed, entries composited)."""
    raster_module = sys.modules["splatu.rasterizer.rasterize"]
    function_module = sys.modules["splatu.rasterizer.function"]
    footprint = sys.modules["splatu.rasterizer.footprint"]
    monkeypatch.setattr(footprint, "MAX_ROUNDS", 10_000)
    monkeypatch.setattr(footprint, "ROUND_MIN_ENTRIES", 1)
    monkeypatch.setattr(raster_module, "MAX_CHUNK_ELEMENTS", 24)
    listed, composited = [], []
    block_entries, forward_chunk = raster_module.block_entries, function_module.forward_chunk

    def recording_block_entries(*args):
        entries = block_entries(*args)
        listed.append(entries.key.numel())
        return entries

    def recording_forward_chunk(entries, chunk, *args):
        composited.append(chunk[0].numel())
        return forward_chunk(entries, chunk, *args)

    monkeypatch.setattr(raster_module, "block_entries", recording_block_entries)
    monkeypatch.setattr(function_module, "forward_chunk", recording_forward_chunk)
    return listed, composited


def assert_matches_reference(got: Rendered, ref: Rendered) -> None:
    for name in ("image", "alpha", "depth", "contrib_sum", "contrib_max"):
        assert_close(getattr(got.out, name), getattr(ref.out, name), name)
    assert got.out.num_contributing_pairs == ref.out.num_contributing_pairs
    for name, expected in ref.grads.items():
        scale = max(1.0, expected.abs().max().item())
        assert_close(got.grads[name], expected, f"d loss / d {name}", atol=1e-7 * scale, rtol=1e-6)


@pytest.mark.parametrize("case", OPAQUE, ids=[f"seed{c.seed}" for c in OPAQUE])
def test_one_gaussian_rounds_and_tiny_chunks_match_reference(fast, case, one_gaussian_rounds):
    """T (forward) and Σ w g (backward) are carried across every chunk boundary without changing a value."""
    _, composited = one_gaussian_rounds
    assert_matches_reference(render_with_grads(case, fast.rasterize), reference_case(case))
    assert max(composited) <= 3 and len(composited) > 10


def test_terminated_blocks_are_skipped_exactly(fast, one_gaussian_rounds):
    """Behind a stack of opaque layers covering the image, later rounds skip the blocks, values unchanged."""
    listed, composited = one_gaussian_rounds
    layers = 12
    scene = axis_scene([[0.02 * k, -0.01 * k, 1.0 + 0.1 * k] for k in range(layers)], [0.99] * layers, scale=5.0,
                       width=16, height=6, features=[[k / layers, 1.0 - k / layers, 0.5] for k in range(layers)])

    def rendered(rasterize_fn) -> Rendered:
        params = scene.leaves()
        out = scene.render(rasterize_fn, params)
        (out.image.square().sum() + out.alpha.sum() + 0.1 * out.depth.sum()).backward()
        return Rendered(out, {name: p.grad for name, p in params.items()}, None, None)

    assert_matches_reference(rendered(fast.rasterize), rendered(reference_rasterize))
    assert sum(composited) < 0.5 * listed[0], (sum(composited), listed[0])


WITH_DEAD_ENTRIES = [c for c in OPAQUE if c.seed in (8, 12, 22)]
"""Opaque cases with chunks that mix live and dead entries under one_gaussian_rounds (the test asserts it)."""
assert len(WITH_DEAD_ENTRIES) == 3, "the random cases changed: pick opaque cases with dead entries again"


@pytest.mark.parametrize("case", WITH_DEAD_ENTRIES, ids=[f"seed{c.seed}" for c in WITH_DEAD_ENTRIES])
def test_keeping_dead_entries_changes_no_value(fast, case, monkeypatch, one_gaussian_rounds):
    """A chunk that is nearly all live keeps its dead entries instead of compacting them away (composite.py,
    COMPACT_AT_MOST_LIVE). Their w, T and gradients are exactly 0, so every output and gradient equals the
    always-compacted render's, with and without a contribution mask and without gradients: the images bit for
    bit, the gradients to rounding (eager torch may reduce a (B, Q) tensor over B in another order when Q
    differs)."""
    composite_module = sys.modules["splatu.rasterizer.composite"]
    function_module = sys.modules["splatu.rasterizer.function"]
    forward_chunk = function_module.forward_chunk
    mask = torch.rand(case.height, case.width, generator=torch.Generator().manual_seed(case.seed)) < 0.5

    def rendered(compact_at_most_live: float, contribution_mask) -> tuple[Rendered, list[int]]:
        """The render with gradients, and the number of entries each chunk saved for the backward."""
        monkeypatch.setattr(composite_module, "COMPACT_AT_MOST_LIVE", compact_at_most_live)
        saved = []

        def recording_forward_chunk(*args):
            state = forward_chunk(*args)
            saved.append(state.transmittance.shape[1])
            return state

        monkeypatch.setattr(function_module, "forward_chunk", recording_forward_chunk)
        result = render_with_grads(case, lambda *a, **k: fast.rasterize(*a, contribution_mask=contribution_mask,
                                                                        **k))
        monkeypatch.setattr(function_module, "forward_chunk", forward_chunk)
        return result, saved

    def rendered_without_grad(compact_at_most_live: float, contribution_mask):
        monkeypatch.setattr(composite_module, "COMPACT_AT_MOST_LIVE", compact_at_most_live)
        with torch.no_grad():
            return case_scene(case).render(fast.rasterize, contribution_mask=contribution_mask, **case.options())

    outputs = ("image", "alpha", "depth", "contrib_sum", "contrib_max")
    for contribution_mask in (None, mask):
        (compacted, compacted_sizes), (kept, kept_sizes) = (rendered(limit, contribution_mask) for limit in (1.0, -1.0))
        assert any(0 < c < k for c, k in zip(compacted_sizes, kept_sizes, strict=True)), "no chunk mixes live and dead"
        for name in outputs:
            assert torch.equal(getattr(kept.out, name), getattr(compacted.out, name)), name
        gradients = {**compacted.grads, "means2d_absgrad": compacted.out.means2d_absgrad}
        for name, grad in gradients.items():
            other = kept.out.means2d_absgrad if name == "means2d_absgrad" else kept.grads[name]
            assert_close(other, grad, name, atol=1e-13 * max(1.0, grad.abs().max().item()))
        no_grad_compacted, no_grad_kept = (rendered_without_grad(limit, contribution_mask) for limit in (1.0, -1.0))
        for name in outputs:
            assert torch.equal(getattr(no_grad_kept, name), getattr(no_grad_compacted, name)), name
            assert torch.equal(getattr(no_grad_kept, name), getattr(kept.out, name).detach()), name


@pytest.mark.parametrize("case", CASES[1:8:2], ids=IDS[1:8:2])
@pytest.mark.parametrize("grad", [True, False], ids=["with-grad", "no-grad"])
def test_a_contribution_mask_counts_only_its_pixels_and_changes_nothing_else(fast, case, grad, one_gaussian_rounds):
    """Contributions over the masked pixels equal the reference's per-pixel weights summed and maxed over them,
    across chunk and round boundaries; images, gradients and liveness are those of the unmasked render."""
    from splatu.rasterizer import rasterize

    scene = case_scene(case)
    mask = torch.rand(case.height, case.width, generator=torch.Generator().manual_seed(case.seed)) < 0.5
    ref = reference_case(case)
    counted = ref.out.weights * mask[..., None]
    with torch.set_grad_enabled(grad):
        params = scene.leaves()
        got = scene.render(rasterize, params, contribution_mask=mask, **case.options())
        if grad:
            weighted_loss(got, loss_weights(case)).backward()
    assert_close(got.contrib_sum, counted.sum((0, 1)), "masked contrib_sum")
    assert_close(got.contrib_max, counted.amax((0, 1)) if counted.numel() else counted.sum((0, 1)),
                 "masked contrib_max")
    for name in ("image", "alpha", "depth"):
        assert_close(getattr(got, name), getattr(ref.out, name), name)
    assert got.num_contributing_pairs == ref.out.num_contributing_pairs
    if grad:
        for name, expected in ref.grads.items():
            scale = max(1.0, expected.abs().max().item())
            assert_close(params[name].grad, expected, f"d loss / d {name}", atol=1e-7 * scale, rtol=1e-6)


def test_terminated_blocks_past_the_image_edge_are_skipped_too(fast, one_gaussian_rounds):
    """13 px wide: each row's second block has 3 columns outside the image, which no Gaussian ever reaches, so
    their T stays 1; the skip must look at the in-image pixels only, or no such block is ever skipped."""
    listed, composited = one_gaussian_rounds
    layers = 12
    scene = axis_scene([[0.02 * k, -0.01 * k, 1.0 + 0.1 * k] for k in range(layers)], [0.99] * layers, scale=5.0,
                       width=13, height=6, features=[[k / layers, 1.0 - k / layers, 0.5] for k in range(layers)])
    got, ref = scene.render(fast.rasterize), scene.render(reference_rasterize)
    for name in ("image", "alpha", "depth", "contrib_sum", "contrib_max"):
        assert_close(getattr(got, name), getattr(ref, name), name)
    assert sum(composited) < 0.5 * listed[0], (sum(composited), listed[0])
