"""One training step: render one camera, one backward for the photometric and uncertainty losses, then
optimise and refine, unless a value is non-finite.

The camera order, resolution level, colour-SH degree and background are pure functions of the step (and
the seeded generator), so a resumed run takes exactly the steps an uninterrupted one would. A step whose
loss or gradients are non-finite is skipped (no optimizer step, no density statistics), so a bad value
never reaches the model; a refinement due at that step still happens, on the model as it was.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from splatu.camera import Camera
from splatu.data.scene import PerView, ViewList, Views, on_background
from splatu.densify import DensityController
from splatu.losses import photometric_loss, psnr, uncertainty_loss
from splatu.model import GaussianModel, ModelConfig
from splatu.optim import Optimizers
from splatu.rasterizer import RasterOutput
from splatu.train_config import TrainConfig
from splatu.world_frame import WorldTransform


@dataclass
class TrainState:
    """What changes during training; with the config, exactly what a checkpoint stores."""

    model: GaussianModel
    optimizers: Optimizers
    density: DensityController
    generator: torch.Generator
    """Backgrounds, density control and init: everything that shapes the geometry."""
    uncertainty_generators: list[torch.Generator]
    """The uncertainty loss's own draws (`mean`'s directions), one stream per head, so that L_u never shifts the
    geometry's stream and each head draws what it would draw in a run of its own."""
    scene_extent: float
    to_world: WorldTransform
    """The scene's normalised → original frame; fixed, stored so exports land in the data's frame."""
    step: int = 0
    """Completed steps."""
    nonfinite_streak: int = 0
    train_seconds: float = 0.0
    """Time spent in steps, summed over sessions (resumes), without the compiles of the rasterizer's kernels."""
    train_compile_seconds: float | None = 0.0
    """The time those steps spent compiling the kernels (mostly each session's first step); None when resumed from
    a checkpoint written before it was recorded, or once the compile clock stopped (`kernels.compile_seconds`):
    train_seconds then includes every compile, as it goes on doing."""
    wall_start: float = dataclasses.field(default_factory=time.perf_counter)
    """perf_counter origin of the run's wall time; on resume, moved back by the earlier sessions' wall time."""


StepHook = Callable[[int, TrainState], None]
"""Called after every completed step with the number of completed steps (tests, callers)."""


@dataclass
class StepOutcome:
    loss: float
    """The step's total, photometric + uncertainty (metrics.jsonl's `loss`)."""
    photometric_loss: float
    """0.8·L1 + 0.2·(1 − SSIM) alone, what the progress displays show: splatfacto's loss, comparable to it."""
    uncertainty_loss: float
    psnr: float
    skipped: str | None
    """Why the step was skipped (which value was non-finite), or None."""
    refined: dict[str, int]


def camera_index(step: int, num_cameras: int, seed: int) -> int:
    """Shuffled order, a new permutation per epoch; a pure function of the step, so resume is exact."""
    epoch, position = divmod(step, num_cameras)
    order = torch.randperm(num_cameras, generator=torch.Generator().manual_seed(seed * 1_000_003 + epoch))
    return int(order[position])


