"""L1 / SSIM / PSNR and the view-dependent uncertainty loss (REFERENCE §1)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from splatu.camera import Camera
from splatu.errors import SplatuError
from splatu.losses import (
    SSIM_C1,
    UncertaintyLossConfig,
    l1,
    photometric_loss,
    psnr,
    refuse_copies_of_the_own_head,
    ssim,
    ssim_map,
    uncertainty_heads,
    uncertainty_loss,
)
from splatu.model import GaussianModel, ModelConfig
from splatu.sh import eval_sh, safe_normalize, sh_basis


def _image(seed: int, h: int = 24, w: int = 20) -> torch.Tensor:
    return torch.rand(h, w, 3, generator=torch.Generator().manual_seed(seed))


def test_ssim_of_identical_images_is_one():
    x = _image(0)
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-6)


def test_ssim_is_symmetric_and_below_one_for_noise():
    x = _image(0)
    noisy = (x + 0.1 * torch.randn(x.shape, generator=torch.Generator().manual_seed(1))).clamp(0, 1)
    noisier = (x + 0.3 * torch.randn(x.shape, generator=torch.Generator().manual_seed(1))).clamp(0, 1)
    assert float(ssim(x, noisy)) == pytest.approx(float(ssim(noisy, x)), abs=1e-6)
    assert float(ssim(x, noisier)) < float(ssim(x, noisy)) < 0.99


def test_ssim_matches_closed_form_on_constant_images():
    # Away from the border both windows see constants: variances vanish and SSIM = (2ab + C1) / (a² + b² + C1).
    a, b = 0.3, 0.7
    x = torch.full((32, 32, 3), a)
    y = torch.full((32, 32, 3), b)
    expected = (2 * a * b + SSIM_C1) / (a * a + b * b + SSIM_C1)
    interior = ssim_map(x, y)[5:-5, 5:-5]
    # float32 cancellation in E[x²] − E[x]² limits agreement to ~1e-4 (as in every float32 SSIM)
    assert torch.allclose(interior, torch.full_like(interior, expected), atol=5e-4)


def test_ssim_matches_a_direct_window_sum():
    x, y = _image(2, 15, 15), _image(3, 15, 15)
    coords = torch.arange(11, dtype=torch.float64) - 5
    g = torch.exp(-coords**2 / (2 * 1.5**2))
    window = torch.outer(g, g) / g.sum() ** 2
    px, py = x[2:13, 2:13, 0].double(), y[2:13, 2:13, 0].double()  # the full window around pixel (7, 7)
    mx, my = (window * px).sum(), (window * py).sum()
    vx, vy = (window * px * px).sum() - mx**2, (window * py * py).sum() - my**2
    cov = (window * px * py).sum() - mx * my
    expected = ((2 * mx * my + 1e-4) * (2 * cov + 9e-4)) / ((mx**2 + my**2 + 1e-4) * (vx + vy + 9e-4))
    assert float(ssim_map(x, y)[7, 7, 0]) == pytest.approx(float(expected), abs=1e-5)


def test_ssim_map_matches_3dgs_zero_padded_windows_at_every_pixel():
    """Borders included, on an image narrower than the window: 3DGS's conv2d(padding=5) counts the pixels outside
    the image as 0 in every moment; a float64 sum over each pixel's own 11×11 window, zero-padded, must agree."""
    x = _image(4, 13, 7)
    y = (x + 0.2 * torch.randn(x.shape, generator=torch.Generator().manual_seed(5))).clamp(0, 1)
    coords = torch.arange(11, dtype=torch.float64) - 5
    g = torch.exp(-coords**2 / (2 * 1.5**2))
    window = torch.outer(g, g) / g.sum() ** 2
    px, py = (torch.nn.functional.pad(t.double().permute(2, 0, 1), (5, 5, 5, 5)) for t in (x, y))
    expected = torch.empty(13, 7, 3, dtype=torch.float64)
    for i in range(13):
        for j in range(7):
            a, b = px[:, i:i + 11, j:j + 11], py[:, i:i + 11, j:j + 11]
            mx, my = (window * a).sum((1, 2)), (window * b).sum((1, 2))
            vx, vy = (window * a * a).sum((1, 2)) - mx**2, (window * b * b).sum((1, 2)) - my**2
            cov = (window * a * b).sum((1, 2)) - mx * my
            expected[i, j] = ((2 * mx * my + 1e-4) * (2 * cov + 9e-4)) / ((mx**2 + my**2 + 1e-4) * (vx + vy + 9e-4))
    torch.testing.assert_close(ssim_map(x.double(), y.double()), expected, rtol=0, atol=1e-12)
    torch.testing.assert_close(ssim_map(x, y).double(), expected, rtol=0, atol=1e-5)


