"""The uncertainty, depth and alpha maps `render-uncertainty` writes for ours, checked at pixels against the paper's
rendering worked by hand (REFERENCE §1): two isotropic Gaussians in front of a rotated, off-centre camera,

    U(p) = Σ_i w_i(p)·u_i(d_i) + (1 − Σ_i w_i(p))·1,   u_i(d) = sigmoid(Σ_k u_sh[i, k]·Y_k(d)),
    d_i = normalize(mean_i − camera centre),   depth(p) = Σ_i w_i z_i / Σ_i w_i,

with w_i = T_i·α_i composited front to back, the projection from the pinhole model and EWA's J, and Y_k from
REFERENCE §2's constants. Neither the rasterizer nor `eval_sh` computes the expected values.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import torch

from splatu.baselines.model_sources import OursSource
from splatu.camera import Camera, look_at
from splatu.checkpoint import select_head
from splatu.maps import read_entry
from splatu.model import GaussianModel, ModelConfig
from splatu.render_uncertainty import ViewSpec, render_views, write_outputs
from splatu.train_config import TrainConfig

C0, C1 = 0.28209479177387814, 0.4886025119029199
SIZE = 16
FOCAL = 20.0
MEANS = [[0.1, -0.05, 0.2], [-0.05, 0.1, -0.3]]
SCALES = [0.15, 0.25]
OPACITIES = [0.6, 0.7]
U_SH = [[[0.4, -1.0], [1.5, 0.0], [-2.0, 0.0], [0.7, 0.0]],  # (K = 4, heads = 2): the own head is degree 1,
        [[1.2, 0.3], [-0.8, 0.0], [0.5, 0.0], [2.5, 0.0]]]  # the extra head degree 0
DEPTH_UNIT = 2.5
EXTRA = "degree=0"


def _camera() -> Camera:
    position = torch.tensor([0.6, -0.4, -2.5])
    w2c = look_at(position, torch.tensor([0.05, 0.0, 0.0]), torch.tensor([0.0, -1.0, 0.0]))
    K = torch.tensor([[FOCAL, 0.0, 7.3], [0.0, FOCAL, 8.6], [0.0, 0.0, 1.0]])
    return Camera(K, w2c.float(), SIZE, SIZE, name="view")


def _model() -> GaussianModel:
    n = len(MEANS)
    cfg = ModelConfig(sh_degree=0, u_sh_degree=1)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n)
    sh_dc = torch.tensor([[[0.8, -0.3, 0.1]], [[-0.5, 0.6, 0.2]]])
    return GaussianModel(torch.tensor(MEANS), quats, torch.log(torch.tensor(SCALES))[:, None].repeat(1, 3),
                         torch.logit(torch.tensor(OPACITIES)), sh_dc, torch.zeros(n, 0, 3), torch.tensor(U_SH), cfg)


def _by_hand(camera: Camera, channel: int, degree: int, blur: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(U, depth in model units, alpha) at every pixel, from the formulas in the module's docstring."""
    w2c = camera.world_to_camera.double()
    R, t = w2c[:3, :3], w2c[:3, 3]
    centre = -R.T @ t
    fx, fy, cx, cy = (float(camera.K[i, j]) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
    layers = []
    for mean, scale, opacity, u_sh in zip(MEANS, SCALES, OPACITIES, U_SH, strict=True):
        mean = torch.tensor(mean, dtype=torch.float64)
        x, y, z = (R @ mean + t).tolist()
        J = torch.tensor([[fx / z, 0.0, -fx * x / z**2], [0.0, fy / z, -fy * y / z**2]], dtype=torch.float64)
        cov2d = scale**2 * J @ J.T + blur * torch.eye(2, dtype=torch.float64)  # isotropic: R Σ Rᵀ = s² I
        d = (mean - centre) / (mean - centre).norm()
        dx, dy, dz = d.tolist()
        logit = C0 * u_sh[0][channel]
        if degree >= 1:
            logit += -C1 * dy * u_sh[1][channel] + C1 * dz * u_sh[2][channel] - C1 * dx * u_sh[3][channel]
        layers.append((z, (fx * x / z + cx, fy * y / z + cy), torch.linalg.inv(cov2d), opacity,
                       1.0 / (1.0 + math.exp(-logit))))
    layers.sort(key=lambda layer: layer[0])
    U, depth, alpha = (np.zeros((SIZE, SIZE)) for _ in range(3))
    for i in range(SIZE):
        for j in range(SIZE):
            transmittance, u_sum, z_sum = 1.0, 0.0, 0.0
            for z, (mx, my), conic, opacity, u in layers:
                offset = torch.tensor([j + 0.5 - mx, i + 0.5 - my], dtype=torch.float64)
                a = min(0.99, opacity * math.exp(-0.5 * float(offset @ conic @ offset)))
                if a < 1 / 255:
                    continue
                u_sum += transmittance * a * u
                z_sum += transmittance * a * z
                transmittance *= 1.0 - a
            alpha[i, j] = 1.0 - transmittance
            U[i, j] = u_sum + transmittance * 1.0
            depth[i, j] = z_sum / alpha[i, j] if alpha[i, j] > 0 else 0.0
    return U, depth, alpha


def _written(model: GaussianModel, out: Path, gt: np.ndarray) -> dict[str, np.ndarray]:
    """What render-uncertainty's rendering and writing make of `model` for the one view: its npy maps."""
    source = OursSource(model, 0, torch.zeros(3))
    views, _ = render_views(source, ViewSpec([_camera()], ["view"], depth_unit=DEPTH_UNIT))
    views[0].gt = gt
    write_outputs(out, views, orbit=False, fps=6)
    return {key: np.load(out / "npy" / f"view_{key}.npy") for key in ("uncertainty", "depth", "alpha", "rgb")}


def test_the_written_uncertainty_depth_and_alpha_are_the_papers_rendering_worked_by_hand(tmp_path):
    model = _model()
    U, depth, alpha = _by_hand(_camera(), 0, 1, model.cfg.screen_blur)
    assert 0.05 < alpha.max() < 0.99 and (alpha < 1e-6).any()  # a pixel that both Gaussians leave partly empty
    maps = _written(model, tmp_path / "ours", np.full((SIZE, SIZE, 3), 0.3))
    np.testing.assert_allclose(maps["alpha"], alpha, atol=2e-5)
    np.testing.assert_allclose(maps["uncertainty"], U, atol=2e-5)
    np.testing.assert_allclose(maps["depth"], depth * DEPTH_UNIT, rtol=1e-5, atol=1e-5)
    assert (maps["depth"][alpha == 0] == 0).all()
    # the maps eval-ause scores: the same U as float32, the render and ground truth within 16-bit quantisation
    entry = read_entry(tmp_path / "ours" / "maps", "view")
    np.testing.assert_array_equal(entry.uncertainty, maps["uncertainty"].astype(np.float64))
    np.testing.assert_allclose(entry.rgb, np.clip(maps["rgb"], 0, 1), atol=0.5 / 65535 + 1e-7)
    np.testing.assert_allclose(entry.gt, 0.3, atol=0.5 / 65535)


def test_an_extra_heads_map_is_its_own_channel_at_its_own_degree(tmp_path):
    model = _model()
    base = TrainConfig()
    config = dataclasses.replace(base, model=model.cfg,
                                 uncertainty=dataclasses.replace(base.uncertainty, extra_heads=(EXTRA,)))
    _, head_model = select_head(config, model, EXTRA, tmp_path)
    U, _, _ = _by_hand(_camera(), 1, 0, model.cfg.screen_blur)
    maps = _written(head_model, tmp_path / "head", np.zeros((SIZE, SIZE, 3)))
    np.testing.assert_allclose(maps["uncertainty"], U, atol=2e-5)
    own, _, _ = _by_hand(_camera(), 0, 1, model.cfg.screen_blur)
    assert np.abs(own - U).max() > 0.1  # the two heads differ, so a swapped channel would show
