"""The angular gap: the angle to the nearest training view that saw a Gaussian, against a float64 brute force."""

from __future__ import annotations

import dataclasses
import math

import torch

from splatu.baselines.angle import VIEW_CHUNK, AngleSource, ViewCoverage, angular_gap, view_coverage
from splatu.baselines.residual import ResidualSource, training_residuals
from splatu.baselines.visibility import visibility_counts
from tests.small_models import noise_views, overlapping_gaussians, two_cameras


def test_gap_is_the_angle_to_the_nearest_seeing_view_over_pi_and_unseen_views_do_not_count():
    means = torch.zeros(2, 3)  # both at the origin; only the first was seen, from the camera at z = -1
    coverage = ViewCoverage(torch.tensor([[True, False], [False, False]]), torch.tensor([[0.0, 0.0, -1.0],
                                                                                         [1.0, 0.0, 0.0]]))
    for viewer, expected in (((0.0, 0.0, -3.0), 0.0), ((0.0, 2.0, 0.0), 0.5), ((0.0, 0.0, 5.0), 1.0),
                             ((2.0, 0.0, 0.0), 0.5)):  # the last: along the camera that did NOT see it
        gap = angular_gap(means, coverage, torch.tensor(viewer))
        assert math.isclose(float(gap[0]), expected, abs_tol=1e-3), viewer
        assert float(gap[1]) == 1.0  # no training view saw it: the worst gap from anywhere


def test_gap_matches_a_float64_brute_force_across_view_chunks():
    g = torch.Generator().manual_seed(0)
    n, views = 50, VIEW_CHUNK * 2 + 5
    means = torch.randn(n, 3, generator=g)
    seen = torch.rand(n, views, generator=g) < 0.1
    seen[-3:] = False  # never seen
    coverage = ViewCoverage(seen, torch.randn(views, 3, generator=g) * 4)
    viewer = torch.tensor([0.5, -3.0, 2.0])
    gap = angular_gap(means, coverage, viewer)
    for i in range(n):
        best = math.pi  # no seeing view: the opposite side
        for v in range(views):
            if coverage.seen[i, v]:
                a, b = (means[i] - viewer).double(), (means[i] - coverage.centres[v]).double()
                best = min(best, math.acos(max(-1.0, min(1.0, float(a @ b / (a.norm() * b.norm()))))))
        assert math.isclose(float(gap[i]), best / math.pi, abs_tol=1e-3), i
    assert (gap[-3:] == 1.0).all() and (gap[:-3] < 1.0).all()


def test_a_camera_on_a_mean_reads_half_and_nothing_is_nan():
    means = torch.tensor([[1.0, 2.0, 3.0]])
    coverage = ViewCoverage(torch.tensor([[True]]), torch.zeros(1, 3))
    gap = angular_gap(means, coverage, means[0])  # zero-length viewing direction
    assert float(gap[0]) == 0.5
    no_views = ViewCoverage(torch.zeros(1, 0, dtype=torch.bool), torch.zeros(0, 3))
    assert float(angular_gap(means, no_views, torch.zeros(3))[0]) == 1.0


def test_coverage_uses_the_loss_supervision_rule_and_counts_like_visibility():
    model, cameras = overlapping_gaussians(), two_cameras()
    coverage = view_coverage(model, cameras, 0.05)
    for v, camera in enumerate(cameras):
        expected = model.render(camera, 0, torch.zeros(3)).raster.contrib_max >= 0.05
        assert torch.equal(coverage.seen[:, v], expected)
    assert coverage.seen.any() and not coverage.seen[-1].any()  # the far-off Gaussian: never seen
    torch.testing.assert_close(visibility_counts(model, cameras, 0.05), coverage.seen.sum(1).float())
    torch.testing.assert_close(coverage.centres, torch.stack([c.center() for c in cameras]))


def test_coverage_counts_only_the_pixels_the_mask_files_keep():
    """A Gaussian that shows only where a view's mask file excludes the pixels was never trained from that view."""
    model, cameras = overlapping_gaussians(), two_cameras()
    height, width = cameras[0].height, cameras[0].width
    everything = torch.ones(len(cameras), height, width)
    assert torch.equal(view_coverage(model, cameras, 0.05, masks=everything).seen, view_coverage(model, cameras,
                                                                                                 0.05).seen)
    left = everything.clone()
    left[:, :, width // 2:] = 0.0
    seen_left = view_coverage(model, cameras, 0.05, masks=left).seen
    for v, camera in enumerate(cameras):
        weights = model.render(camera, 0, torch.zeros(3), contribution_mask=left[v] > 0).raster.contrib_max
        assert torch.equal(seen_left[:, v], weights >= 0.05)
    assert seen_left.sum() < view_coverage(model, cameras, 0.05).seen.sum()
    assert not view_coverage(model, cameras, 0.05, masks=torch.zeros_like(everything)).seen.any()
    torch.testing.assert_close(visibility_counts(model, cameras, 0.05, masks=left), seen_left.sum(1).float())


def test_from_a_training_view_every_seen_gaussian_has_zero_gap_so_only_empty_space_is_uncertain():
    model, cameras = overlapping_gaussians(), two_cameras()
    source = AngleSource(model, 0, torch.zeros(3), view_coverage(model, cameras, 0.0))  # threshold 0: all seen
    out = source.render(cameras[0])
    torch.testing.assert_close(out.uncertainty, 1.0 - out.alpha, atol=1e-4, rtol=0)  # arccos(≈1) in float32
    assert (out.alpha > 0.1).any()


def test_ours_residual_angle_is_the_or_of_the_three_maps():
    model, views = overlapping_gaussians(), noise_views()
    with torch.no_grad():
        model.u_sh[:, 0, 0] = torch.linspace(-2.0, 2.0, len(model))
    residuals = training_residuals(model, views, 0, torch.zeros(3))
    coverage = view_coverage(model, views.cameras, 0.05)
    camera = dataclasses.replace(views.cameras[1], world_to_camera=views.cameras[1].world_to_camera.clone())
    camera.world_to_camera[1, 3] = 0.5  # off the training cameras' line: every seen Gaussian has a gap
    combined = ResidualSource(model, 0, torch.zeros(3), residuals, with_ours=True, coverage=coverage).render(camera)
    residual = ResidualSource(model, 0, torch.zeros(3), residuals, with_ours=False).render(camera).uncertainty
    angle = AngleSource(model, 0, torch.zeros(3), coverage).render(camera).uncertainty
    ours = model.render(camera, 0, torch.zeros(3), with_uncertainty=True).uncertainty
    torch.testing.assert_close(combined.uncertainty, 1 - (1 - ours) * (1 - residual) * (1 - angle), atol=1e-6, rtol=0)
    u = combined.uncertainty
    assert torch.isfinite(u).all() and (u >= 0).all() and (u <= 1).all()
    covered = combined.alpha > 0.5
    assert covered.any() and (angle[covered] > 1e-3).all()  # the gap, not empty space, on the covered pixels