def test_photometric_loss_combines_l1_and_ssim():
    x, y = _image(0), _image(1)
    expected = 0.8 * float(l1(x, y)) + 0.2 * (1 - float(ssim(x, y)))
    assert float(photometric_loss(x, y)) == pytest.approx(expected, rel=1e-6)
    assert float(photometric_loss(x, x)) == pytest.approx(0.0, abs=1e-6)


def test_l1_and_psnr_known_values_and_masks():
    gt = torch.zeros(4, 4, 3)
    pred = gt.clone()
    pred[:2] = 0.1
    mask = torch.zeros(4, 4, dtype=torch.bool)
    mask[:2] = True
    assert float(l1(pred, gt)) == pytest.approx(0.05)
    assert psnr(pred, gt, mask) == pytest.approx(20.0, abs=1e-4)
    assert psnr(pred, gt) == pytest.approx(-10 * math.log10(0.005), abs=1e-4)
    assert psnr(gt, gt) == pytest.approx(100.0)  # floored, never +inf
    with pytest.raises(ValueError):
        psnr(pred, gt, torch.zeros(4, 4, dtype=torch.bool))


@pytest.mark.parametrize("lam", [0.5, 0.7, -0.1])
def test_lambda_outside_range_is_a_user_error(lam):
    with pytest.raises(SplatuError, match="λ"):
        UncertaintyLossConfig(lam=lam)


@pytest.mark.parametrize("threshold", [-0.1, 1.5, float("nan")])
def test_a_threshold_that_is_no_blend_weight_is_a_user_error(threshold):
    with pytest.raises(SplatuError, match="is not a blend weight in"):
        UncertaintyLossConfig(threshold=threshold)


def test_a_new_run_may_not_use_threshold_0_which_a_saved_run_may_have():
    """0 supervised every Gaussian, the ones this view never drew too, as seen from this camera: a new run is refused
    it (`validate`, run as a new run's options are checked), but a config saved before still loads."""
    for config, where in ((UncertaintyLossConfig(threshold=0.0), "--uncertainty.threshold"),
                          (UncertaintyLossConfig(extra_heads=("threshold=0",)), "uncertainty head 'threshold=0'")):
        with pytest.raises(SplatuError, match=f"threshold = 0.0 is not a blend weight in.*{where}"):
            config.validate()


def test_a_new_run_may_not_use_a_threshold_no_blend_weight_reaches():
    """α is clamped at 0.99, so a threshold above it supervised no Gaussian and u_sh silently kept its initial value;
    a saved config with one still loads."""
    model, camera = _single_gaussian(u_degree=1)
    with torch.no_grad():
        model.opacity_logits.fill_(20.0)
        model.log_scales.fill_(math.log(3.0))  # flat over the pixel nearest its centre: α reaches the clamp
    assert float(model.render(camera, 0, torch.zeros(3)).raster.contrib_max.max()) == pytest.approx(0.99)
    UncertaintyLossConfig(threshold=0.99).validate()
    head = "threshold=0.995"
    for config, where in ((UncertaintyLossConfig(threshold=1.0), "--uncertainty.threshold"),
                          (UncertaintyLossConfig(extra_heads=(head,)), f"uncertainty head '{head}'")):
        with pytest.raises(SplatuError, match=f"above 0.99, the largest blend weight.*{where}"):
            config.validate()


def _single_gaussian(u_degree: int, u_init_logit: float = 2.0) -> tuple[GaussianModel, Camera]:
    """One opaque Gaussian 3 units in front of a camera at the origin, seen along +z."""
    cfg = ModelConfig(sh_degree=0, u_sh_degree=u_degree, init_opacity=0.95, u_init_logit=u_init_logit)
    model = GaussianModel.from_points(torch.tensor([[0.2, -0.1, 3.0]]), None, cfg, torch.Generator())
    with torch.no_grad():
        model.log_scales.fill_(math.log(0.3))
    K = torch.tensor([[30.0, 0, 16], [0, 30.0, 16], [0, 0, 1]])
    return model, Camera(K, torch.eye(4), 32, 32)


def _train_u(model: GaussianModel, camera: Camera, cfg: UncertaintyLossConfig, steps: int = 200) -> None:
    raster = model.render(camera, 0, torch.zeros(3)).raster
    optimizer = torch.optim.Adam([model.u_sh], lr=0.05)
    generator = torch.Generator().manual_seed(0)
    for _ in range(steps):
        optimizer.zero_grad()
        uncertainty_loss(model, camera.center(), raster, cfg, [generator]).backward()
        optimizer.step()


