"""The Gaussian model: 3DGS parameters plus `u_sh`, the view-dependent uncertainty SH.

Every per-Gaussian quantity is a row of one of the `PARAM_NAMES` parameters, so density
control edits rows of these seven tensors (see `splatu.optim`), and choosing the SH degrees
mid-run (`splatu.degree_choice`) cuts their SH columns and uncertainty heads.
Uncertainty seen along unit direction d is u(d) = sigmoid(Σ_k u_sh[k]·Y_k(d)) (REFERENCE §1). `u_sh` has one
channel per uncertainty head (see `losses.uncertainty_heads`); channel 0 is the run's own, the one rendered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal

import torch
from torch import Tensor

from splatu.camera import Camera
from splatu.errors import SplatuError, require_at_least
from splatu.knn import mean_neighbour_distance
from splatu.rasterizer import RasterOutput, rasterize
from splatu.rasterizer.projection import LOW_PASS
from splatu.rasterizer.rasterize import MIN_BLUR
from splatu.sh import C0, MAX_SH_DEGREE, eval_sh, num_sh_bases, rgb_to_sh

NEIGHBOURS = 3
"""Initial scale is the mean distance to this many nearest neighbours (3DGS / splatfacto)."""
MAX_U_INIT_LOGIT = 30.0
"""sigmoid(30) is 1 to float32's precision, so a larger initial logit only slows the uncertainty loss's start."""


@dataclass
class ModelConfig:
    sh_degree: int = 3
    """Colour SH degree (0-3)."""
    sh_degree_interval: int = 1000
    """Raise the active colour SH degree by one every this many steps."""
    u_sh_degree: int = 3
    """Uncertainty SH degree (0-3). On the poster stand-in (one `fast` training with a head per degree) the
    antipodal loss's area under the sparsification curve (MAE) reads 0.100 / 0.078 / 0.074 / 0.070 for degrees
    0 / 1 / 2 / 3, AUSE-MAE 0.409 / 0.373 / 0.330 for 1 / 2 / 3 (the weighted loss's study read 0.431 / 0.421 /
    0.392 / 0.341 for 0-3), so the default is 3; fox needs only 1 (docs/results.md). --degree-choice.on picks it
    per scene. At 0, U has no direction: u(d) = u(−d), so it tells only whether training views saw a Gaussian,
    not from where."""
    u_init_logit: float = 2.0
    """Initial uncertainty logit: u starts at sigmoid(2) ≈ 0.88 everywhere (unseen means uncertain)."""
    init_opacity: float = 0.1
    """Opacity of every Gaussian at initialisation."""
    init_rotations: Literal["random", "identity"] = "random"
    """random: splatfacto's rotations, drawn from the run's seed, so that an ensemble's members on a scene with SfM
    points start from different models, as the paper's ensemble baseline asks; identity: the original 3DGS's. On
    the poster stand-in, whose room and chair are boxes along the world axes, identity read 0.26 dB more on the
    unseen block's observed pixels (mean of two seeds, docs/results.md)."""
    random_init_points: int = 50000
    """Number of random points when the scene has no initial points."""
    random_init_extent: float = 10.0
    """Side of the random-init cube centred at the origin, in scene units (splatfacto: 10 for scenes normalised
    to [-1, 1]); scale it with the scene."""
    screen_blur: float = LOW_PASS
    """px² added to every Gaussian's 2D covariance (3DGS: 0.3, about a pixel). The presets use 0.1: on poster's
    unseen block and path frames +0.55 / +0.7 dB, on fox's held-out block +1.1 dB (mean of two seeds; docs/results.md).
    Viewers that render the exported PLY with 3DGS's 0.3 show such a model slightly blurred."""
    antialiased: bool = False
    """Also scale each opacity by sqrt(det Σ₂ / det(Σ₂ + screen_blur·I)): Mip-Splatting's 2D filter (with a
    screen_blur of 0.1), gsplat's and splatfacto's "antialiased" rasterize mode (with 0.3). The PLY holds the
    unscaled opacities, so a viewer without this filter shows Gaussians smaller than a pixel too opaque."""

    def validate(self) -> None:
        """`check_loadable`, and the initial values a new model is made of (`from_points`), which a loaded model
        never reads: a saved run with a u_init_logit refused since (36d6409) still loads."""
        self.check_loadable()
        if not (math.isfinite(self.u_init_logit) and abs(self.u_init_logit) <= MAX_U_INIT_LOGIT):
            raise SplatuError(f"--model.u-init-logit {self.u_init_logit} is not a number within ±{MAX_U_INIT_LOGIT:g}",
                              "in the model options", "use e.g. 2.0 (u starts at sigmoid(2) ≈ 0.88)")

    def check_loadable(self) -> None:
        """Raise a one-line SplatuError for options no model can be built from."""
        for name in ("sh_degree", "u_sh_degree"):
            value = getattr(self, name)
            if not 0 <= value <= MAX_SH_DEGREE:
                raise SplatuError(f"{name} = {value} is out of range", f"in --model.{name.replace('_', '-')}",
                                  f"use a degree from 0 to {MAX_SH_DEGREE}")
        require_at_least(self.sh_degree_interval, 1, "--model.sh-degree-interval")
        if self.init_rotations not in ("random", "identity"):  # from Python: anything else would read as identity
            raise SplatuError(f"init_rotations = {self.init_rotations!r} is neither random nor identity",
                              "in --model.init-rotations", "use random (splatfacto) or identity (3DGS)")
        if not 0.0 < self.init_opacity < 1.0:
            raise SplatuError(f"init_opacity = {self.init_opacity} is not in (0, 1)", "in --model.init-opacity",
                              "use e.g. 0.1")
        if not (math.isfinite(self.screen_blur) and self.screen_blur >= MIN_BLUR):
            raise SplatuError(f"--model.screen-blur {self.screen_blur} is below {MIN_BLUR} px² or not a number",
                              "in the model options", "use 0.3 (3DGS) or 0.1 (the presets)")
        if self.random_init_points < 1 or not 0 < self.random_init_extent < math.inf:
            raise SplatuError("random initialisation needs at least one point in a cube of positive side",
                              "in --model.random-init-points / --model.random-init-extent", "use e.g. 50000 and 10")


