"""Degenerate inputs: the fast rasterizer's outputs and gradients stay finite and still match the reference.

Each case is its own test. Values are compared with the float64 reference where the case
has a well-defined image; float32 runs (the training dtype) must at least stay finite.
"""

from __future__ import annotations

import math

import pytest
import torch

from splatu.rasterizer.projection import MIN_QUATERNION_NORM
from splatu.sh import eval_sh
from tests.reference_rasterizer import GaussianScene, random_scene, reference_rasterize

D = torch.float64
DTYPES = [torch.float32, torch.float64]


def scene_at_origin(means: list[list[float]], scales: list[list[float]] | float, opacities: list[float] | float,
                    width: int = 8, height: int = 6, focal: float = 10.0, seed: int = 0) -> GaussianScene:
    """Gaussians with random rotations and colours, seen by a camera at the origin looking down +z."""
    g = torch.Generator().manual_seed(seed)
    n = len(means)
    scale_tensor = torch.full((n, 3), scales, dtype=D) if isinstance(scales, float) else torch.tensor(scales, dtype=D)
    opacity_tensor = torch.full((n,), opacities, dtype=D) if isinstance(opacities, float) else torch.tensor(
        opacities, dtype=D)
    return GaussianScene(
        means=torch.tensor(means, dtype=D).reshape(n, 3),
        quats=torch.randn(n, 4, generator=g, dtype=D),
        scales=scale_tensor.reshape(n, 3),
        opacities=opacity_tensor,
        features=torch.rand(n, 3, generator=g, dtype=D),
        world_to_camera=torch.eye(4, dtype=D),
        K=torch.tensor([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]], dtype=D),
        width=width,
        height=height,
        background=torch.tensor([0.2, 0.4, 0.6], dtype=D),
    )


def render_backward(fast, scene: GaussianScene, dtype: torch.dtype, **options):
    """Render with the fast rasterizer, backpropagate a loss touching every output, check all is finite."""
    params = scene.leaves(dtype)
    out = scene.render(fast.rasterize, params, dtype=dtype, **options)
    g = torch.Generator().manual_seed(5)
    loss = (out.image * torch.randn(out.image.shape, generator=g, dtype=dtype)).sum() + out.alpha.sum()
    loss = loss + 0.1 * out.depth.sum()
    for name in ("image", "alpha", "depth", "means2d", "contrib_sum", "contrib_max", "depths"):
        value = getattr(out, name)
        assert torch.isfinite(value).all(), f"{name} has non-finite values"
    if loss.requires_grad:
        loss.backward()
    for name, p in params.items():
        assert p.grad is None or torch.isfinite(p.grad).all(), f"gradient of {name} is not finite: {p.grad}"
    assert torch.isfinite(out.means2d_absgrad).all(), "means2d_absgrad is not finite"
    return out, params


def reference_backward(scene: GaussianScene, **options):
    params = scene.leaves(D)
    out = scene.render(reference_rasterize, params, **options)
    g = torch.Generator().manual_seed(5)
    loss = (out.image * torch.randn(out.image.shape, generator=g, dtype=D)).sum() + out.alpha.sum()
    loss = loss + 0.1 * out.depth.sum()
    if loss.requires_grad:
        loss.backward()
    return out, params


def assert_matches_reference(fast, scene: GaussianScene, grads: bool = True, radii: bool = True, **options) -> None:
    """float64 fast vs reference: images, contributions, pair count and (optionally) radii and gradients."""
    got, got_params = render_backward(fast, scene, D, **options)
    ref, ref_params = reference_backward(scene, **options) if grads else (scene.render(reference_rasterize,
                                                                                        **options), None)
    for name in ("image", "alpha", "depth", "contrib_sum", "contrib_max"):
        torch.testing.assert_close(getattr(got, name).detach(), getattr(ref, name).detach(), rtol=0, atol=1e-5,
                                   msg=lambda m, name=name: f"{name}: {m}")
    assert not radii or torch.equal(got.radii, ref.radii), (got.radii, ref.radii)
    assert got.num_contributing_pairs == ref.num_contributing_pairs
    if grads:
        for name, p in ref_params.items():
            expected = p.grad if p.grad is not None else torch.zeros_like(p)
            actual = got_params[name].grad if got_params[name].grad is not None else torch.zeros_like(p)
            scale = max(1.0, expected.abs().max().item())
            torch.testing.assert_close(actual, expected, rtol=1e-6, atol=1e-7 * scale,
                                       msg=lambda m, name=name: f"d loss / d {name}: {m}")