def _u_seen_and_opposite(model: GaussianModel, camera: Camera) -> tuple[float, float]:
    with torch.no_grad():
        d = model.view_dirs(camera)
        return float(model.uncertainty(d)), float(model.uncertainty(-d))


def test_antipodal_loss_makes_the_seen_side_certain_and_the_other_uncertain():
    model, camera = _single_gaussian(u_degree=1)
    seen0, opposite0 = _u_seen_and_opposite(model, camera)
    assert seen0 == pytest.approx(opposite0) == pytest.approx(torch.sigmoid(torch.tensor(2.0)).item(), abs=1e-5)
    _train_u(model, camera, UncertaintyLossConfig(kind="antipodal", lam=0.3))
    seen, opposite = _u_seen_and_opposite(model, camera)
    assert seen < 0.2
    assert opposite > 0.7


def test_settings_the_loss_kind_never_reads_are_refused_only_for_a_run_that_trains_it():
    """A new run's weighted loss with a threshold, or antipodal with num_dirs, trained as without them; with the loss
    off (splatfacto, an ensemble's members, whose resume validates members not yet begun) nothing reads them."""
    with pytest.raises(SplatuError, match="is not read by the loss --uncertainty\\.kind weighted trains"):
        UncertaintyLossConfig(kind="weighted", threshold=0.2).validate()
    with pytest.raises(SplatuError, match="is not read by the loss --uncertainty\\.kind antipodal trains"):
        UncertaintyLossConfig(num_dirs=32).validate()
    UncertaintyLossConfig(kind="mean", threshold=0.2, num_dirs=32).validate()
    UncertaintyLossConfig(off=True, kind="weighted", threshold=0.2, num_dirs=32).validate()
    UncertaintyLossConfig(kind="weighted", threshold=0.2).check_loadable()  # a saved run still loads


def test_the_antipodal_term_makes_the_side_opposite_the_view_uncertain():
    """Started certain from everywhere (u = 0.12), only λ·(1 − u(−d)) raises u(−d): without it (λ = 0) lowering u(d)
    moves u(−d) only as a side effect of the shared coefficients (0.32 after these steps, against 0.98). From the
    default start (u = 0.88) the two read alike, so the test above cannot tell them apart."""
    opposite = {}
    for lam in (0.0, 0.3):
        model, camera = _single_gaussian(u_degree=1, u_init_logit=-2.0)
        assert _u_seen_and_opposite(model, camera) == pytest.approx((0.1192, 0.1192), abs=1e-4)
        _train_u(model, camera, UncertaintyLossConfig(kind="antipodal", lam=lam))
        seen, opposite[lam] = _u_seen_and_opposite(model, camera)
        assert seen < 0.05
    assert opposite[0.3] > 0.9 and opposite[0.0] < 0.5


@pytest.mark.parametrize("kind", ["mean", "weighted"])
def test_other_variants_also_reduce_the_seen_uncertainty(kind):
    model, camera = _single_gaussian(u_degree=1)
    _train_u(model, camera, UncertaintyLossConfig(kind=kind, lam=0.3))
    seen, opposite = _u_seen_and_opposite(model, camera)
    assert seen < 0.5
    assert opposite > seen


def test_uncertainty_loss_only_moves_u_sh_and_photometric_loss_never_does():
    model, camera = _single_gaussian(u_degree=2)
    render = model.render(camera, 0, torch.zeros(3))
    uncertainty_loss(model, camera.center(), render.raster, UncertaintyLossConfig()).backward()
    assert model.u_sh.grad is not None and model.u_sh.grad.abs().sum() > 0
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest"):
        grad = getattr(model, name).grad
        assert grad is None or not grad.any(), name

    model.zero_grad(set_to_none=True)
    render = model.render(camera, 0, torch.zeros(3))
    photometric_loss(render.rgb, torch.full_like(render.rgb, 0.3)).backward()
    assert model.means.grad is not None and model.means.grad.abs().sum() > 0
    assert model.u_sh.grad is None or not model.u_sh.grad.any()


def test_no_supervised_gaussian_gives_zero_with_a_gradient_path():
    model, camera = _single_gaussian(u_degree=1)
    raster = model.render(camera, 0, torch.zeros(3)).raster
    loss = uncertainty_loss(model, camera.center(), raster, UncertaintyLossConfig(kind="antipodal", threshold=1.0))
    assert float(loss.detach()) == 0.0 and loss.requires_grad
    loss.backward()
    assert not model.u_sh.grad.any()


