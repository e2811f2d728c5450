"""The colour-spread uncertainty: the std of the colours a pixel blends, against its closed form."""

from __future__ import annotations

import math

import pytest
import torch

from splatu.baselines.model_sources import SPREAD_SCALE, SpreadSource, colour_spread
from splatu.camera import Camera
from splatu.model import GaussianModel, ModelConfig
from splatu.sh import rgb_to_sh


def _two_layers(front: tuple[float, float, float], back: tuple[float, float, float], o_front: float,
                o_back: float) -> GaussianModel:
    """Two huge flat Gaussians on the optical axis at depths 2 and 4: every pixel sees both, α = opacity."""
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 4.0]])
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2)
    log_scales = torch.log(torch.tensor([[1e3, 1e3, 1e-3]] * 2))
    logits = torch.logit(torch.tensor([o_front, o_back]))
    sh_dc = rgb_to_sh(torch.tensor([front, back])).unsqueeze(1)
    cfg = ModelConfig(sh_degree=0, u_sh_degree=0)
    return GaussianModel(means, quats, log_scales, logits, sh_dc, torch.zeros(2, 0, 3), torch.zeros(2, 1, 1), cfg)


def _camera(size: int = 8) -> Camera:
    K = torch.tensor([[10.0, 0.0, size / 2], [0.0, 10.0, size / 2], [0.0, 0.0, 1.0]])
    return Camera(world_to_camera=torch.eye(4), K=K, width=size, height=size, near=0.01, far=100.0, name="c")


@pytest.mark.parametrize(("o_front", "o_back"), [(0.5, 0.9), (0.2, 0.3), (0.9, 0.05)])
def test_two_layers_give_the_two_point_standard_deviation(o_front, o_back):
    red, blue = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)
    model = _two_layers(red, blue, o_front, o_back)
    out = SpreadSource(model, 0, torch.zeros(3), with_ours=False).render(_camera())
    w_front, w_back = o_front, (1 - o_front) * o_back
    p = w_front / (w_front + w_back)
    std = math.dist(red, blue) * math.sqrt(p * (1 - p))  # two-point distribution of the blended colours
    alpha = w_front + w_back
    expected = alpha * std / (std + SPREAD_SCALE) + (1 - alpha)
    # atol: VARIANCE_ROUNDING's floor (1e-5·E|c|²) moves S by up to ~1e-4 at these spreads
    torch.testing.assert_close(out.uncertainty, torch.full((8, 8), expected), atol=3e-4, rtol=0)


def test_equal_colours_have_no_spread_and_ours_combines_as_or():
    model = _two_layers((0.3, 0.6, 0.2), (0.3, 0.6, 0.2), 0.6, 0.99)
    spread = SpreadSource(model, 0, torch.zeros(3), with_ours=False).render(_camera()).uncertainty
    alpha = 0.6 + 0.4 * 0.99
    torch.testing.assert_close(spread, torch.full((8, 8), 1 - alpha), atol=1e-4, rtol=0)  # only the empty part
    with torch.no_grad():
        model.u_sh.fill_(0.0)  # u = 0.5 in every direction
    combined = SpreadSource(model, 0, torch.zeros(3), with_ours=True).render(_camera()).uncertainty
    ours = 0.5 * alpha + (1 - alpha)
    torch.testing.assert_close(combined, 1 - (1 - ours) * (1 - spread), atol=1e-4, rtol=0)


def test_spread_stays_finite_and_in_unit_range_where_nothing_or_almost_nothing_is_seen():
    alpha = torch.tensor([[0.0, 1e-12, 1e-7, 0.5, 1.0]])
    # features composited on background 1, including float32 rounding noise on almost-empty pixels
    features = torch.stack([torch.ones(1, 5) + torch.tensor([[0.0, 1e-7, -1e-7, 0.1, -0.3]])] * 4, dim=-1)
    spread = colour_spread(features, alpha)
    assert torch.isfinite(spread).all() and (spread >= 0).all() and (spread <= 1).all()
    assert spread[0, 0] == 1.0  # empty reads fully uncertain