@pytest.mark.parametrize("dtype", DTYPES)
def test_gaussians_on_and_behind_the_near_plane(fast, dtype):
    near = 0.01
    scene = scene_at_origin(
        [[0.0, 0.0, near], [0.0, 0.0, 0.0], [0.1, 0.0, -1.0], [0.0, 0.0, near * (1 + 1e-3)], [0.1, 0.1, 2.0]],
        0.05, 0.8)
    out, _ = render_backward(fast, scene, dtype)
    assert out.radii[:3].tolist() == [0, 0, 0]
    assert out.radii[3] > 0 and out.radii[4] > 0
    if dtype == D:
        assert_matches_reference(fast, scene)


@pytest.mark.parametrize("dtype", DTYPES)
def test_zero_scales(fast, dtype):
    scene = scene_at_origin([[0.1, 0.1, 2.0], [-0.2, 0.0, 3.0]], 0.0, 0.9)
    out, _ = render_backward(fast, scene, dtype)
    assert out.num_contributing_pairs > 0  # the 0.3 px² blur keeps a point visible
    if dtype == D:
        assert_matches_reference(fast, scene)


@pytest.mark.parametrize("dtype", DTYPES)
def test_zero_scales_antialiased_fade_out_with_finite_gradients(fast, dtype):
    """Mip-Splatting's 2D filter scales opacity by sqrt(det Σ₂ / det(Σ₂ + blur I)), 0 for a point: it vanishes,
    and the factor's gradient (through |minors|, not sqrt(det Σ₂)) stays finite where det Σ₂ = 0."""
    scene = scene_at_origin([[0.1, 0.1, 2.0], [-0.2, 0.0, 3.0]], 0.0, 0.9)
    out, params = render_backward(fast, scene, dtype, blur=0.1, antialiased=True)
    assert out.num_contributing_pairs == 0 and float(out.alpha.detach().max()) == 0.0
    assert all(p.grad is None or torch.isfinite(p.grad).all() for p in params.values())


@pytest.mark.parametrize("dtype", DTYPES)
def test_rank_deficient_covariances_antialiased(fast, dtype):
    """Flat and needle Gaussians (one or two zero scales) under the 2D filter: a disc seen face-on keeps its
    footprint, the needle along the view axis projects to a point and fades; both match the reference."""
    scene = scene_at_origin(
        [[0.1, 0.1, 2.0], [-0.2, 0.05, 2.5], [0.0, -0.1, 3.0]],
        [[0.3, 0.1, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 0.5]], 0.8, seed=3)
    scene.quats[0] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=D)  # a disc facing the camera
    scene.quats[2] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=D)  # a needle along the view axis
    out, _ = render_backward(fast, scene, dtype, blur=0.1, antialiased=True)
    assert out.contrib_max[0] > 0.5 and out.contrib_max[2] == 0.0
    if dtype == D:
        assert_matches_reference(fast, scene, grads=False, blur=0.1, antialiased=True)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("log_scales", [False, True])
def test_enormous_scales(fast, dtype, log_scales):
    scene = scene_at_origin([[0.1, 0.1, 2.0], [0.0, 0.0, 5.0]], 1e6, [0.5, 0.7])
    if log_scales:
        scene.scales = scene.scales.log()
    out, _ = render_backward(fast, scene, dtype, log_scales=log_scales)
    assert out.radii.min() > 1000
    # Flat to within 1e-6 over the image: the front Gaussian alone covers everything with α ≈ 0.5.
    torch.testing.assert_close(out.alpha, torch.full_like(out.alpha, 1 - 0.5 * 0.3), rtol=0, atol=1e-5)
    if dtype == D:
        assert_matches_reference(fast, scene, log_scales=log_scales)