@dataclass
class ModelRender:
    """One rendered view: images split back out of the rasterizer's feature channels."""

    rgb: Tensor  # (H, W, 3)
    alpha: Tensor  # (H, W)
    depth: Tensor  # (H, W)
    uncertainty: Tensor | None  # (H, W), only when rendered with_uncertainty
    extra: Tensor | None  # (H, W, F), only when extra_features were given
    raster: RasterOutput


class GaussianModel(torch.nn.Module):
    """3D Gaussians with colour SH and uncertainty SH, all stored as trainable rows."""

    PARAM_NAMES: ClassVar[tuple[str, ...]] = (
        "means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest", "u_sh",
    )

    def __init__(self, means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor, sh_dc: Tensor,
                 sh_rest: Tensor, u_sh: Tensor, cfg: ModelConfig) -> None:
        super().__init__()
        cfg.check_loadable()
        n = means.shape[0]
        heads = u_sh.shape[-1]  # any number of uncertainty heads; none for a model without a trained uncertainty
        expected = {
            "means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,), "sh_dc": (n, 1, 3),
            "sh_rest": (n, num_sh_bases(cfg.sh_degree) - 1, 3),
            "u_sh": (n, num_sh_bases(cfg.u_sh_degree), heads),
        }
        given = {"means": means, "quats": quats, "log_scales": log_scales, "opacity_logits": opacity_logits,
                 "sh_dc": sh_dc, "sh_rest": sh_rest, "u_sh": u_sh}
        for name, shape in expected.items():
            if tuple(given[name].shape) != shape:
                raise ValueError(f"{name} has shape {tuple(given[name].shape)}, expected {shape}")
        self.cfg = cfg
        self.means = torch.nn.Parameter(means.float().contiguous())
        self.quats = torch.nn.Parameter(quats.float().contiguous())
        self.log_scales = torch.nn.Parameter(log_scales.float().contiguous())
        self.opacity_logits = torch.nn.Parameter(opacity_logits.float().contiguous())
        self.sh_dc = torch.nn.Parameter(sh_dc.float().contiguous())
        self.sh_rest = torch.nn.Parameter(sh_rest.float().contiguous())
        self.u_sh = torch.nn.Parameter(u_sh.float().contiguous())

    @classmethod
    def from_points(cls, points: Tensor, colors: Tensor | None, cfg: ModelConfig,
                    generator: torch.Generator, u_heads: int = 1) -> GaussianModel:
        """Gaussians at SfM points (or random points when `points` is empty), 3DGS initialisation, with splatfacto's
        random rotations unless `cfg.init_rotations` is identity."""
        cfg.validate()
        points = points.detach().to(torch.float32, copy=True).reshape(-1, 3)  # never alias the scene's points
        if points.shape[0] == 0:
            points = (torch.rand(cfg.random_init_points, 3, generator=generator) - 0.5) * cfg.random_init_extent
            colors = torch.rand(cfg.random_init_points, 3, generator=generator)
        if not torch.isfinite(points).all():
            raise SplatuError("initial points contain NaN or Inf", "in the scene's point cloud",
                              "fix or remove the non-finite points (or drop the point cloud to use random init)")
        n = points.shape[0]
        if colors is None:
            colors = torch.full((n, 3), 0.5)
        colors = colors.detach().float().reshape(-1, 3)
        if colors.shape[0] != n:
            raise SplatuError(f"{colors.shape[0]} point colours for {n} points", "in the scene's point cloud",
                              "give one colour per point")
        log_scales = torch.log(mean_neighbour_distance(points, NEIGHBOURS)).unsqueeze(-1).repeat(1, 3)
        quats = random_rotations(n, generator) if cfg.init_rotations == "random" else identity_rotations(n)
        opacity_logits = torch.full((n,), math.log(cfg.init_opacity / (1.0 - cfg.init_opacity)))
        sh_dc = rgb_to_sh(colors.clamp(0.0, 1.0)).unsqueeze(1)
        sh_rest = torch.zeros(n, num_sh_bases(cfg.sh_degree) - 1, 3)
        return cls(points, quats, log_scales, opacity_logits, sh_dc, sh_rest, initial_u_sh(n, cfg, u_heads), cfg)

    @classmethod
    def empty_like_config(cls, n: int, cfg: ModelConfig, u_heads: int = 1) -> GaussianModel:
        """A model of `n` zero rows with the shapes `cfg` and `u_heads` imply, to load a checkpoint into."""
        cfg.check_loadable()
        return cls(torch.zeros(n, 3), torch.zeros(n, 4), torch.zeros(n, 3), torch.zeros(n), torch.zeros(n, 1, 3),
                   torch.zeros(n, num_sh_bases(cfg.sh_degree) - 1, 3),
                   torch.zeros(n, num_sh_bases(cfg.u_sh_degree), u_heads), cfg)

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def has_uncertainty(self) -> bool:
        """Whether `u_sh` holds an uncertainty head; a model loaded from a PLY without `u_*` properties has none."""
        return self.u_sh.shape[-1] > 0

    def without_uncertainty(self) -> GaussianModel:
        """The same Gaussians with no uncertainty head: what a run trained without the uncertainty loss is, since its
        `u_sh` never left the initial value and would read as a measured, uniform uncertainty."""
        return GaussianModel(self.means.detach(), self.quats.detach(), self.log_scales.detach(),
                             self.opacity_logits.detach(), self.sh_dc.detach(), self.sh_rest.detach(),
                             self.u_sh.detach()[..., :0], self.cfg)

    def view_dirs(self, camera: Camera) -> Tensor:
        """(N, 3) mean − camera centre, unnormalised (eval_sh normalises; zero stays safe)."""
        return self.means - camera.center().to(self.means)

    def uncertainty(self, dirs: Tensor, channel: int = 0, degree: int | None = None) -> Tensor:
        """(N,) u_i(d_i) in (0, 1) for per-Gaussian directions `dirs` (N, 3) of any length, from uncertainty head
        `channel` at its own `degree` (the run's u-SH degree when None; channel 0 is the run's own head)."""
        if channel >= self.u_sh.shape[-1]:
            raise SplatuError(f"the model has no uncertainty head {channel}" if self.has_uncertainty else
                              "the model has no uncertainty (trained without the uncertainty loss, or read from a "
                              "PLY without u_* properties)", "when rendering its uncertainty",
                              "render it without uncertainty, or use a model trained with the uncertainty loss")
        degree = self.cfg.u_sh_degree if degree is None else degree
        return torch.sigmoid(eval_sh(head_coefficients(self.u_sh, channel, degree), dirs, degree)).squeeze(-1)

    def colors(self, dirs: Tensor, sh_degree: int) -> Tensor:
        """(N, 3) colour seen along `dirs`: max(SH(d) + 0.5, 0), the 3DGS convention."""
        coeffs = torch.cat([self.sh_dc, self.sh_rest], dim=1)
        return torch.clamp_min(eval_sh(coeffs, dirs, min(sh_degree, self.cfg.sh_degree)) + 0.5, 0.0)

    def render(self, camera: Camera, sh_degree: int, background: Tensor, *, with_uncertainty: bool = False,
               extra_features: Tensor | None = None, contribution_mask: Tensor | None = None) -> ModelRender:
        """Render a view in ONE rasterizer call; uncertainty and extras ride along as feature channels.

        Pixels that see nothing get uncertainty 1 and extra value 1 (their background), so empty space reads
        as uncertain / unseen. `contribution_mask` (H, W) bool: the pixels the contributions count (the view's
        mask file), as in `rasterize`.
        """
        dirs = self.view_dirs(camera)
        channels = [self.colors(dirs, sh_degree)]
        backgrounds = [background.to(self.means).reshape(3)]
        if with_uncertainty:
            channels.append(self.uncertainty(dirs).unsqueeze(-1))
            backgrounds.append(self.means.new_ones(1))
        if extra_features is not None:
            if extra_features.shape[0] != len(self):
                raise ValueError(f"extra_features has {extra_features.shape[0]} rows for {len(self)} Gaussians")
            channels.append(extra_features.to(self.means))
            backgrounds.append(self.means.new_ones(extra_features.shape[1]))
        raster = rasterize(
            self.means, self.quats, self.log_scales, torch.sigmoid(self.opacity_logits), torch.cat(channels, dim=-1),
            camera.world_to_camera.to(self.means), camera.K.to(self.means), camera.width, camera.height,
            near=camera.near, far=camera.far, background=torch.cat(backgrounds), log_scales=True,
            contribution_mask=contribution_mask, blur=self.cfg.screen_blur, antialiased=self.cfg.antialiased,
        )
        image = raster.image
        uncertainty = image[..., 3] if with_uncertainty else None
        extra = image[..., 3 + int(with_uncertainty):] if extra_features is not None else None
        return ModelRender(image[..., :3], raster.alpha, raster.depth, uncertainty, extra, raster)


