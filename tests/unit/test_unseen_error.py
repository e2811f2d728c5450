"""The unseen-block error split (benchmarks/unseen_error.py): per-bin sums on made-up pixels, the depth error and
the Gaussians' offsets from the true surface on one- to three-Gaussian models."""

from __future__ import annotations

import math

import pytest
import torch

from splatu.data.poster.generate import build_scene, camera_path, standin_splits
from splatu.data.poster.raycast import blocked
from splatu.data.poster.render import render
from splatu.data.poster.visibility import in_view
from splatu.model import GaussianModel, ModelConfig
from tests.benchmark_scripts import benchmark_script
from tests.small_models import SIZE, noise_views, two_cameras
from tests.unit.test_poster import TINY


@pytest.fixture(scope="module")
def unseen_error():
    yield from benchmark_script("unseen_error")


def test_binned_pools_each_bin_and_skips_missing_depths(unseen_error) -> None:
    pixels = unseen_error.PixelErrors(
        squared=torch.tensor([1e-2, 1e-2, 1e-4, 3e-4], dtype=torch.float64),
        squared_dc=torch.tensor([1e-3, 1e-3, 1e-4, 1e-4], dtype=torch.float64),
        squared_reprojected=torch.tensor([1e-4, 1e-4, 1e-3, 1e-3], dtype=torch.float64),
        depth=torch.tensor([0.01, math.nan, 0.03, 0.05], dtype=torch.float64),
    )
    rows = unseen_error.binned(pixels, torch.tensor([1.0, 2.0, 12.0, 15.0]), (0.0, 5.0, 10.0, 20.0, math.inf))
    assert [(r["from"], r["to"]) for r in rows] == [(0.0, 5.0), (10.0, 20.0)]  # the empty [5, 10) bin is left out
    low, high = rows
    assert low["pixels"] == pytest.approx(0.5) and high["pixels"] == pytest.approx(0.5)
    assert low["psnr"] == pytest.approx(20.0) and low["psnr_dc_only"] == pytest.approx(30.0)
    assert low["psnr_reprojected"] == pytest.approx(40.0) and high["psnr_reprojected"] == pytest.approx(30.0)
    assert high["psnr"] == pytest.approx(-10 * math.log10(2e-4))
    assert low["squared_error"] == pytest.approx(0.02 / 0.0204)
    assert low["depth_error"] == pytest.approx(0.01)  # the NaN (less than half opaque) pixel is not counted
    assert high["depth_error"] == pytest.approx(0.04)


def test_binned_reports_no_depth_error_when_no_pixel_has_one(unseen_error) -> None:
    pixels = unseen_error.PixelErrors(*(torch.full((2,), 1e-3, dtype=torch.float64) for _ in range(3)),
                                      torch.full((2,), math.nan, dtype=torch.float64))
    (row,) = unseen_error.binned(pixels, torch.zeros(2), (0.0, 1.0))
    assert row["depth_error"] is None and row["psnr"] == pytest.approx(30.0)


def gaussians(means: list[list[float]], opacities: list[float], scales: list[float]) -> GaussianModel:
    n = len(means)
    return GaussianModel(torch.tensor(means), torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
                         torch.tensor(scales).log()[:, None].repeat(1, 3), torch.logit(torch.tensor(opacities)),
                         torch.zeros(n, 1, 3), torch.zeros(n, 0, 3), torch.zeros(n, 1, 1),
                         ModelConfig(sh_degree=0, u_sh_degree=0))


def test_relative_depth_error_reads_the_rendered_depth_as_already_normalised(unseen_error) -> None:
    model = gaussians([[0.0, 0.0, 3.0]], [0.6], [1.0])  # alpha about 0.6 at the centre, 0.09 in the corners
    with torch.no_grad():
        render = model.render(two_cameras()[0], 0, torch.zeros(3))
    error = unseen_error.relative_depth_error(render, torch.full((SIZE, SIZE), 2.5))
    centre = SIZE // 2
    assert float(render.alpha[centre, centre]) == pytest.approx(0.6, abs=0.02)
    assert float(error[centre, centre]) == pytest.approx(3.0 / 2.5 - 1.0, rel=1e-5)  # not 3 / 0.6 / 2.5 - 1
    assert torch.isnan(error[0, 0])  # less than half opaque: no depth to compare