@pytest.mark.parametrize("dtype", DTYPES)
def test_rank_deficient_covariances(fast, dtype):
    scene = scene_at_origin(
        [[0.1, 0.1, 2.0], [-0.2, 0.05, 2.5], [0.0, -0.1, 3.0], [0.05, 0.0, 1.5]],
        [[0.3, 0.1, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 0.5], [0.0, 0.0, 0.0]],
        0.8, seed=3)
    scene.quats[2] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=D)  # a needle along the view axis
    render_backward(fast, scene, dtype)
    if dtype == D:
        assert_matches_reference(fast, scene)


@pytest.mark.parametrize("dtype", DTYPES)
def test_opacity_near_zero(fast, dtype):
    scene = scene_at_origin([[0.1, 0.1, 2.0], [0.0, 0.0, 3.0]], 0.2, [1e-8, 0.99 / 255])
    out, _ = render_backward(fast, scene, dtype)
    assert out.num_contributing_pairs == 0
    assert out.alpha.abs().max() == 0
    torch.testing.assert_close(out.image, scene.background.to(dtype).expand_as(out.image))
    if dtype == D:
        assert_matches_reference(fast, scene)


@pytest.mark.parametrize("dtype", DTYPES)
def test_opacity_near_one_clamps_alpha(fast, dtype):
    scene = scene_at_origin([[0.1, 0.1, 2.0]], 0.05, 1 - 1e-7)
    out, _ = render_backward(fast, scene, dtype)
    assert out.alpha[3, 4].item() == pytest.approx(0.99, abs=1e-6)
    assert out.alpha.max().item() <= 0.99 + 1e-6
    if dtype == D:
        assert_matches_reference(fast, scene)


def test_2000_coincident_layers_terminate_early(fast):
    """T would underflow to 0 without the 1e-4 stop; with it, T_final ≥ 1e-4 at every pixel."""
    layers = 2000
    scene = scene_at_origin([[0.05, 0.05, 2.0]] * layers, 0.3, 0.5, width=5, height=4)
    scene.quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * layers, dtype=D)
    out32, _ = render_backward(fast, scene, torch.float32)
    assert out32.alpha.max().item() <= 1 - 1e-4 + 1e-6
    assert out32.alpha.min().item() >= 1 - 2e-4  # α ≥ 0.5·e^(−σ) per layer still saturates every pixel
    assert_matches_reference(fast, scene)


@pytest.mark.parametrize("dtype", DTYPES)
def test_offscreen_centre_whose_footprint_covers_the_image(fast, dtype):
    scene = scene_at_origin([[-6.0, -4.0, 2.0]], [[3.0, 3.0, 3.0]], 0.9, width=8, height=6)
    out, _ = render_backward(fast, scene, dtype)
    assert out.means2d[0, 0] < 0 and out.means2d[0, 1] < 0
    assert out.radii[0] > 0 and (out.alpha > 1 / 255).all()
    if dtype == D:
        assert_matches_reference(fast, scene)


@pytest.mark.parametrize("dtype", DTYPES)
def test_a_footprint_wider_than_the_radius_cap_centred_far_off_screen_still_covers_the_image(fast, dtype):
    """The radius is stored capped at 2³⁰ px; the on-screen test used the capped value, so a Gaussian centred
    1e10 px away with a far wider footprint was culled and the image left empty."""
    scene = scene_at_origin([[1e9, 0.0, 1.0]], [[1e12, 1e12, 1e12]], 0.8, width=16, height=16)
    out, _ = render_backward(fast, scene, dtype)
    assert out.radii[0] == 2**30 and out.means2d[0, 0] > 2**30
    assert torch.allclose(out.alpha, torch.full_like(out.alpha, 0.8), atol=1e-6)


