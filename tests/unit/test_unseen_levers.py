"""The training levers of benchmarks/unseen_levers.py: each term's value on hand-made inputs, the 3D filter's
invariants, and that applying a lever patches the training and always puts it back."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

import splatu.model
from splatu import training_step
from splatu.camera import Camera
from splatu.losses import photometric_loss
from splatu.model import GaussianModel
from tests.benchmark_scripts import benchmark_script
from tests.small_models import SIZE, noise_views, overlapping_gaussians, two_cameras


@pytest.fixture(scope="module")
def levers():
    yield from benchmark_script("unseen_levers")


def camera_at_z(z: float) -> Camera:
    world_to_camera = torch.eye(4)
    world_to_camera[2, 3] = -z  # centre at (0, 0, z), looking along +z
    return Camera(torch.tensor([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]]), world_to_camera, 64, 64)


def test_sampling_rate_is_the_nearest_viewing_cameras_and_the_smallest_for_unseen_means(levers) -> None:
    means = torch.tensor([[0.0, 0, 2], [0, 0, 4], [0, 0, -5], [100.0, 0, 2]])  # behind both, far off to the side
    rate = levers.max_sampling_rate(means, [camera_at_z(0.0), camera_at_z(-2.0)])
    assert rate.tolist() == pytest.approx([50.0, 25.0, 25.0, 25.0])  # unseen: the strongest filter of the seen


def test_filter_widens_every_axis_by_the_variance_and_keeps_opacity_times_volume(levers) -> None:
    g = torch.Generator().manual_seed(0)
    log_scales, opacities = torch.randn(5, 3, generator=g) - 2, torch.rand(5, generator=g)
    variance = torch.rand(5, generator=g) * 0.01
    wide, dimmer = levers.filtered(log_scales, opacities, variance)
    assert torch.allclose(torch.exp(2 * wide), torch.exp(2 * log_scales) + variance[:, None])
    assert torch.allclose(dimmer * wide.sum(-1).exp(), opacities * log_scales.sum(-1).exp())
    assert (dimmer < opacities).all()
    same, unchanged = levers.filtered(log_scales, opacities, torch.zeros(5))
    assert torch.allclose(same, log_scales) and torch.allclose(unchanged, opacities)


def test_depth_smoothness_counts_steps_less_across_image_edges_and_only_between_opaque_pixels(levers) -> None:
    depth = torch.ones(4, 4)
    depth[:, 2:] = 2.0  # one step between columns 1 and 2; the median depth is 1
    flat, edge = torch.zeros(4, 4, 3), torch.zeros(4, 4, 3)
    edge[:, 2:] = 0.5
    opaque = torch.ones(4, 4)
    assert float(levers.depth_smoothness(torch.ones(4, 4), opaque, flat)) == 0.0
    assert float(levers.depth_smoothness(depth, opaque, flat)) == pytest.approx(4 / 12)
    assert float(levers.depth_smoothness(depth, opaque, edge)) == pytest.approx(4 / 12 * math.exp(-5))
    half = opaque.clone()
    half[:, 2:] = 0.0
    assert float(levers.depth_smoothness(depth, half, flat)) == 0.0
    assert float(levers.depth_smoothness(depth, torch.zeros(4, 4), flat)) == 0.0


def test_opacity_entropy_is_ln2_at_one_half_and_vanishes_at_the_ends(levers) -> None:
    assert float(levers.opacity_entropy(torch.zeros(3))) == pytest.approx(math.log(2))
    assert float(levers.opacity_entropy(torch.tensor([-30.0, 30.0]))) < 1e-4


def test_true_depth_error_is_relative_and_skips_transparent_or_unknown_pixels(levers) -> None:
    depth = torch.tensor([[2.2, 5.0], [1.0, 3.0]])
    alpha = torch.tensor([[1.0, 0.2], [1.0, 1.0]])
    truth = torch.tensor([[2.0, 1.0], [math.nan, 3.0]])
    assert float(levers.true_depth_error(depth, alpha, truth)) == pytest.approx(0.05)


ORIGINALS = {"rasterize": (splatu.model, "rasterize"), "loss": (training_step, "photometric_loss"),
             "render": (GaussianModel, "render"), "get": (training_step.TrainImages, "get")}


@pytest.mark.parametrize(("lever", "patched"), [("none", set()), ("filter-3d", {"rasterize"}),
                                                ("depth-smoothness", {"loss", "render", "get"}),
                                                ("opacity-entropy", {"loss", "render", "get"}),
                                                ("true-depth", {"loss", "render", "get"})])
def test_a_lever_patches_what_it_needs_and_is_undone_even_on_an_error(levers, lever, patched) -> None:
    before = {name: getattr(owner, attr) for name, (owner, attr) in ORIGINALS.items()}
    with pytest.raises(RuntimeError), levers.applied(lever, 0.5, two_cameras()):
        assert {name for name, (owner, attr) in ORIGINALS.items() if getattr(owner, attr) is not before[name]} \
            == patched
        raise RuntimeError("training failed")
    assert all(getattr(owner, attr) is before[name] for name, (owner, attr) in ORIGINALS.items())


def test_filter_3d_adds_weight_over_the_squared_sampling_rate_and_refreshes_when_the_means_change(levers) -> None:
    cameras = [camera_at_z(0.0)]
    seen: list = []

    def recording_rasterize(means, quats, scales, opacities, *args, **kwargs):
        seen.append((scales, opacities))

    filtering = levers._filtering_rasterize(recording_rasterize, 0.2, cameras)
    log_scales, opacities, quats = torch.full((2, 3), -3.0), torch.full((2,), 0.5), torch.zeros(2, 4)
    for depth in (2.0, 4.0):  # a new means tensor of the same size, as refinement makes, at twice the depth
        means = torch.tensor([[0.0, 0.0, depth], [0.1, 0.0, depth]])
        filtering(means, quats, log_scales, opacities, log_scales=True)
        rate = 100.0 / depth  # focal / depth, pixels per unit
        assert torch.allclose(torch.exp(2 * seen[-1][0]), torch.exp(2 * log_scales) + 0.2 / rate**2)
    with pytest.raises(ValueError, match="log-scales"):
        filtering(means, quats, log_scales.exp(), opacities)


def test_filter_3d_renders_the_filtered_gaussians(levers) -> None:
    model, camera = overlapping_gaussians(), two_cameras()[0]
    with torch.no_grad():
        plain = model.render(camera, 0, torch.zeros(3)).alpha
        with levers.applied("filter-3d", 1.0, two_cameras()):  # 1 px²: about the Gaussians' own size here
            blurred = model.render(camera, 0, torch.zeros(3)).alpha
    assert float(blurred.max()) < float(plain.max())  # the opacity compensation spreads the same mass wider
    assert float((blurred > 1e-3).sum()) > float((plain > 1e-3).sum())


def test_true_depth_adds_its_weighted_error_at_full_resolution_only(levers) -> None:
    model = overlapping_gaussians()
    views = dataclasses.replace(noise_views(), depths=torch.full((2, SIZE, SIZE), 2.5))
    images = training_step.TrainImages(views)
    with levers.applied("true-depth", 0.5, views.cameras):
        camera, target = images.get(1, 0)
        render = model.render(camera, 0, torch.zeros(3))
        total = training_step.photometric_loss(render.rgb, target, 0.2)
        expected = (photometric_loss(render.rgb, target, 0.2)
                    + 0.5 * levers.true_depth_error(render.depth, render.alpha, views.depths[1]))
        camera, target = images.get(1, 1)
        coarse = model.render(camera, 0, torch.zeros(3))
        coarse_total = training_step.photometric_loss(coarse.rgb, target, 0.2)
    assert float(levers.true_depth_error(render.depth, render.alpha, views.depths[1]).detach()) > 0.01
    assert float(total.detach()) == pytest.approx(float(expected.detach()))
    assert float(coarse_total.detach()) == pytest.approx(float(photometric_loss(coarse.rgb, target, 0.2).detach()))


@pytest.mark.parametrize("lever", ["depth-smoothness", "opacity-entropy"])
def test_a_regulariser_adds_its_weighted_term_to_the_photometric_loss(levers, lever) -> None:
    model, views = overlapping_gaussians(), noise_views()
    images = training_step.TrainImages(views)
    with levers.applied(lever, 0.5, views.cameras):
        camera, target = images.get(1, 0)
        render = model.render(camera, 0, torch.zeros(3))
        total = training_step.photometric_loss(render.rgb, target, 0.2)
    term = (levers.depth_smoothness(render.depth, render.alpha, target) if lever == "depth-smoothness"
            else levers.opacity_entropy(model.opacity_logits))
    assert float(term.detach()) > 1e-4
    expected = photometric_loss(render.rgb, target, 0.2) + 0.5 * term
    assert float(total.detach()) == pytest.approx(float(expected.detach()))


def test_merged_replaces_the_row_of_the_same_lever_weight_preset_and_seed(levers) -> None:
    old = [{"lever": "none", "weight": 0.0, "preset": "fast", "seed": 0, "psnr": 1.0},
           {"lever": "filter-3d", "weight": 0.2, "preset": "fast", "seed": 0, "psnr": 2.0}]
    row = {"lever": "none", "weight": 0.0, "preset": "fast", "seed": 0, "psnr": 3.0}
    assert levers.merged(row, old) == [old[1], row]
    other_seed = {**row, "seed": 1}
    assert levers.merged(other_seed, old) == [*old, other_seed]


@pytest.mark.parametrize("weight", [0.0, -1.0, math.nan])
def test_a_lever_needs_a_positive_weight(levers, weight) -> None:
    with pytest.raises(SystemExit, match="--weight must be positive"):
        levers.main(levers.Args(lever="filter-3d", weight=weight))