def head_coefficients(u_sh: Tensor, channel: int, degree: int) -> Tensor:
    """(N, K_degree, 1): the SH of uncertainty head `channel`. The heads share one (N, K, heads) `u_sh` at the
    largest degree; a head trained at a lower degree owns only the leading coefficients of its channel."""
    return u_sh[:, :num_sh_bases(degree), channel:channel + 1]


def random_rotations(n: int, generator: torch.Generator) -> Tensor:
    """(n, 4) unit quaternions (wxyz) uniform over the rotations, as splatfacto starts its Gaussians. The initial
    scales are isotropic, so no covariance changes, but the seed then sets where each Gaussian's optimisation starts:
    an ensemble's members on a scene with SfM points began from identical models (REFERENCE §5 has them differ in
    initialisation too)."""
    quats = torch.randn(n, 4, generator=generator)
    return quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def identity_rotations(n: int) -> Tensor:
    """(n, 4) identity quaternions (wxyz), as the original 3DGS starts its Gaussians."""
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1.0
    return quats


def initial_u_sh(n: int, cfg: ModelConfig, heads: int) -> Tensor:
    """(n, Ku, heads) uncertainty SH that is sigmoid(u_init_logit) in every direction."""
    u_sh = torch.zeros(n, num_sh_bases(cfg.u_sh_degree), heads)
    u_sh[:, 0, :] = cfg.u_init_logit / C0
    return u_sh