def needle(offset: float, angle: float, length_px: float, width_px: float = 0.32, size: int = 64,
           focal: float = 64.0) -> GaussianScene:
    """One long thin Gaussian lying along `angle` in the image plane; its centre projects `offset` px back
    along that line from a point near the image centre (sub-pixel, so no coordinate is a round number)."""
    depth = 2.0
    scene = scene_at_origin([[0.0, 0.0, depth]], [[length_px * depth / focal, width_px * depth / focal,
                                                   width_px * depth / focal]], 0.9,
                            width=size, height=size, focal=focal)
    scene.quats = torch.tensor([[math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)]], dtype=D)  # x → angle
    scene.K[0, 2] = size / 2 + 0.37 - offset * math.cos(angle)  # the mean sits on the axis, unclamped by the
    scene.K[1, 2] = size / 2 + 0.21 - offset * math.sin(angle)  # FoV rule, and projects at (cx, cy)
    return scene


def render_with_one_loss(fast, scene: GaussianScene, dtype: torch.dtype):
    """Render and backpropagate Σ image·weights with the same float64 weights in any dtype (render_backward draws
    its weights in the render's dtype, so its float32 and float64 losses differ)."""
    weights = torch.randn(scene.height, scene.width, 3, generator=torch.Generator().manual_seed(1), dtype=D)
    params = scene.leaves(dtype)
    out = scene.render(fast.rasterize, params, dtype=dtype)
    (out.image * weights.to(dtype)).sum().backward()
    return out, params


def assert_float32_gradients_match(grads32: dict, grads64: dict) -> None:
    for name in ("means", "quats"):
        torch.testing.assert_close(grads32[name].grad.double(), grads64[name].grad, rtol=1e-2, atol=1e-6,
                                   msg=lambda m, name=name: f"float32 d loss / d {name}: {m}")


@pytest.mark.parametrize("angle", [math.pi / 4, 0.6, math.pi / 2 - 0.6])  # 0.6 is swapped, π/2 − 0.6 is not
@pytest.mark.parametrize("offset", [0.0, 3000.0, 30000.0])
def test_a_long_thin_gaussian_centred_far_off_screen_renders_the_same_in_float32(fast, offset, angle):
    """A needle crossing the image whose centre is `offset` px off-screen. Its conic terms ½a·dx², b·dx·dy and
    ½c·dy² are each ~10⁷ at 3,000 px and cancel to about 1: summed in float32 they moved α by up to 0.53
    (3,000 px) and 0.9 (30,000 px). The sheared form leaves a position error of about one float32 step of the
    offset (2e-3 px at 30,000 px), and α across this 0.63 px-wide needle changes by up to about 1.2 per px, so the
    bound grows with the offset: 2.5e-3 at 30,000 px."""
    scene = needle(offset, angle, length_px=max(2.0 * offset, 200.0))
    render_backward(fast, scene, torch.float32)  # every output and gradient finite
    out64, grads64 = render_with_one_loss(fast, scene, D)
    out32, grads32 = render_with_one_loss(fast, scene, torch.float32)
    assert (out64.alpha > 0.6).sum() >= 64  # the needle crosses the image
    assert (out64.alpha.double() - out32.alpha.double()).abs().max() < 1e-4 + 8e-8 * offset
    if offset <= 3000.0:
        assert_float32_gradients_match(grads32, grads64)
        assert_matches_reference(fast, scene)
    else:  # the reference's own det = ac − b² cancels to ~5e-10 of its terms, so its sums drift by ~1e-5
        ref = scene.render(reference_rasterize)
        for name in ("image", "alpha", "depth", "contrib_max"):
            torch.testing.assert_close(getattr(out64, name).detach(), getattr(ref, name), rtol=0, atol=1e-5)
        torch.testing.assert_close(out64.contrib_sum.detach(), ref.contrib_sum, rtol=1e-6, atol=0)