def test_loss_weight_scales_the_loss():
    model, camera = _single_gaussian(u_degree=1)
    raster = model.render(camera, 0, torch.zeros(3)).raster
    base = uncertainty_loss(model, camera.center(), raster, UncertaintyLossConfig(kind="antipodal")).detach()
    doubled = uncertainty_loss(model, camera.center(), raster,
                               UncertaintyLossConfig(kind="antipodal", weight=2.0)).detach()
    u = torch.sigmoid(torch.tensor(2.0))
    assert float(base) == pytest.approx(0.7 * float(u) + 0.3 * (1 - float(u)), abs=1e-5)
    assert float(doubled) == pytest.approx(2 * float(base), rel=1e-6)


@pytest.mark.parametrize(("spec", "message"), [
    ("lam", "bad uncertainty head"), ("colour=1", "unknown key 'colour'"), ("lam=0.1,lam=0.2", "'lam' given twice"),
    ("lam=abc", "lam='abc' is not a number"), ("kind=median", "unknown loss kind"),
    ("degree=4", "asks for degree 4, above the u-SH degree 3"), ("degree=-1", "negative degree"),
    ("lam=0.7", "not in \\[0, 0.5\\)"),
])
def test_a_bad_extra_head_is_a_one_line_user_error(spec, message):
    with pytest.raises(SplatuError, match=message):
        UncertaintyLossConfig(extra_heads=(spec,))


def test_repeated_extra_heads_and_heads_with_the_loss_off_are_user_errors():
    with pytest.raises(SplatuError, match="repeats another head"):
        UncertaintyLossConfig(extra_heads=("lam=0.1,degree=1", "degree=1,lam=0.1"))
    with pytest.raises(SplatuError, match="would never train"):
        UncertaintyLossConfig(off=True, extra_heads=("lam=0.1",))


@pytest.mark.parametrize(("spec", "model_degree", "copy"), [("lam=0.3", 3, True), ("lam=0.30,degree=1", 1, True),
                                                            ("lam=0.3,degree=1", 3, False), ("lam=0.2", 3, False)])
def test_an_extra_head_that_copies_the_runs_own_head_is_a_user_error(spec, model_degree, copy):
    """It was accepted and trained channel 0 again under another name; the same settings at another degree, or
    another λ, are a head of their own."""
    config = UncertaintyLossConfig(extra_heads=(spec,))
    if not copy:
        refuse_copies_of_the_own_head(config, model_degree)
        return
    with pytest.raises(SplatuError, match=f"uncertainty head '{spec}' repeats the run's own settings"):
        refuse_copies_of_the_own_head(config, model_degree)


def test_extra_heads_are_the_own_settings_with_overrides_in_their_own_channels():
    cfg = UncertaintyLossConfig(kind="weighted", lam=0.3, extra_heads=("kind=antipodal,threshold=0.2", "degree=0"))
    own, antipodal, constant = uncertainty_heads(cfg, model_degree=2)
    assert (own.loss, own.degree) == (UncertaintyLossConfig(kind="weighted", lam=0.3), 2)
    assert (antipodal.loss.kind, antipodal.loss.threshold, antipodal.loss.lam, antipodal.degree) == (
        "antipodal", 0.2, 0.3, 2)
    assert (constant.name, constant.loss.kind, constant.degree) == ("degree=0", "weighted", 0)
    with pytest.raises(SplatuError, match=r"raise --model\.u-sh-degree"):
        uncertainty_heads(UncertaintyLossConfig(extra_heads=("degree=3",)), model_degree=1)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("kind", ["antipodal", "weighted"])