def resolution_level(step: int, levels: int, interval: int) -> int:
    """k in the 1/2^k resolution schedule: k = max(levels - step // interval, 0)."""
    return max(levels - step // interval, 0)


def active_sh_degree(step: int, max_degree: int, interval: int) -> int:
    return min(step // interval, max_degree)


def trained_sh_degree(steps: int, model: ModelConfig) -> int:
    """The colour SH degree a model is after `steps` completed steps: that of its last step (0 before any). The
    bands above it never had a gradient and are still 0, so the configured degree is only the schedule's cap."""
    return active_sh_degree(max(steps - 1, 0), model.sh_degree, model.sh_degree_interval)


def scene_extent(cameras: Sequence[Camera]) -> float:
    """3DGS's scene radius: 1.1 × the largest camera distance from the mean camera centre."""
    centers = torch.stack([c.center() for c in cameras])
    radius = float((centers - centers.mean(0)).norm(dim=-1).max())
    return 1.1 * radius if radius > 0 else 1.0


def training_background(kind: str, generator: torch.Generator) -> torch.Tensor:
    """Random backgrounds stop the model from painting the background colour into empty space."""
    if kind == "random":
        return torch.rand(3, generator=generator)
    return torch.full((3,), 1.0 if kind == "white" else 0.0)


class TrainImages:
    """Training views at every resolution level, downsampled once (area averaging) and cached.

    Images with alpha (`Views.alphas`) are recomposited on the background the step renders on,
    so empty space is asked to be exactly the render's background (as nerfstudio does); alpha is
    downsampled with the colour, which keeps that exact. The scene's mask files (`Views.mask_files`)
    are downsampled alike and weight the loss (`weight`). Views of one size are downsampled as one stack; views
    that differ in size (a `ViewList`) one by one, each to its own camera's size at the level.
    """

    def __init__(self, views: Views) -> None:
        self.views = views
        self._levels: dict[int, PerView] = {}

    def __len__(self) -> int:
        return len(self.views)

    def _level(self, level: int) -> PerView:
        """(h, w, 3 + a + v) per view: colour, then alpha when the views have one, then the valid-pixel mask."""
        if level not in self._levels:
            views = self.views
            if isinstance(views.images, ViewList):
                self._levels[level] = ViewList([_downsampled(views.subset([i]), level)[0] for i in range(len(views))])
            else:
                self._levels[level] = _downsampled(views, level)
        return self._levels[level]

    def get(self, index: int, level: int, background: torch.Tensor | None = None) -> tuple[Camera, torch.Tensor]:
        """Camera and target image of view `index` at 1/2^level resolution, on `background` (None: as loaded)."""
        camera = self.views.cameras[index]
        camera = camera.scaled(0.5**level) if level > 0 else camera
        pixels = self._level(level)[index]
        if background is None or self.views.alphas is None:
            return camera, pixels[..., :3]
        return camera, on_background(pixels[..., :3], pixels[..., 3], self.views.alpha_background, background)

    def weight(self, index: int, level: int) -> torch.Tensor | None:
        """(h, w) weight in [0, 1] of each pixel in the loss, from the scene's mask files; None without them."""
        return None if self.views.mask_files is None else self._level(level)[index][..., -1]


def _downsampled(views: Views, level: int) -> torch.Tensor:
    """(N, h, w, 3 + a + v) of views that share one size (stacked tensors) at 1/2^level resolution: colour, then
    alpha when the views have one, then the valid-pixel mask.

    Colour is averaged over valid pixels only (downsampled premultiplied by the mask, then divided by
    the downsampled mask), so what a mask excludes never reaches the loss, at any level.
    """
    colour, valid = views.images, views.mask_files
    if valid is not None:
        colour = colour * valid.unsqueeze(-1)
    extras = [t.unsqueeze(-1) for t in (views.alphas, valid) if t is not None]
    images = torch.cat([colour, *extras], dim=-1) if extras else colour  # no copy of a plain image set
    if level > 0:
        probe = views.cameras[0].scaled(0.5**level)
        size = (probe.height, probe.width)
        images = F.interpolate(images.permute(0, 3, 1, 2), size=size, mode="area").permute(0, 2, 3, 1)
    if valid is not None:
        coverage = images[..., -1:]
        images[..., :3] = torch.where(coverage > 0, images[..., :3] / coverage.clamp_min(1e-12), 0.0)
    return images.contiguous()


# --- one step --------------------------------------------------------------------------------

def _first_nonfinite(named: list[tuple[str, torch.Tensor]]) -> str | None:
    """The name of the first tensor holding a NaN/Inf, or None.

    A tensor's sum is non-finite iff it holds a NaN/Inf (or is large enough to overflow float32,
    which is just as fatal), and one reduction per tensor is cheaper than an elementwise isfinite.
    """
    finite = torch.isfinite(torch.stack([t.sum() for _, t in named]))
    if bool(finite.all()):
        return None
    return next(what for (what, _), ok in zip(named, finite.tolist(), strict=True) if not ok)


def _nonfinite(loss: torch.Tensor, model: GaussianModel, raster: RasterOutput) -> str | None:
    """Name the first non-finite value among the loss, every parameter gradient and the absgrad."""
    if not torch.isfinite(loss):
        return "loss"
    named = [(f"gradient of {name}", getattr(model, name).grad) for name in GaussianModel.PARAM_NAMES]
    named.append(("screen-space gradient", raster.means2d_absgrad))
    return _first_nonfinite([(what, t) for what, t in named if t is not None])


class NonFiniteUpdate(Exception):
    """A step's update, or the refinement after it, made a parameter non-finite (finite gradients, but a learning rate
    far too large, or a split of a Gaussian whose log-scale it sent to 1e4): once applied it cannot be skipped, so
    training stops before anything saves the model."""

    def __init__(self, parameter: str, by: str) -> None:
        super().__init__(parameter, by)
        self.parameter, self.by = parameter, by


def _refuse_nonfinite(model: GaussianModel, by: str) -> None:
    """Raise `NonFiniteUpdate` naming the parameter `by` (the update, the refinement) made non-finite: about 0.07 ms
    for 18k Gaussians, against a step of about 85 ms."""
    corrupted = _first_nonfinite([(name, getattr(model, name).detach()) for name in GaussianModel.PARAM_NAMES])
    if corrupted is not None:
        raise NonFiniteUpdate(corrupted, by)


def train_step(state: TrainState, config: TrainConfig, images: TrainImages) -> StepOutcome:
    """Render one camera, one backward for both losses, then optimise (unless non-finite) and refine."""
    step = state.step
    background = training_background(config.train_background, state.generator)
    level = resolution_level(step, config.resolution_levels, config.resolution_interval)
    index = camera_index(step, len(images), config.seed)
    camera, target = images.get(index, level, background)
    weight = images.weight(index, level)
    degree = active_sh_degree(step, config.model.sh_degree, config.model.sh_degree_interval)

    # what a Gaussian shows only on masked pixels is neither trained nor "seen" (uncertainty loss, pruning)
    render = state.model.render(camera, degree, background, contribution_mask=None if weight is None else weight > 0)
    rgb = render.rgb
    if weight is not None:  # masked pixels: both images are 0 there, as nerfstudio's splatfacto does
        rgb, target = rgb * weight[..., None], target * weight[..., None]
    photometric = photometric_loss(rgb, target, config.ssim_lambda)
    loss, u_loss = photometric, torch.zeros(())
    if not config.uncertainty.off:
        u_loss = uncertainty_loss(state.model, camera.center(), render.raster, config.uncertainty,
                                  state.uncertainty_generators)
        loss = photometric + u_loss  # already scaled by --uncertainty.weight; it reaches only u_sh
    loss.backward()

    bad = _nonfinite(loss.detach(), state.model, render.raster)
    train_psnr = psnr(rgb.detach(), target) if bad is None else float("nan")
    if bad is None:
        state.density.observe(render.raster, camera.width, camera.height)
        state.optimizers.step(step)
        _refuse_nonfinite(state.model, "update")
    state.optimizers.zero_grad()
    # a skipped step left the model as it was, so its refinement (or opacity reset) still falls on schedule
    changes = state.density.refine(step, state.model, state.optimizers, views_per_epoch=len(images))
    refined = {k: v for k, v in changes.items() if v}
    if refined:
        _refuse_nonfinite(state.model, "refinement")
    return StepOutcome(float(loss.detach()), float(photometric.detach()), float(u_loss.detach()), train_psnr,
                       bad, refined)