def test_a_needle_tilted_just_off_the_x_axis_renders_and_differentiates_the_same_in_float32(fast):
    """A needle 5·10³⁹ px long (scale 10³⁰, the cap), tilted off the x axis by its width over its length, is a
    horizontal band a few rows tall across the image. With w = dy always (commit 9ee9f26) its form had
    S ≈ 4·10³⁹ (beyond float32) and A ≈ 10⁻⁷⁹: float32 rendered nothing, and in float64 the gradient of its
    rotation read −1.9e-55 instead of −262. With w the longer axis, |S| ≤ 1 and float32 matches float64. (The
    reference's det = ac − b² cancels here, so the band is checked against its closed form: across the image the
    tilt moves it 10⁻³⁸ px.)"""
    focal, length, width = 1e10, 5e39, 0.32
    scene = needle(0.0, math.sqrt(0.3 + width * width) / length, length_px=length, width_px=width, focal=focal)
    render_backward(fast, scene, torch.float32)  # every output and gradient finite
    out64, grads64 = render_with_one_loss(fast, scene, D)
    out32, grads32 = render_with_one_loss(fast, scene, torch.float32)
    dy = torch.arange(scene.height, dtype=D) + 0.5 - scene.K[1, 2]
    band = 0.9 * torch.exp(-0.5 * dy * dy / (width * width + 0.3))
    expected = torch.where(band >= 1 / 255, band, 0.0)[:, None].expand(-1, scene.width)
    torch.testing.assert_close(out64.alpha.detach(), expected, rtol=0, atol=1e-9)
    torch.testing.assert_close(out32.alpha.detach().double(), expected, rtol=0, atol=1e-6)
    assert_float32_gradients_match(grads32, grads64)


def test_culled_gaussians_beyond_float32_range_give_finite_outputs(fast):
    """A culled mean's projection u = fx·x + cx (depth held at 1) overflowed float32 to inf, and so did a depth
    past 3.4e38; neither is drawn, and render_backward checks every output is finite."""
    behind = scene_at_origin([[1e38, 0.0, -1.0], [0.0, 0.0, 2.0]], 0.1, 0.5)  # u = 10·x: 1e39
    beyond = scene_at_origin([[0.0, 0.0, 3e38]], 0.1, 0.5)
    beyond.world_to_camera[2, 3] = 1e38  # camera-space z = 4e38
    assert render_backward(fast, behind, torch.float32)[0].radii[0] == 0
    assert render_backward(fast, beyond, torch.float32)[0].radii[0] == 0


@pytest.mark.parametrize("dtype", DTYPES)
def test_one_pixel_image(fast, dtype):
    scene = random_scene(seed=4, n=20, width=1, height=1)
    out, _ = render_backward(fast, scene, dtype)
    assert out.image.shape == (1, 1, 3)
    if dtype == D:
        assert_matches_reference(fast, scene)


def test_non_square_image_not_a_multiple_of_16(fast):
    scene = random_scene(seed=6, n=40, width=37, height=23)
    out, _ = render_backward(fast, scene, torch.float32)
    assert out.image.shape == (23, 37, 3)
    assert_matches_reference(fast, scene)


INPUT_NAMES = ["means", "quats", "scales", "opacities", "features", "world_to_camera", "K", "background"]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
@pytest.mark.parametrize("name", INPUT_NAMES)
def test_non_finite_input_raises_a_clear_error(fast, name, bad):
    scene = random_scene(seed=1, n=5, width=8, height=6)
    tensor = getattr(scene, name).clone()
    tensor.view(-1)[0] = bad
    setattr(scene, name, tensor)
    with pytest.raises(fast.NonFiniteInputError, match=name):
        scene.render(fast.rasterize)