def test_surface_offsets_read_the_true_depth_under_each_strong_gaussian(unseen_error) -> None:
    # camera a sees the first mean at (u, v) = (8.6, 3.6), i.e. column 8 and row 3; camera b (0.2 to the side) at
    # column 9. The true depth varies along columns only, so a swapped or rounded pixel reads another depth. A faint
    # Gaussian and a strong one centred left of the image (it covers the left edge) must not count.
    model = gaussians([[0.65, -0.6, 3.0], [0.1, 0.0, 3.5], [-1.75, 0.0, 3.0]], [0.9, 0.05, 0.9], [0.5, 0.5, 0.8])
    views = noise_views()
    column = torch.arange(SIZE, dtype=torch.float32).expand(SIZE, SIZE)
    views.depths = torch.stack([2.0 + 0.1 * column, 4.0 - 0.1 * column])
    with torch.no_grad():
        assert float(model.render(views.cameras[0], 0, torch.zeros(3)).raster.contrib_max[2]) >= unseen_error.MIN_WEIGHT
    offsets = unseen_error.surface_offsets(model, views)
    assert offsets.tolist() == pytest.approx([3.0 / 2.8 - 1.0, 3.0 / 3.1 - 1.0], rel=1e-5)


def test_offset_summary(unseen_error) -> None:
    summary = unseen_error.offset_summary(torch.tensor([-0.3, -0.1, 0.2, 0.4], dtype=torch.float64))
    assert summary["gaussian_views"] == 4 and summary["median_abs"] == pytest.approx(0.25)
    assert summary["quantiles"]["0.5"] == pytest.approx(0.05)
    assert unseen_error.offset_summary(torch.zeros(0)) == {"gaussian_views": 0, "median_abs": None, "quantiles": {}}


def test_bilinear_interpolates_between_pixel_centres_and_clamps_at_the_edges(unseen_error) -> None:
    images = torch.tensor([[[0.0], [1.0]], [[2.0], [3.0]]]).repeat(2, 1, 1, 3)  # (2 views, 2x2, 3 channels)
    images[1] += 10.0
    x, y = torch.tensor([0.0, 0.5, 1.0, -3.0, 0.5]), torch.tensor([0.0, 0.5, 1.0, 0.0, 9.0])
    sampled = unseen_error.bilinear(images, torch.tensor([0, 0, 0, 0, 1]), x, y)
    assert sampled[:, 0].tolist() == pytest.approx([0.0, 1.5, 3.0, 0.0, 12.5])


def test_nearest_view_colours_takes_the_closest_view_in_angle_that_sees_each_point(unseen_error) -> None:
    world, cameras = build_scene(), camera_path(TINY)
    train_ids, eval_ids, _ = standin_splits(TINY)
    train = [cameras[i] for i in train_ids]
    viewer = cameras[eval_ids[len(eval_ids) // 2]]
    points = render(world, viewer).points
    images = torch.arange(len(train), dtype=torch.float32)[:, None, None, None].expand(-1, TINY.height, TINY.width, 3)
    chosen = unseen_error.nearest_view_colours(world, points, viewer.center(), train, images.contiguous())[:, 0]

    # brute force: every view's visibility and angle, for every point
    centres = torch.stack([c.center().double() for c in train])
    sees = in_view(train, points)
    for k in range(len(train)):
        rows = sees[k].nonzero()[:, 0]
        sees[k, rows] = ~blocked(world, centres[k].expand(rows.numel(), 3), points[rows])
    to_viewer = torch.nn.functional.normalize(viewer.center().double() - points, dim=-1)
    cosines = torch.stack([(torch.nn.functional.normalize(c - points, dim=-1) * to_viewer).sum(-1) for c in centres])
    best = torch.where(sees, cosines, -math.inf).argmax(0).float()
    seen = sees.any(0)
    assert 0.3 < float(seen.float().mean()) < 1.0  # some of what the middle of the block sees, no training view does
    assert torch.equal(chosen[seen], best[seen])
    assert torch.isnan(chosen[~seen]).all()


def test_nearest_view_colours_samples_each_point_where_it_projects_with_pixel_centres_at_half(unseen_error) -> None:
    world, cameras = build_scene(), camera_path(TINY)
    train_ids, eval_ids, _ = standin_splits(TINY)
    train = [cameras[i] for i in train_ids]
    viewer = cameras[eval_ids[0]]
    points = render(world, viewer).points
    ys, xs = torch.meshgrid(torch.arange(TINY.height), torch.arange(TINY.width), indexing="ij")
    images = torch.stack([xs, ys, torch.zeros_like(xs)], dim=-1).float().expand(len(train), -1, -1, -1).clone()
    images[..., 2] = torch.arange(len(train), dtype=torch.float32)[:, None, None]  # which view was sampled
    colours = unseen_error.nearest_view_colours(world, points, viewer.center(), train, images)
    seen = ~torch.isnan(colours[:, 0])
    assert int(seen.sum()) > 100
    for k in colours[seen, 2].unique().long().tolist():
        rows = seen & (colours[:, 2] == k)
        uv, _ = train[k].to(dtype=torch.float64).project(points[rows].double())
        expected = (uv - 0.5).clamp_min(0.0)  # x and y, clamped at the first pixel centre
        expected[:, 0] = expected[:, 0].clamp_max(TINY.width - 1)
        expected[:, 1] = expected[:, 1].clamp_max(TINY.height - 1)
        assert torch.allclose(colours[rows, :2].double(), expected, atol=1e-3)
