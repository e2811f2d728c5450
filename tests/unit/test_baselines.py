"""The ensemble and visibility-count baselines (REFERENCE §5), on closed-form cases."""

from __future__ import annotations

import json

import pytest
import torch

from splatu.baselines.ensemble import EnsembleSource, read_ensemble
from splatu.baselines.fisher import fisher_diagonal
from splatu.baselines.load import _ensemble_seconds
from splatu.baselines.visibility import visibility_feature
from splatu.errors import SplatuError
from splatu.rasterizer import kernels
from splatu.rasterizer.kernels import set_compile
from splatu.sh import rgb_to_sh
from tests.small_models import overlapping_gaussians, two_cameras


def test_ensemble_uncertainty_is_the_population_std_of_the_members():
    """Two members that differ only in colour render a and b: their std over members (ddof 0) is |a − b|/2."""
    first, second = overlapping_gaussians(), overlapping_gaussians()
    with torch.no_grad():
        second.sh_dc.copy_(rgb_to_sh(torch.rand(len(second), 3, generator=torch.Generator().manual_seed(5))[:, None]))
    camera = two_cameras()[0]
    with torch.no_grad():
        a, b = (member.render(camera, 0, torch.zeros(3)).rgb for member in (first, second))
        out = EnsembleSource([first, second], 0, torch.zeros(3)).render(camera)
    torch.testing.assert_close(out.uncertainty, ((a - b).abs() / 2).mean(-1))
    torch.testing.assert_close(out.rgb, (a + b) / 2)
    assert float(out.uncertainty.max()) > 0.05  # the members really differ


def test_ensemble_members_disagreeing_only_above_white_show_one_colour_and_no_uncertainty():
    """Colours past 1 are clipped in every image eval-ause scores, so two members rendering 1.5 and 3 both show
    white: their std over the unclipped values (0.75) called a pixel uncertain whose scored error is 0, and their
    unclipped mean was clipped after averaging, not averaged over what each member shows."""
    bright, brighter = overlapping_gaussians(), overlapping_gaussians()
    with torch.no_grad():
        bright.sh_dc.copy_(rgb_to_sh(torch.full((len(bright), 3), 1.5))[:, None])
        brighter.sh_dc.copy_(rgb_to_sh(torch.full((len(brighter), 3), 3.0))[:, None])
    camera = two_cameras()[0]
    with torch.no_grad():
        shown = [member.render(camera, 0, torch.zeros(3)).rgb for member in (bright, brighter)]
        out = EnsembleSource([bright, brighter], 0, torch.zeros(3)).render(camera)
    saturated = (shown[0] >= 1.0).all(-1)
    assert bool(saturated.any()) and bool((shown[1][saturated] > shown[0][saturated] + 0.1).any())
    assert float(out.uncertainty[saturated].abs().max()) == 0.0
    torch.testing.assert_close(out.rgb, torch.stack(shown).clamp(0, 1).mean(0))


def test_ensemble_depth_counts_only_the_members_that_drew_the_pixel():
    """A member that draws nothing at a pixel has depth 0 there; the plain mean over members halved the depth of a
    pixel only one of two members covers."""
    first, elsewhere = overlapping_gaussians(), overlapping_gaussians()
    with torch.no_grad():
        elsewhere.means.add_(torch.tensor([0.0, 0.0, -100.0]))  # behind the camera: it draws nothing
    camera = two_cameras()[0]
    with torch.no_grad():
        alone = first.render(camera, 0, torch.zeros(3))
        out = EnsembleSource([first, elsewhere], 0, torch.zeros(3)).render(camera)
        assert float(elsewhere.render(camera, 0, torch.zeros(3)).alpha.max()) == 0.0
    drawn = alone.alpha > 0
    assert bool(drawn.any()) and not bool(drawn.all())
    torch.testing.assert_close(out.depth[drawn], alone.depth[drawn])
    assert float(out.depth[~drawn].abs().max()) == 0.0


def test_visibility_feature_is_one_over_one_plus_the_count():
    """1 for a Gaussian no training view saw, 1/2 for one view, 1/4 for three."""
    torch.testing.assert_close(visibility_feature(torch.tensor([0.0, 1.0, 3.0])), torch.tensor([1.0, 0.5, 0.25]))


@pytest.mark.parametrize("wall", ['"12 s"', "NaN", "true"])
def test_an_ensemble_record_whose_wall_time_is_not_a_number_is_one_line(tmp_path, wall):
    (tmp_path / "ensemble.json").write_text(f'{{"members": ["members/0", "members/1"], "wall_seconds": {wall}}}')
    with pytest.raises(SplatuError, match=r"wall_seconds is .*, not a number"):
        read_ensemble(tmp_path)
    (tmp_path / "ensemble.json").write_text('{"members": ["members/0", "members/1"], "wall_seconds": 12.5}')
    assert read_ensemble(tmp_path).wall_seconds == 12.5


@pytest.mark.slow
def test_the_fisher_information_is_the_same_with_compiled_kernels(monkeypatch):
    """A compiled backward frees its saved buffers, so the probes' second backward through one render raised
    ("compiled with non-empty donated buffers"): the uncertainty study and any process that had trained with compiled
    kernels could not build the fisher baseline. The buffers are donated by AOTAutograd, which the aot_eager backend
    runs as inductor does, without inductor's C++ compile (this test took 76 s with a cold compile cache)."""
    real_compile = torch.compile
    monkeypatch.setattr(torch, "compile", lambda fn, **options: real_compile(fn, backend="aot_eager", **options))
    monkeypatch.setattr(kernels, "_compiled", {})
    torch._dynamo.reset()
    model, cameras = overlapping_gaussians(), two_cameras()
    estimates = []
    for compiled in (False, True):
        previous = set_compile(compiled)
        try:
            estimates.append(fisher_diagonal(model, cameras, 0, 3, torch.Generator().manual_seed(5)))
        finally:
            set_compile(previous)
    torch._dynamo.reset()  # nothing later runs the aot_eager graphs
    assert estimates[0].max() > 0  # the visible Gaussians are constrained
    torch.testing.assert_close(estimates[1], estimates[0], rtol=1e-5, atol=1e-8)


def test_an_ensemble_with_a_member_without_a_compile_time_counts_every_compile_in_its_steps(tmp_path):
    """A member saved before compiles were timed apart (or whose torch could not time them) has them in its
    train_seconds; summed with members that left theirs out, the ensemble's time in steps mixed the two measures
    beside a null compile time, which says that the steps include every compile."""
    members = []
    for name, times in (("old", {"train_seconds": 50.0}), ("new", {"train_seconds": 40.0,
                                                                     "train_compile_seconds": 9.0})):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps(times))
        members.append(tmp_path / name)
    assert _ensemble_seconds(1000.0, members) == (99.0, None, 1000.0)
    assert _ensemble_seconds(1000.0, members[1:] * 2) == (80.0, 18.0, 1000.0)