def test_zero_length_sh_direction_stays_finite(fast):
    """A Gaussian sitting on the camera centre has no view direction: its colour is its DC term."""
    scene = scene_at_origin([[0.0, 0.0, 0.0], [0.1, 0.1, 2.0]], 0.1, 0.8)
    sh = torch.randn(2, 16, 3, dtype=D, requires_grad=True)
    means = scene.means.clone().requires_grad_(True)
    camera_centre = torch.zeros(3, dtype=D)
    colours = eval_sh(sh, means - camera_centre, 3) + 0.5
    assert torch.isfinite(colours).all()
    out = fast.rasterize(means, scene.quats, scene.scales, scene.opacities, colours, scene.world_to_camera, scene.K,
                         scene.width, scene.height)
    (out.image.sum() + colours.sum()).backward()
    assert torch.isfinite(out.image).all()
    assert torch.isfinite(sh.grad).all() and torch.isfinite(means.grad).all()
    assert (sh.grad[0, 1:] == 0).all()  # only the DC term of the centred Gaussian is used


@pytest.mark.parametrize("name", ["means", "world_to_camera", "K"])
def test_float64_geometry_beyond_float32_s_range_is_a_clear_error(fast, name):
    """A float64 mean at 1e300 (or a focal length of 1e300 px) projected to 1e300 px and beyond, and the projection's
    gradients (f·x/z², squares of the footprint) overflowed float64 to NaN: float64 renders take float32's range."""
    scene = random_scene(seed=1, n=5, width=8, height=6)
    getattr(scene, name)[0, 0] = 1e300
    with pytest.raises(fast.RasterInputError, match=f"`{name}`.*float32's range"):
        scene.render(fast.rasterize)


@pytest.mark.parametrize("with_background", [True, False])
def test_no_gaussians_gives_the_background(fast, with_background):
    scene = random_scene(seed=2, n=0, width=7, height=5)
    if not with_background:
        scene.background = None
    out = scene.render(fast.rasterize)
    expected = scene.background if with_background else torch.zeros(3, dtype=D)
    torch.testing.assert_close(out.image, expected.expand(5, 7, 3))
    assert (out.alpha == 0).all() and (out.depth == 0).all()
    assert out.radii.shape == (0,) and out.contrib_sum.shape == (0,) and out.contrib_max.shape == (0,)
    assert out.num_contributing_pairs == 0


@pytest.mark.parametrize(("near", "far"), [(-1.0, 100.0), (0.0, 100.0), (math.nan, 100.0), (0.01, math.nan),
                                           (5.0, 1.0), (math.inf, math.inf), (1.0, 1.0), (1e-300, 100.0)])
def test_a_near_and_far_that_are_no_positive_range_are_a_clear_error(fast, near, far):
    """near ≤ 0 divided by a zero depth (NaN gradients); NaN or near > far culled everything without a word. A near
    below float32's smallest normal number let a float64 depth of 1e-200 through, whose f·x/z² overflowed float64 in
    the gradients."""
    scene = random_scene(seed=1, n=5, width=8, height=6)
    scene.near, scene.far = near, far
    with pytest.raises(fast.RasterInputError, match="near"):
        scene.render(fast.rasterize)


def test_depth_has_no_gradient_where_nothing_was_drawn(fast):
    """Σw·z / alpha.clamp(1e-10) sent 1e10 upstream at empty pixels; times a far depth it overflowed float32, and
    the backward's 0·inf made every gradient NaN (far = inf lets such a depth through)."""
    scene = scene_at_origin([[0.1, 0.1, 2.0], [0.0, 0.0, 1e29]], [[0.1] * 3, [1e28] * 3], [0.7, 0.5])
    scene.far = math.inf
    params = scene.leaves(torch.float32)
    out = scene.render(fast.rasterize, params, dtype=torch.float32)
    assert (out.alpha == 0).any()
    out.depth.sum().backward()
    for name, p in params.items():
        assert torch.isfinite(p.grad).all(), name


@pytest.mark.parametrize(("dtype", "factor"), [(torch.float32, 1e-13), (torch.float32, 1e-20), (torch.float32, 1e15),
                                               (D, 1e-100), (D, 1e200)])