def test_the_one_basis_parity_evaluation_equals_evaluating_both_directions(kind, degree):
    """u(−d) comes from the even/odd bands of u(d)'s basis; it must equal evaluating −d directly."""
    g = torch.Generator().manual_seed(degree)
    n = 300
    model = GaussianModel.empty_like_config(n, ModelConfig(u_sh_degree=degree))
    with torch.no_grad():
        model.means.copy_(torch.randn(n, 3, generator=g))
        model.u_sh.copy_(torch.randn(model.u_sh.shape, generator=g))
    raster = SimpleNamespace(contrib_max=torch.rand(n, generator=g))
    cfg = UncertaintyLossConfig(kind=kind, lam=0.3, threshold=0.2)
    centre = torch.tensor([0.3, -2.0, 0.5])
    loss = uncertainty_loss(model, centre, raster, cfg)
    weights = raster.contrib_max
    chosen = weights >= (1.0 / 255.0 if kind == "weighted" else 0.2)
    dirs = safe_normalize(model.means.detach()[chosen] - centre)
    u_sh = model.u_sh[chosen]
    seen = torch.sigmoid(eval_sh(u_sh, dirs, degree)).squeeze(-1)
    other = torch.sigmoid(eval_sh(u_sh, -dirs, degree)).squeeze(-1)
    first = seen * weights[chosen] if kind == "weighted" else seen
    expected = ((1 - 0.3) * first + 0.3 * (1 - other)).mean()
    torch.testing.assert_close(loss, expected, rtol=1e-6, atol=1e-7)
    grad, = torch.autograd.grad(loss, model.u_sh)
    expected_grad, = torch.autograd.grad(expected, model.u_sh)
    torch.testing.assert_close(grad, expected_grad, rtol=1e-5, atol=1e-8)


def test_the_mean_variant_is_the_seen_term_and_one_minus_the_mean_over_its_random_directions():
    """(1−λ)·u(d) + λ·(1 − ū), ū over `num_dirs` directions drawn from the head's generator, in float64 by hand, with d
    from the camera centre to the mean (the paper's pixel-ray direction, the one colour SH uses)."""
    g = torch.Generator().manual_seed(11)
    n, centre = 60, torch.tensor([0.1, 0.2, -3.0])
    model = GaussianModel.empty_like_config(n, ModelConfig(u_sh_degree=3))
    with torch.no_grad():
        model.means.copy_(torch.randn(n, 3, generator=g))
        model.u_sh.copy_(torch.randn(model.u_sh.shape, generator=g))
    raster = SimpleNamespace(contrib_max=torch.rand(n, generator=g))
    cfg = UncertaintyLossConfig(kind="mean", lam=0.2, threshold=0.3, num_dirs=7)
    loss = uncertainty_loss(model, centre, raster, cfg, [torch.Generator().manual_seed(5)])
    random_dirs = torch.randn(7, 3, generator=torch.Generator().manual_seed(5)).double()
    chosen = raster.contrib_max >= 0.3
    d = model.means.detach().double()[chosen] - centre.double()
    coeffs = model.u_sh.detach().double()[chosen][..., 0]
    seen = torch.sigmoid((sh_basis(d / d.norm(dim=-1, keepdim=True), 3) * coeffs).sum(-1))
    mean_u = torch.sigmoid(sh_basis(random_dirs / random_dirs.norm(dim=-1, keepdim=True), 3) @ coeffs.T).mean(0)
    assert float(loss.detach()) == pytest.approx(float((0.8 * seen + 0.2 * (1 - mean_u)).mean()), rel=1e-6)


def test_each_uncertainty_head_reads_only_its_own_u_sh_channel():
    """With two heads the loss is head 0's on channel 0 plus head 1's on channel 1, each as if it trained alone."""
    from types import SimpleNamespace

    g = torch.Generator().manual_seed(7)
    n = 200
    model = GaussianModel.empty_like_config(n, ModelConfig(u_sh_degree=2), u_heads=2)
    with torch.no_grad():
        model.means.copy_(torch.randn(n, 3, generator=g))
        model.u_sh.copy_(torch.randn(model.u_sh.shape, generator=g))
        model.u_sh[:, 0, 1] += 5.0  # channel 1 reads far more uncertain than channel 0
    raster = SimpleNamespace(contrib_max=torch.rand(n, generator=g))
    cfg = UncertaintyLossConfig(kind="antipodal", lam=0.3, threshold=0.2, extra_heads=("lam=0.1",))
    centre = torch.tensor([0.3, -2.0, 0.5])

    def alone(channel: int, head_cfg: UncertaintyLossConfig) -> torch.Tensor:
        single = GaussianModel.empty_like_config(n, ModelConfig(u_sh_degree=2))
        with torch.no_grad():
            single.means.copy_(model.means)
            single.u_sh.copy_(model.u_sh[..., channel:channel + 1])
        return uncertainty_loss(single, centre, raster, head_cfg).detach()

    own, extra = uncertainty_heads(cfg, model_degree=2)
    expected = alone(0, own.loss) + alone(1, extra.loss)
    torch.testing.assert_close(uncertainty_loss(model, centre, raster, cfg).detach(), expected)
    assert float(alone(1, extra.loss)) > float(alone(0, extra.loss)) + 0.1  # so head 1 reading channel 0 would show
