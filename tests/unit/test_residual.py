"""The training-residual uncertainty: per-Gaussian residuals against a brute force over one-hot renders."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
import torch

from splatu.baselines import METHODS_FOR_PLAIN_RUNS, METHODS_WITH_OURS
from splatu.baselines.angle import VIEW_CHUNK
from splatu.baselines.load import LoadedRun, build_method, check_method
from splatu.baselines.residual import (
    RESIDUAL_FLOOR,
    ResidualSource,
    ViewResiduals,
    directional_residuals,
    mean_residuals,
    residual_feature,
    residual_map,
    training_residuals,
    typical_residual,
    view_residual_sums,
)
from splatu.camera import Camera
from splatu.data.scene import Scene, Views
from splatu.errors import SplatuError
from splatu.model import GaussianModel
from splatu.rasterizer import rasterize
from splatu.sh import rgb_to_sh
from splatu.train_config import eval_background, preset_config
from tests.small_models import SIZE, noise_views, overlapping_gaussians


def _brute_force(model: GaussianModel, views: Views) -> torch.Tensor:
    """Σ w_i e / Σ w_i with w_i(p) read off a render whose features are one-hot per Gaussian (image[..., i] = w_i)."""
    n = len(model)
    num, den = torch.zeros(n, dtype=torch.float64), torch.zeros(n, dtype=torch.float64)
    with torch.no_grad():
        for i, camera in enumerate(views.cameras):
            weights = rasterize(model.means.double(), model.quats.double(), model.log_scales.double(),
                                torch.sigmoid(model.opacity_logits).double(), torch.eye(n, dtype=torch.float64),
                                camera.world_to_camera.double(), camera.K.double(), SIZE, SIZE,
                                near=camera.near, far=camera.far, log_scales=True,
                                blur=model.cfg.screen_blur, antialiased=model.cfg.antialiased).image  # (H, W, n)
            rgb = model.render(camera, 0, torch.zeros(3)).rgb
            error = (rgb.clamp(0, 1) - views.images[i]).abs().mean(-1).double()
            valid = torch.ones_like(error) if views.object_masks is None else (views.object_masks[i] > 0).double()
            num += (weights * (error * valid)[..., None]).sum((0, 1))
            den += (weights * valid[..., None]).sum((0, 1))
    return torch.where(den > 0, num / den, torch.nan)


def test_residuals_match_the_one_hot_brute_force_and_unseen_gaussians_are_nan():
    model, views = overlapping_gaussians(), noise_views()
    residuals = training_residuals(model, views, 0, torch.zeros(3))
    expected = _brute_force(model, views)
    assert math.isnan(float(residuals[-1])) and math.isnan(float(expected[-1]))
    torch.testing.assert_close(residuals[:-1].double(), expected[:-1], atol=1e-6, rtol=1e-4)
    assert (residuals[:-1] > 0.01).all()  # random targets: every seen Gaussian has a real residual


@pytest.mark.parametrize("soft", [False, True])
def test_masked_pixels_count_neither_in_the_error_nor_in_the_weight(soft):
    """A zero mask value drops a pixel; any non-zero one (an RGBA alpha's edge) counts it fully, as eval-ause does."""
    masks = torch.zeros(2, SIZE, SIZE)
    masks[:, :, : SIZE // 2] = torch.linspace(0.05, 1.0, SIZE // 2) if soft else 1.0
    model, views = overlapping_gaussians(seed=3), noise_views(masks)
    residuals = training_residuals(model, views, 0, torch.zeros(3))
    expected = _brute_force(model, views)
    seen = torch.isfinite(expected)
    assert torch.equal(torch.isfinite(residuals), seen)
    torch.testing.assert_close(residuals[seen].double(), expected[seen], atol=1e-6, rtol=1e-4)
    unmasked = training_residuals(model, noise_views(), 0, torch.zeros(3))
    assert not torch.allclose(residuals[seen], unmasked[seen])  # the mask did change something


def test_a_perfect_fit_has_zero_residual():
    model, views = overlapping_gaussians(seed=2), noise_views()
    with torch.no_grad():
        views.images.copy_(torch.stack([model.render(c, 0, torch.zeros(3)).rgb.clamp(0, 1) for c in views.cameras]))
    residuals = training_residuals(model, views, 0, torch.zeros(3))
    assert residuals[:-1].abs().max() < 1e-6


def test_the_map_is_half_at_the_typical_residual_and_one_where_nothing_is_seen():
    residuals = torch.tensor([0.01, 0.02, 0.04, float("nan")])
    typical = typical_residual(residuals)
    assert typical == float(torch.tensor(0.02))  # the median of the seen ones, the NaN ignored
    assert float(residual_map(torch.tensor(typical), typical)) == 0.5
    assert typical_residual(torch.full((3,), float("nan"))) == 1.0  # nothing seen: finite, no division by zero
    assert typical_residual(torch.zeros(3)) == RESIDUAL_FLOOR  # a perfect fit: the floor, not ~0
    model, views = overlapping_gaussians(), noise_views()
    source = ResidualSource(model, 0, torch.zeros(3), training_residuals(model, views, 0, torch.zeros(3)),
                            with_ours=False)
    far_away = Camera(views.cameras[0].K, torch.eye(4), SIZE, SIZE, name="far")
    far_away.world_to_camera[2, 3] = -10.0  # everything behind the camera: empty image
    empty = source.render(far_away).uncertainty
    torch.testing.assert_close(empty, torch.full_like(empty, 1.0 / (1.0 + source.typical)))
    seen = source.render(views.cameras[0])
    assert torch.isfinite(seen.uncertainty).all() and (seen.uncertainty >= 0).all() and (seen.uncertainty < 1).all()


def test_ours_residual_is_the_or_of_ours_and_the_residual_map():
    model, views = overlapping_gaussians(), noise_views()
    residuals = training_residuals(model, views, 0, torch.zeros(3))
    with torch.no_grad():
        model.u_sh[:, 0, 0] = torch.linspace(-2.0, 2.0, len(model))  # a different u per Gaussian
    camera = views.cameras[1]
    alone = ResidualSource(model, 0, torch.zeros(3), residuals, with_ours=False).render(camera).uncertainty
    combined = ResidualSource(model, 0, torch.zeros(3), residuals, with_ours=True).render(camera).uncertainty
    ours = model.render(camera, 0, torch.zeros(3), with_uncertainty=True).uncertainty
    torch.testing.assert_close(combined, 1 - (1 - ours) * (1 - alone), atol=1e-6, rtol=0)
    assert (combined >= alone - 1e-6).all() and (combined > alone + 1e-3).any()


@pytest.mark.parametrize("method", METHODS_WITH_OURS)
def test_methods_reading_u_refuse_a_run_trained_without_the_loss(method):
    config = preset_config("fast")
    off = dataclasses.replace(config, uncertainty=dataclasses.replace(config.uncertainty, off=True))
    run = LoadedRun(Path("run"), off, [overlapping_gaussians()], None, [None])
    with pytest.raises(SplatuError, match="needs a run trained with the uncertainty loss"):
        check_method(method, run)
    check_method("residual", run)  # the residual alone needs no u


def test_ours_by_default_on_a_run_without_the_loss_names_the_methods_that_render_it():
    """render-uncertainty on a splatfacto run, with no --method, was told "--method ours needs…", of a flag never
    typed: it says ours was the default, and the fix names the methods such a run renders."""
    config = preset_config("fast")
    off = dataclasses.replace(config, uncertainty=dataclasses.replace(config.uncertainty, off=True))
    run = LoadedRun(Path("run"), off, [overlapping_gaussians()], None, [None])
    with pytest.raises(SplatuError) as refused:
        check_method("ours", run, typed=False)
    assert refused.value.what.startswith("without --method a single run renders ours, which needs")
    assert refused.value.fix.startswith("pass one of --method visibility, fisher, random, spread, residual or angle")
    for method in METHODS_FOR_PLAIN_RUNS:  # each one named is accepted
        check_method(method, run, typed=False)


def test_per_view_sums_give_each_views_own_residual():
    model, views = overlapping_gaussians(), noise_views()
    record = view_residual_sums(model, views, 0, torch.zeros(3))
    assert record.sums.shape == (len(model), len(views.cameras), 2)
    torch.testing.assert_close(record.centres, torch.stack([c.center() for c in views.cameras]))
    for v, camera in enumerate(views.cameras):
        alone = Views([camera], views.images[v:v + 1], [camera.name])
        expected = _brute_force(model, alone)
        seen = torch.isfinite(expected)
        own = record.sums[:, v, 0] / record.sums[:, v, 1]
        torch.testing.assert_close(own[seen].double(), expected[seen], atol=1e-6, rtol=1e-4)
    torch.testing.assert_close(mean_residuals(record), training_residuals(model, views, 0, torch.zeros(3)),
                               equal_nan=True)


def _kernel_brute_force(means: torch.Tensor, record: ViewResiduals, viewer: torch.Tensor, kappa: float) -> torch.Tensor:
    """r_i(c) by two loops over Gaussians and views, in float64."""
    out = torch.empty(means.shape[0], dtype=torch.float64)
    for i, mean in enumerate(means.double()):
        looking = (mean - viewer.double()) / (mean - viewer.double()).norm()
        num = den = 0.0
        for v, centre in enumerate(record.centres.double()):
            trained = (mean - centre) / (mean - centre).norm()
            k = math.exp(kappa * (float(trained @ looking) - 1.0))
            num += k * float(record.sums[i, v, 0])
            den += k * float(record.sums[i, v, 1])
        out[i] = num / den if den > 0 else math.nan
    return out


@pytest.mark.parametrize("kappa", [0.0, 3.0, 20.0])
def test_directional_residuals_match_the_kernel_brute_force_across_view_chunks(kappa):
    g = torch.Generator().manual_seed(4)
    views = 2 * VIEW_CHUNK + 5  # three chunks, the last one partial
    means = torch.randn(7, 3, generator=g)
    weight = torch.rand(7, views, generator=g) * (torch.rand(7, views, generator=g) > 0.5)  # many views see none
    weight[-1] = 0.0  # one Gaussian no view saw
    sums = torch.stack([weight * torch.rand(7, views, generator=g), weight], -1)
    record = ViewResiduals(sums, torch.randn(views, 3, generator=g) * 3.0)
    viewer = torch.tensor([0.5, -4.0, 1.0])
    got = directional_residuals(means, record, viewer, kappa)
    torch.testing.assert_close(got.double(), _kernel_brute_force(means, record, viewer, kappa), equal_nan=True,
                               atol=1e-6, rtol=1e-5)
    assert math.isnan(float(got[-1])) and torch.isfinite(got[:-1]).all()
    if kappa == 0.0:  # a flat kernel is the plain mean over every view
        torch.testing.assert_close(got, mean_residuals(record), equal_nan=True)


def test_a_directional_residual_follows_the_nearest_training_direction():
    """One Gaussian at the origin, seen from -z with error 0.1 and from +z with error 0.5."""
    record = ViewResiduals(torch.tensor([[[0.1, 1.0], [0.5, 1.0]]]), torch.tensor([[0.0, 0.0, -2.0], [0.0, 0.0, 2.0]]))
    mean = torch.zeros(1, 3)

    def at(viewer: list[float], rec: ViewResiduals = record) -> float:
        return float(directional_residuals(mean, rec, torch.tensor(viewer)))

    assert at([0.0, 0.0, -3.0]) == pytest.approx(0.1, abs=1e-6)  # the far view weighs e^-40
    assert at([0.0, 0.0, 3.0]) == pytest.approx(0.5, abs=1e-6)
    assert at([3.0, 0.0, 0.0]) == pytest.approx(0.3)  # square to both: the mean
    assert at([0.0, 0.0, 0.0]) == pytest.approx(0.3)  # a zero-length direction: the mean, not NaN
    only_far = ViewResiduals(torch.tensor([[[0.0, 0.0], [0.5, 1.0]]]), record.centres)
    assert at([0.0, 0.0, -3.0], only_far) == pytest.approx(0.5)  # seen only from behind: that view's error, not 0


def test_the_view_residual_source_renders_the_directional_residual():
    model, views = overlapping_gaussians(), noise_views()
    record = view_residual_sums(model, views, 0, torch.zeros(3))
    camera = views.cameras[1]
    camera = Camera(camera.K, camera.world_to_camera.clone(), SIZE, SIZE, name="off")
    camera.world_to_camera[0, 3] = 1.5  # well away from both training cameras
    source = ResidualSource(model, 0, torch.zeros(3), mean_residuals(record), with_ours=False, directional=record)
    got = source.render(camera).uncertainty
    feature = residual_feature(directional_residuals(model.means.detach(), record, camera.center()))
    with torch.no_grad():
        composited = model.render(camera, 0, torch.zeros(3), extra_features=feature).extra[..., 0]
    torch.testing.assert_close(got, residual_map(composited, source.typical))
    plain = ResidualSource(model, 0, torch.zeros(3), mean_residuals(record), with_ours=False).render(camera)
    assert not torch.allclose(got, plain.uncertainty, atol=1e-5)  # the direction did change the map
    assert torch.isfinite(got).all() and (got >= 0).all() and (got < 1).all()


@pytest.mark.parametrize(("method", "directional", "angle"), [("residual", False, False),
                                                              ("ours-residual-angle", False, True),
                                                              ("ours-view-residual-angle", True, True)])
def test_build_method_wires_the_direction_and_the_angle_only_where_named(method, directional, angle):
    model, views = overlapping_gaussians(), noise_views()
    config = preset_config("fast")
    config = dataclasses.replace(config, model=dataclasses.replace(config.model, sh_degree=0))
    run = LoadedRun(Path("run"), config, [model], None, [None])
    source = build_method(method, run, Scene("test", "test", views, views, torch.zeros(0, 3))).source
    assert (source.directional is not None) == directional and (source.coverage is not None) == angle
    expected = training_residuals(model, views, 0, eval_background(config))
    torch.testing.assert_close(source.residuals, expected, equal_nan=True)  # both paths: the same mean residual


def test_the_error_is_that_of_the_render_clamped_to_the_displayable_range():
    """Colour 2.0 over a white background renders above 1 wherever it is drawn; clamped to [0, 1], as evaluation
    scores it, it is exactly the white target, so every seen Gaussian has residual 0."""
    model, views = overlapping_gaussians(), noise_views()
    with torch.no_grad():
        model.sh_dc.fill_(float(rgb_to_sh(torch.tensor(2.0))))
        views.images.fill_(1.0)
    residuals = training_residuals(model, views, 0, torch.ones(3))
    assert math.isnan(float(residuals[-1]))
    assert torch.equal(residuals[:-1], torch.zeros(len(model) - 1))


def test_a_gaussian_no_training_pixel_saw_is_rendered_with_the_worst_residual():
    """NaN (unseen) becomes 1, the worst error, as empty space does; seen residuals are kept, clamped to [0, 1]."""
    feature = residual_feature(torch.tensor([0.2, float("nan"), 1.7, 0.0]))
    torch.testing.assert_close(feature, torch.tensor([[0.2], [1.0], [1.0], [0.0]]))
    model, views = overlapping_gaussians(), noise_views()
    source = ResidualSource(model, 0, torch.zeros(3), training_residuals(model, views, 0, torch.zeros(3)),
                            with_ours=False)
    assert math.isnan(float(source.residuals[-1])) and float(source.feature[-1, 0]) == 1.0