def test_a_quaternion_s_scale_does_not_change_the_rotation(fast, dtype, factor):
    """Its norm was clamped at 1e-12, so q·1e-13 drew another shape, and q·1e200's norm overflowed to the identity."""
    scene = random_scene(seed=3, n=12, width=16, height=12)
    scene.quats = scene.quats / scene.quats.norm(dim=-1, keepdim=True)
    expected = render_backward(fast, scene, dtype)[0]
    scene.quats = scene.quats * factor
    got, params = render_backward(fast, scene, dtype)
    torch.testing.assert_close(got.image, expected.image, rtol=0, atol=1e-5)
    assert params["quats"].grad.abs().max() > 0


def test_summed_contribution_of_a_frame_filling_gaussian_is_accurate_in_float32(fast):
    """Summed in float32, one Gaussian over a 4096×3072 frame read 0.58% short (a numerics review)."""
    scene = scene_at_origin([[0.0, 0.0, 2.0]], 50.0, 0.9, width=1024, height=1024, focal=100.0)
    sums = [scene.render(fast.rasterize, dtype=dtype).contrib_sum.double() for dtype in (torch.float32, D)]
    torch.testing.assert_close(sums[0], sums[1], rtol=1e-6, atol=0)


def test_opacity_of_exactly_one_255th_is_drawn_where_it_is_centred(fast):
    """At the mean α = o·e^0 = 1/255, which passes α ≥ 1/255 (255·(1/255) is exactly 1 in float64): one pair."""
    scene = scene_at_origin([[0.0, 0.0, 2.0]], 0.2, 1 / 255)
    scene.K[0, 2], scene.K[1, 2] = 4.5, 3.5  # the mean projects onto the centre of pixel (3, 4)
    out, _ = render_backward(fast, scene, D)
    assert out.num_contributing_pairs == 1 and out.alpha[3, 4].item() == 1 / 255
    assert_matches_reference(fast, scene)


def integer_quaternion_scene() -> GaussianScene:
    """A random scene whose quaternions are small integers, so that any power-of-two multiple of them is exact (even
    as a denormal) and draws the same rotation."""
    scene = random_scene(seed=3, n=12, width=16, height=12)
    scene.quats = torch.round(scene.quats * 4)
    scene.quats[:, 0] += scene.quats.abs().sum(-1) == 0  # none is zero
    return scene


@pytest.mark.parametrize(("dtype", "exponent"), [(torch.float32, -125), (torch.float32, -140), (D, -1030),
                                                 (D, -1065)])
def test_a_quaternion_too_short_for_its_exact_gradient_keeps_its_rotation_and_a_finite_gradient(fast, dtype, exponent):
    """The gradient of q/|q| is (I − q̂q̂ᵀ)/|q|: beyond float32 below |q| ≈ 1e-37, so it read inf and training skipped
    every step while such a quaternion lasted (float64: below 1e-308). Below MIN_QUATERNION_NORM the backward takes
    |q| as that norm: the gradient keeps its direction and is that of q̂·MIN_QUATERNION_NORM. A float64 denormal
    (2⁻¹⁰⁶⁵·q) also drew another rotation: its power-of-two prescale stopped at 2¹⁰²², leaving a norm below 1e-12."""
    scene = integer_quaternion_scene()
    expected, expected_params = render_backward(fast, scene, dtype)
    norms = scene.quats.norm(dim=-1, keepdim=True)
    scene.quats = scene.quats * 2.0**exponent
    got, params = render_backward(fast, scene, dtype)
    assert torch.equal(got.image, expected.image)
    grad = expected_params["quats"].grad.double() * norms / MIN_QUATERNION_NORM
    assert grad.abs().max() > 0
    torch.testing.assert_close(params["quats"].grad.double(), grad, rtol=1e-5, atol=1e-6 * grad.abs().max().item())


@pytest.mark.parametrize("dtype", DTYPES)
def test_a_zero_quaternion_draws_the_identity_rotation_with_a_zero_gradient(fast, dtype):
    """q = 0 has no direction: it draws the identity, and its gradient is 0 (R is even in q̂, so no direction away
    from 0 is better than its opposite)."""
    scene = integer_quaternion_scene()
    scene.quats[:4] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=D)
    expected, _ = render_backward(fast, scene, dtype)
    scene.quats[:4] = 0.0
    got, params = render_backward(fast, scene, dtype)
    assert torch.equal(got.image, expected.image)
    assert (params["quats"].grad[:4] == 0).all() and params["quats"].grad[4:].abs().max() > 0


@pytest.mark.parametrize("dtype", DTYPES)
def test_a_quaternion_just_below_a_power_of_two_is_made_unit(dtype):
    """Its largest component's log2 rounds up to the power, so the prescaled quaternion's norm is just under 1; a
    clamp of the norm at 1 left it unnormalised (norm 1 − 6e-8 in float32)."""
    from splatu.rasterizer.projection import unit_quaternions

    eps = torch.finfo(dtype).eps
    q = torch.tensor([[2.0**100 * (1 - eps / 2), 0.0, 0.0, 0.0], [0.0, 0.5 * (1 - eps / 2), 0.0, 0.0]], dtype=dtype)
    assert (unit_quaternions(q).norm(dim=-1) == 1.0).all()


def test_a_footprint_1e19_px_wide_seen_from_4e18_px_away_has_finite_gradients_in_float32(fast):
    """A Gaussian just past the near plane and far to the side (x/z = 4·10¹⁶), with a scale to match, covers the image
    from 4·10¹⁸ px away. Its conic's A and Q are ~10⁻³⁸, and dL/dA = ½Σ gσ·t² ~ 10³⁹ was inf in float32, so every
    gradient of the model was inf or NaN. The compositor now differentiates ln A and ln Q, whose gradients
    Σ gσ·½At² are bounded by the pixels' own, and float32 agrees with float64 and the reference."""
    scene = scene_at_origin([[4e14, 0.0, 0.0101], [0.1, 0.1, 2.0]], [[1e15, 5e14, 2e15], [0.05, 0.02, 0.08]],
                            [0.8, 0.5], width=16, height=16, focal=100.0)
    render_backward(fast, scene, torch.float32)  # every output and gradient finite
    out32, grads32 = render_with_one_loss(fast, scene, torch.float32)
    out64, grads64 = render_with_one_loss(fast, scene, D)
    assert out64.means2d[0, 0] > 3.9e18 and (out64.alpha > 0.6).all()  # it covers the image
    torch.testing.assert_close(out32.alpha.double(), out64.alpha, rtol=0, atol=1e-6)
    # atol: the far Gaussian's depth gradient is two terms of 1.34 that cancel; float32 leaves 8e-6 of them
    for name in ("means", "quats", "scales", "opacities"):
        torch.testing.assert_close(grads32[name].grad.double(), grads64[name].grad, rtol=1e-3,
                                   atol=1e-4 * grads64[name].grad.abs().max().item(),
                                   msg=lambda m, name=name: f"float32 d loss / d {name}: {m}")
    assert_matches_reference(fast, scene, radii=False)  # the reference's int64 radius of 3·10¹⁹ px overflows


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("antialiased", [False, True])
def test_a_footprint_beyond_1e77_px_is_a_finite_veil(fast, dtype, antialiased):
    """A focal length of 1e30 px and a mean 1e-20 in front of the camera with scales of 1e30 (the largest): the
    footprint matrix T = J W R S is ~1e80 px, and det(T Tᵀ) ~ |T|⁴ overflows float64 to inf. With opacities scaled
    (antialiased) every gradient was NaN; without, the ln A / ln Q conic (whose log of inf / inf is NaN) needs the
    same guard. Such a footprint is scaled down whole to 2²⁵⁰ px: over the image it is as flat as before, α = o."""
    scene = scene_at_origin([[0.0, 0.0, 1e-20], [0.0, 0.0, 2.0]], [[1e30, 5e29, 2e30], [0.05, 0.02, 0.08]],
                            [0.8, 0.5], focal=1e30)
    scene.near = 1e-30
    out, _ = render_backward(fast, scene, dtype, blur=0.1, antialiased=antialiased)
    torch.testing.assert_close(out.alpha, torch.full_like(out.alpha, 1 - 0.2 * 0.5), rtol=0, atol=1e-6)
