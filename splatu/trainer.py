"""The training loop: splatfacto-style 3DGS with the uncertainty SH learned in the same step.

One step renders one training camera (shuffled order, resolution schedule, random background;
images with alpha are composited on that same background), adds the photometric loss and the
uncertainty loss computed from the *same* render's contributions, and does one backward. A step
whose loss or gradients are non-finite is skipped (no optimizer step, no density statistics), so a
bad value never reaches the model.

Entry points: `train(config)` (the CLI and the Python API; handles --resume, of a single run or of a
whole ensemble, and --ensemble) and
`train_run(config, scene, run_dir)` for callers that already hold a scene.
"""

from __future__ import annotations

import dataclasses
import json
import math
import random
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from splatu.allocator import keep_freed_memory
from splatu.atomic import atomic_write_text
from splatu.camera import Camera
from splatu.checkpoint import (
    RESUME_KEYS,
    capture_rng,
    checkpoint_step,
    list_checkpoints,
    model_from_state,
    read_checkpoint,
    resolve_checkpoint,
    restore_rng,
    run_dir_of,
    save_checkpoint,
    saved_frame,
)
from splatu.data.resolve import load_scene
from splatu.data.scene import Scene, Views, on_background
from splatu.degree_choice import (
    apply_choice,
    decision_step,
    held_out_block,
    score_degrees,
    split_for_choice,
    training_views,
    with_choice_heads,
)
from splatu.densify import DensityController
from splatu.errors import SplatuError
from splatu.losses import photometric_loss, psnr, ssim, uncertainty_heads, uncertainty_loss
from splatu.model import GaussianModel
from splatu.optim import Optimizers
from splatu.ply import save_ply
from splatu.rasterizer.kernels import set_compile
from splatu.run_dir import new_run_dir, point_latest
from splatu.train_config import TrainConfig, eval_background, from_dict, load_config, save_config, to_dict
from splatu.world_frame import WorldTransform, require_same_frame, scene_frame

console = Console(stderr=True)
UNCERTAINTY_SEED_OFFSET = 7_919
"""Offsets the uncertainty loss's seed from the geometry's, so the two streams differ."""


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
    """Time spent in steps, summed over sessions (resumes)."""
    wall_start: float = dataclasses.field(default_factory=time.perf_counter)
    """perf_counter origin of the run's wall time; on resume, moved back by the earlier sessions' wall time."""


StepHook = Callable[[int, TrainState], None]
"""Called after every completed step with the number of completed steps (tests, callers)."""


@dataclass
class StepOutcome:
    loss: float
    uncertainty_loss: float
    psnr: float
    skipped: str | None
    """Why the step was skipped (which value was non-finite), or None."""
    refined: dict[str, int]


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM: the run was saved (when it stopped between steps) and can be resumed."""

    def __init__(self, what: str, run_dir: Path, step: int) -> None:
        self.message = f"{what}; resume with `splatu train --resume {run_dir}`"
        super().__init__(self.message)
        self.what = what
        self.run_dir = run_dir
        self.step = step


# --- pure schedule helpers -------------------------------------------------------------------

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
    downsampled with the colour, which keeps that exact. The scene's mask files (`Views.valid`)
    are downsampled alike and weight the loss (`weight`).
    """

    def __init__(self, views: Views) -> None:
        self.views = views
        self._levels: dict[int, torch.Tensor] = {}

    def __len__(self) -> int:
        return len(self.views)

    def _level(self, level: int) -> torch.Tensor:
        """(N, h, w, 3 + a + v): colour, then alpha when the views have one, then the valid-pixel mask.

        Colour is averaged over valid pixels only (downsampled premultiplied by the mask, then divided by
        the downsampled mask), so what a mask excludes never reaches the loss, at any level.
        """
        if level not in self._levels:
            colour, valid = self.views.images, self.views.valid
            if valid is not None:
                colour = colour * valid.unsqueeze(-1)
            extras = [t.unsqueeze(-1) for t in (self.views.alphas, valid) if t is not None]
            images = torch.cat([colour, *extras], dim=-1)
            if level > 0:
                probe = self.views.cameras[0].scaled(0.5**level)
                size = (probe.height, probe.width)
                images = F.interpolate(images.permute(0, 3, 1, 2), size=size, mode="area").permute(0, 2, 3, 1)
            if valid is not None:
                coverage = images[..., -1:]
                images[..., :3] = torch.where(coverage > 0, images[..., :3] / coverage.clamp_min(1e-12), 0.0)
            self._levels[level] = images.contiguous()
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
        return None if self.views.valid is None else self._level(level)[index, ..., -1]


# --- one step --------------------------------------------------------------------------------

def _nonfinite(loss: torch.Tensor, model: GaussianModel, raster: Any) -> str | None:
    """Name the first non-finite value among the loss, every parameter gradient and the absgrad.

    A tensor's sum is non-finite iff it holds a NaN/Inf (or is large enough to overflow float32,
    which is just as fatal), and one reduction per tensor is cheaper than an elementwise isfinite.
    """
    if not torch.isfinite(loss):
        return "loss"
    named = [(f"gradient of {name}", getattr(model, name).grad) for name in GaussianModel.PARAM_NAMES]
    named.append(("screen-space gradient", getattr(raster, "means2d_absgrad", None)))
    named = [(what, t) for what, t in named if t is not None]
    sums = torch.stack([t.sum() for _, t in named])
    if bool(torch.isfinite(sums).all()):
        return None
    return next(what for (what, _), ok in zip(named, torch.isfinite(sums).tolist(), strict=True) if not ok)


def train_step(state: TrainState, config: TrainConfig, images: TrainImages) -> StepOutcome:
    """Render one camera, one backward for both losses, then optimise and refine (unless non-finite)."""
    step = state.step
    background = training_background(config.train_background, state.generator)
    level = resolution_level(step, config.resolution_levels, config.resolution_interval)
    index = camera_index(step, len(images), config.seed)
    camera, target = images.get(index, level, background)
    weight = images.weight(index, level)
    degree = active_sh_degree(step, config.model.sh_degree, config.model.sh_degree_interval)

    render = state.model.render(camera, degree, background)
    rgb = render.rgb
    if weight is not None:  # masked pixels: both images are 0 there, as nerfstudio's splatfacto does
        rgb, target = rgb * weight[..., None], target * weight[..., None]
    loss = photometric_loss(rgb, target, config.ssim_lambda)
    u_loss = torch.zeros(())
    if not config.uncertainty.off:
        u_loss = uncertainty_loss(state.model, camera.center(), render.raster, config.uncertainty,
                                  state.uncertainty_generators)
        loss = loss + u_loss  # already scaled by --uncertainty.weight; it reaches only u_sh
    loss.backward()

    bad = _nonfinite(loss.detach(), state.model, render.raster)
    train_psnr = psnr(rgb.detach(), target) if bad is None else float("nan")
    refined: dict[str, int] = {}
    if bad is None:
        state.density.observe(render.raster, camera.width, camera.height)
        state.optimizers.step(step)
    state.optimizers.zero_grad()
    if bad is None:
        refined = {k: v for k, v in state.density.refine(step, state.model, state.optimizers).items() if v}
    return StepOutcome(float(loss.detach()), float(u_loss.detach()), train_psnr, bad, refined)


# --- evaluation ------------------------------------------------------------------------------

@torch.no_grad()
def evaluate_views(model: GaussianModel, views: Views, sh_degree: int, background: torch.Tensor) -> dict[str, float]:
    """Mean per-image PSNR and SSIM; with ground-truth `observed` masks also PSNR on observed pixels.

    Images with alpha are scored on `background` too, so render and target share one background. Pixels
    the scene's mask files exclude are left out of PSNR and are 0 in both images for SSIM, as in training.
    """
    psnrs, ssims, observed = [], [], []
    for i, camera in enumerate(views.cameras):
        rgb = model.render(camera, sh_degree, background).rgb.clamp(0, 1)
        gt = views.images[i]
        if views.alphas is not None:
            gt = on_background(gt, views.alphas[i], views.alpha_background, background)
        if views.valid is not None:
            if not bool((views.valid[i] > 0).any()):
                continue  # a view its mask file excludes entirely has nothing to score
            rgb, gt = rgb * views.valid[i][..., None], gt * views.valid[i][..., None]
        psnrs.append(psnr(rgb, gt, mask=None if views.valid is None else views.valid[i] > 0))
        ssims.append(float(ssim(rgb, gt)))
        if views.observed is not None and bool(views.observed[i].any()):
            observed.append(psnr(rgb, gt, mask=views.observed[i]))
    metrics = {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims)), "num_images": len(psnrs)}
    if observed:
        metrics["psnr_observed"] = float(np.mean(observed))
    return metrics


def evaluate_scene(model: GaussianModel, scene: Scene, config: TrainConfig) -> dict[str, dict[str, float]]:
    """Every held-out set: the eval split plus the scene's extra sets (e.g. interp)."""
    sets = {"eval": scene.eval, **scene.extra_eval}
    return {name: evaluate_views(model, views, config.model.sh_degree, eval_background(config))
            for name, views in sets.items()}


# --- run bookkeeping -------------------------------------------------------------------------

class MetricsLog:
    """metrics.jsonl: one JSON object per line, appended and flushed as training goes."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def write(self, record: dict[str, Any]) -> None:
        with self.path.open("a") as f:
            f.write(json.dumps(record) + "\n")

    def drop_after(self, step: int) -> list[str]:
        """On resume: forget the lines logged after the checkpoint (they are about to be redone) and a line
        torn by a killed process; return the dropped whole lines. Rewritten atomically: a crash here keeps
        the old log."""
        if not self.path.is_file():
            return []
        kept, dropped = [], []
        for line in self.path.read_text().splitlines():
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue  # empty, or half a line: the process died while appending it
            (kept if record.get("step", 0) <= step else dropped).append(line)
        atomic_write_text(self.path, "".join(ln + "\n" for ln in kept))
        return dropped


ABANDONED_DIR = "abandoned"


def set_aside_later_work(run_dir: Path, step: int) -> Path | None:
    """Resuming from a checkpoint older than the run's newest abandons what came after it. Move the later
    checkpoints, their metrics lines, and a finished run's summary.json and splat.ply into
    abandoned/<time>/: nothing trained is lost, and `--resume RUN`, `render-uncertainty` and `eval-ause`,
    which take the newest checkpoint, never pick up the abandoned branch. Returns that folder, or None."""
    later = [path for path in list_checkpoints(run_dir) if checkpoint_step(path) > step]
    if not later:
        return None
    folder = run_dir / ABANDONED_DIR / time.strftime("%Y-%m-%d_%H%M%S")
    folder.mkdir(parents=True, exist_ok=True)
    dropped = MetricsLog(run_dir / "metrics.jsonl").drop_after(step)
    atomic_write_text(folder / "metrics.jsonl", "".join(ln + "\n" for ln in dropped))
    for path in [*later, run_dir / "summary.json", run_dir / "splat.ply"]:
        if path.is_file():
            path.replace(folder / path.name)
    return folder


def _checkpoint_state(state: TrainState, config: TrainConfig) -> dict[str, Any]:
    return {
        "config": to_dict(dataclasses.replace(config, resume=None)),
        "model": state.model.state_dict(),
        "num_gaussians": len(state.model),
        "optimizers": state.optimizers.state_dict(),
        "density": state.density.state_dict(),
        "rng": capture_rng(state.generator),
        "uncertainty_rng": [g.get_state() for g in state.uncertainty_generators],
        "scene_extent": state.scene_extent,
        "world_transform": state.to_world.state_dict(),
        "nonfinite_streak": state.nonfinite_streak,
        "train_seconds": state.train_seconds,
        "wall_seconds": time.perf_counter() - state.wall_start,
    }


def seed_everything(seed: int) -> torch.Generator:
    """Seed torch, numpy and random; return the trainer's own generator."""
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    random.seed(seed)
    return torch.Generator().manual_seed(seed)


def fresh_state(config: TrainConfig, scene: Scene) -> TrainState:
    generator = seed_everything(config.seed)
    extent = scene_extent(scene.train.cameras)
    heads = uncertainty_heads(config.uncertainty, config.model.u_sh_degree)  # validates each head's degree
    model = GaussianModel.from_points(scene.points, scene.point_colors, config.model, generator, len(heads))
    optimizers = Optimizers(model, config.optim, extent, config.steps)
    density = DensityController(config.densify, extent, generator)
    return TrainState(model, optimizers, density, generator, uncertainty_generators(config.seed, len(heads)),
                      extent, scene_frame(scene))


def uncertainty_generators(seed: int, heads: int) -> list[torch.Generator]:
    """One identically seeded stream per uncertainty head: a head draws exactly what a run of its own would."""
    return [torch.Generator().manual_seed(seed + UNCERTAINTY_SEED_OFFSET) for _ in range(heads)]


def restored_state(checkpoint: dict[str, Any], config: TrainConfig, scene: Scene) -> TrainState:
    """The checkpointed state; refuses a scene whose normalisation moved (its cameras would not fit the model)."""
    to_world = scene_frame(scene)
    require_same_frame(saved_frame(checkpoint), to_world, f"in {config.data.data}",
                       "resume with the scene as it was, or start a new run")
    model = model_from_state(checkpoint, config)
    extent = float(checkpoint["scene_extent"])
    optimizers = Optimizers(model, config.optim, extent, config.steps)
    optimizers.load_state_dict(checkpoint["optimizers"])
    generator = torch.Generator()
    restore_rng(checkpoint["rng"], generator)
    density = DensityController(config.densify, extent, generator)
    density.load_state_dict(checkpoint["density"])
    u_generators = uncertainty_generators(config.seed, model.u_sh.shape[-1])
    for u_generator, saved_state in zip(u_generators, checkpoint.get("uncertainty_rng", []), strict=False):
        u_generator.set_state(saved_state)  # absent in checkpoints written before L_u had its own streams
    return TrainState(model, optimizers, density, generator, u_generators, extent, to_world,
                      step=int(checkpoint["step"]),
                      nonfinite_streak=int(checkpoint["nonfinite_streak"]),
                      train_seconds=float(checkpoint["train_seconds"]))


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""Ctrl-C, and `kill` or a batch scheduler's time limit: both finish the step and save."""


@contextmanager
def deferred_interrupt() -> Iterator[dict[str, bool]]:
    """First Ctrl-C (or SIGTERM): finish the current step, then stop cleanly; a second one aborts at once."""
    flag = {"requested": False}
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def handler(signum: int, frame: Any) -> None:
        if flag["requested"]:
            raise KeyboardInterrupt
        flag["requested"] = True

    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield flag
    finally:
        for sig, before in previous.items():
            if before is not None:  # None: a handler set outside Python, which cannot be put back from here
                signal.signal(sig, before)


@contextmanager
def sigterm_as_ctrl_c() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt for a whole command, as Ctrl-C does: outside the steps too (loading the
    scene, between ensemble members), a kill then unwinds through the code that records a session."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        yield
    finally:
        if before is not None:
            signal.signal(signal.SIGTERM, before)


PLAIN_PROGRESS_LINES = 20
"""Off a terminal a live bar draws nothing useful until the run ends (or writes cursor codes into the log, when
FORCE_COLOR is set), so plain progress lines replace it there, every 1/20 of the run and at the last step."""


def _progress(enabled: bool) -> Progress:
    return Progress(
        TextColumn("step {task.completed:>6.0f}/{task.total:.0f}"),
        BarColumn(),
        TextColumn("loss {task.fields[loss]:.4f}  PSNR {task.fields[psnr]:5.2f}  #G {task.fields[gaussians]:>7}"
                   "  {task.fields[rate]:5.2f} it/s"),
        TimeRemainingColumn(),
        console=console,
        disable=not enabled,
    )


# --- the loop --------------------------------------------------------------------------------

def run_loop(state: TrainState, config: TrainConfig, scene: Scene, run_dir: Path,
             hooks: Sequence[StepHook] = ()) -> tuple[TrainState, TrainConfig]:
    """Train from `state.step` to `config.steps`, with checkpoints, evaluation and Ctrl-C / SIGTERM handling.

    Returns the config too: choosing the SH degrees mid-run (`--degree-choice.on`) changes it.
    """
    images = TrainImages(training_views(scene.train, config, state.step))
    log = MetricsLog(run_dir / "metrics.jsonl")
    log.drop_after(state.step)
    smoothed_psnr = float("nan")
    session_start, session_steps = time.perf_counter(), 0
    on_terminal = console.file.isatty()  # not console.is_terminal, which FORCE_COLOR (set by some CI) fakes
    plain_every = math.ceil(config.steps / PLAIN_PROGRESS_LINES) if config.progress and not on_terminal else 0
    with _progress(config.progress and on_terminal) as progress, deferred_interrupt() as interrupt:
        task = progress.add_task("train", total=config.steps, completed=state.step, loss=0.0, psnr=0.0,
                                 gaussians=len(state.model), rate=0.0)
        in_step = False
        try:
            while state.step < config.steps:
                in_step = True  # from here until the step is counted, a stop cannot save a consistent state
                if config.degree_choice.on and state.step == decision_step(config.degree_choice, config.steps):
                    config = choose_degrees(state, config, scene, log, run_dir)
                    images = TrainImages(scene.train)
                started = time.perf_counter()
                outcome = train_step(state, config, images)
                state.step += 1
                state.train_seconds += time.perf_counter() - started
                in_step = False
                session_steps += 1
                _account(state, config, outcome, log, run_dir)
                if outcome.skipped is None:
                    smoothed_psnr = (outcome.psnr if math.isnan(smoothed_psnr)
                                     else 0.9 * smoothed_psnr + 0.1 * outcome.psnr)
                rate = session_steps / max(time.perf_counter() - session_start, 1e-9)
                progress.update(task, completed=state.step, loss=outcome.loss, psnr=smoothed_psnr,
                                gaussians=len(state.model), rate=rate)
                if plain_every and (state.step % plain_every == 0 or state.step == config.steps):
                    console.print(progress_line(state.step, config.steps, outcome.loss, smoothed_psnr,
                                                len(state.model), rate), highlight=False, soft_wrap=True)
                if (config.eval_every_steps and state.step % config.eval_every_steps == 0 and state.step < config.steps
                        and not interrupt["requested"]):  # a stop request must not wait for a whole evaluation
                    _log_eval(state, config, scene, log)
                if config.checkpoint_every and state.step % config.checkpoint_every == 0:
                    save_checkpoint(run_dir, state.step, _checkpoint_state(state, config))
                for hook in hooks:
                    hook(state.step, state)
                if interrupt["requested"]:
                    raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise _interrupted(state, config, run_dir, mid_step=in_step) from None
    return state, config


DEGREE_CHOICE_FILE = "degree_choice.json"


def choose_degrees(state: TrainState, config: TrainConfig, scene: Scene, log: MetricsLog,
                   run_dir: Path) -> TrainConfig:
    """Score the SH degrees on the held-out block, keep the chosen ones (see splatu.degree_choice), record why.

    It runs before step `decision_step + 1`, so the checkpoint at the decision step is the model before the
    choice, and a run interrupted during it resumes by choosing again. Its time counts as training time.
    """
    started = time.perf_counter()
    fitted_on, held_out = split_for_choice(scene.train, config.degree_choice.held_out)
    scores = score_degrees(state.model, held_out, fitted_on, config, eval_background(config))
    config, state.uncertainty_generators = apply_choice(state.model, state.optimizers,
                                                        state.uncertainty_generators, config, scores)
    choice = scores.record
    seconds = time.perf_counter() - started
    state.train_seconds += seconds
    record = {"step": state.step, "event": "degree_choice", **choice, "seconds": seconds}
    log.write(record)
    atomic_write_text(run_dir / DEGREE_CHOICE_FILE, json.dumps(record, indent=2))
    save_config(config, run_dir / "config.yml")
    u_part = f", u-SH degree {choice['u_sh_degree']}" if "u_sh_degree" in choice else ""
    console.print(f"step {state.step}: chose colour SH degree {choice['sh_degree']}{u_part} "
                  f"on {len(choice['held_out_views'])} held-out views (scores in {run_dir / DEGREE_CHOICE_FILE})",
                  soft_wrap=True)
    return config


def _account(state: TrainState, config: TrainConfig, outcome: StepOutcome, log: MetricsLog, run_dir: Path) -> None:
    """Log the step; count non-finite steps in a row and stop after too many."""
    if outcome.skipped is not None:
        state.nonfinite_streak += 1
        log.write({"step": state.step, "event": "nonfinite_skipped", "what": outcome.skipped})
        print(f"step {state.step}: non-finite {outcome.skipped}, step skipped", file=sys.stderr)
        if state.nonfinite_streak >= config.max_nonfinite_steps:
            found = list_checkpoints(run_dir)
            last = f"the last good checkpoint is {found[-1]}" if found else "no checkpoint was written yet"
            raise SplatuError(
                f"training stopped: {state.nonfinite_streak} steps in a row had a non-finite value "
                f"(last: {outcome.skipped} at step {state.step})",
                f"in {run_dir}",
                f"{last}; check the input data or retrain with lower learning rates",
            )
        return
    state.nonfinite_streak = 0
    if outcome.refined or state.step % config.log_every == 0:
        log.write({"step": state.step, "event": "train", "loss": outcome.loss,
                   "uncertainty_loss": outcome.uncertainty_loss, "psnr": outcome.psnr,
                   "num_gaussians": len(state.model), "train_seconds": state.train_seconds,
                   **({"refined": outcome.refined} if outcome.refined else {})})


def _log_eval(state: TrainState, config: TrainConfig, scene: Scene, log: MetricsLog) -> dict[str, dict[str, float]]:
    results = evaluate_scene(state.model, scene, config)
    for name, metrics in results.items():
        log.write({"step": state.step, "event": "eval", "set": name, **metrics})
        console.print(eval_line(state.step, name, metrics), highlight=False, soft_wrap=True)
    return results


def eval_line(step: int, name: str, metrics: dict[str, float]) -> str:
    """One console line per evaluated set: a run's quality on screen and in its log, not only in metrics.jsonl."""
    observed = f", observed pixels {metrics['psnr_observed']:.2f} dB" if "psnr_observed" in metrics else ""
    return (f"step {step} {name} ({metrics['num_images']} views): PSNR {metrics['psnr']:.2f} dB{observed}, "
            f"SSIM {metrics['ssim']:.3f}")


def progress_line(step: int, steps: int, loss: float, psnr: float, gaussians: int, rate: float) -> str:
    """The progress bar's figures as one plain line, for output that is not a terminal (a log file, CI), where
    rich draws no bar until the end."""
    left = round((steps - step) / rate) if rate > 0 else None
    eta = "?" if left is None else f"{left // 3600}:{left // 60 % 60:02d}:{left % 60:02d}"
    return (f"step {step:>6}/{steps}  loss {loss:.4f}  PSNR {psnr:5.2f}  #G {gaussians:>7}  {rate:5.2f} it/s"
            f"  ETA {eta}")


def _interrupted(state: TrainState, config: TrainConfig, run_dir: Path, mid_step: bool) -> TrainingInterrupted:
    """Save (only at a step boundary, where the state is consistent) and say how to resume."""
    if mid_step:
        found = list_checkpoints(run_dir)
        where = f"the last checkpoint is {found[-1]}" if found else "no checkpoint was written"
        return TrainingInterrupted(f"aborted during step {state.step + 1}; {where}", run_dir, state.step)
    path = save_checkpoint(run_dir, state.step, _checkpoint_state(state, config))
    return TrainingInterrupted(f"interrupted at step {state.step}, saved {path}", run_dir, state.step)


def finish_run(state: TrainState, config: TrainConfig, scene: Scene, run_dir: Path) -> dict:
    """Final checkpoint, evaluation, PLY export and summary.json."""
    save_checkpoint(run_dir, state.step, _checkpoint_state(state, config))
    results = _log_eval(state, config, scene, MetricsLog(run_dir / "metrics.jsonl"))
    save_ply(state.model, run_dir / "splat.ply", state.to_world)
    summary = {"scene": scene.name, "method": config.method, "preset": config.preset, "steps": state.step,
               "num_gaussians": len(state.model), "sh_degree": config.model.sh_degree,
               "u_sh_degree": config.model.u_sh_degree, "train_seconds": state.train_seconds,
               "wall_seconds": time.perf_counter() - state.wall_start, "eval": results}
    if (run_dir / DEGREE_CHOICE_FILE).is_file():
        summary["degree_choice"] = json.loads((run_dir / DEGREE_CHOICE_FILE).read_text())
    atomic_write_text(run_dir / "summary.json", json.dumps(summary, indent=2))
    return summary


def train_run(config: TrainConfig, scene: Scene, run_dir: Path, hooks: Sequence[StepHook] = (),
              checkpoint: dict[str, Any] | None = None, wall_start: float | None = None) -> dict:
    """Train one model into `run_dir` (fresh, or continuing `checkpoint`); returns the summary."""
    wall_start = time.perf_counter() if wall_start is None else wall_start
    if config.compile_kernels:  # here, so every way in (train, ensemble members, the benchmarks) compiles
        set_compile(True)
    keep_freed_memory()  # likewise: without it the first training of a process page-faults ~20% of its time away
    if checkpoint is None and config.degree_choice.on:
        config = with_choice_heads(config)
    run_dir.mkdir(parents=True, exist_ok=True)
    save_config(config, run_dir / "config.yml")
    state = fresh_state(config, scene) if checkpoint is None else restored_state(checkpoint, config, scene)
    # wall time counts scene loading and every earlier session up to its last checkpoint (older ones lack it)
    state.wall_start = wall_start - (0.0 if checkpoint is None else float(checkpoint.get("wall_seconds", 0.0)))
    state, config = run_loop(state, config, scene, run_dir, hooks)
    return finish_run(state, config, scene, run_dir)


ENSEMBLE_SESSIONS = "ensemble_sessions.json"


def train_member(member: TrainConfig, scene: Scene, member_dir: Path, hooks: Sequence[StepHook] = ()) -> None:
    """Skip a finished member (summary.json written last), continue one from its newest checkpoint, or start it."""
    if (member_dir / "summary.json").is_file():
        console.print(f"already trained: {member_dir}", soft_wrap=True)
        return
    found = list_checkpoints(member_dir)
    if not found:
        train_run(member, scene, member_dir, hooks)
        return
    checkpoint = read_checkpoint(found[-1], RESUME_KEYS)
    train_run(from_dict(checkpoint["config"], str(found[-1])), scene, member_dir, hooks, checkpoint)


def record_session(run_dir: Path, seconds: float) -> list[float]:
    """Append one session's wall time to the run's ensemble_sessions.json; returns every session's."""
    path = run_dir / ENSEMBLE_SESSIONS
    sessions = json.loads(path.read_text())["session_seconds"] if path.is_file() else []
    sessions.append(seconds)
    atomic_write_text(path, json.dumps({"session_seconds": sessions}, indent=2))
    return sessions


def train_ensemble(config: TrainConfig, scene: Scene, run_dir: Path, wall_start: float,
                   hooks: Sequence[StepHook] = ()) -> dict:
    """N members differing only in seed (seed + k), then ensemble.json with their dirs and wall time.

    Calling it again on the same `run_dir` resumes: finished members are skipped, an interrupted one
    continues from its newest checkpoint, one never started starts fresh. `wall_seconds` is honest
    across sessions: every call (session) adds its own wall time, from `wall_start` (the start of
    `train`, so scene loading counts) until it finishes, is interrupted or fails, to
    ensemble_sessions.json, and `wall_seconds` is their sum. A session killed outright (SIGKILL, power
    loss) cannot record itself and is missing from the sum.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    save_config(config, run_dir / "config.yml")
    members = [run_dir / "members" / str(k) for k in range(config.ensemble)]
    try:
        for k, member_dir in enumerate(members):
            member = dataclasses.replace(config, seed=config.seed + k, ensemble=1)
            console.print(f"ensemble member {k + 1}/{config.ensemble} (seed {member.seed})")
            try:
                train_member(member, scene, member_dir, hooks)
            except TrainingInterrupted as stop:  # point the resume hint at the ensemble, not the member
                raise TrainingInterrupted(f"ensemble member {k + 1}/{config.ensemble}: {stop.what}",
                                          run_dir, stop.step) from None
    finally:
        sessions = record_session(run_dir, time.perf_counter() - wall_start)
    record = {"members": [str(m.relative_to(run_dir)) for m in members],
              "seeds": [config.seed + k for k in range(config.ensemble)],
              "wall_seconds": sum(sessions), "session_seconds": sessions}
    atomic_write_text(run_dir / "ensemble.json", json.dumps(record, indent=2))
    return record


def ensemble_config(run_dir: Path) -> TrainConfig | None:
    """The saved config when `run_dir` is an ensemble run directory, else None."""
    path = Path(run_dir).expanduser() / "config.yml"
    if not path.is_file():
        return None
    config = load_config(path)
    return config if config.ensemble > 1 else None


def check_options(config: TrainConfig) -> None:
    """Every option check that needs no scene: a bad option fails in one line before the scene loads (which
    may build the stand-in) and before a run folder is made and `latest` pointed at it."""
    for part in (config.model, config.optim, config.densify, config.degree_choice):
        part.validate()
    uncertainty_heads(config.uncertainty, config.model.u_sh_degree)


def train(config: TrainConfig, hooks: Sequence[StepHook] = ()) -> Path:
    """Train (or resume, a single run or a whole ensemble) as configured; returns the run directory."""
    wall_start = time.perf_counter()
    if config.resume is not None:
        saved_ensemble = ensemble_config(config.resume)
        if saved_ensemble is not None:
            run_dir = Path(config.resume).expanduser()
            train_ensemble(saved_ensemble, load_scene(saved_ensemble.data), run_dir, wall_start, hooks)
            return run_dir
        path = resolve_checkpoint(config.resume)
        checkpoint = read_checkpoint(path, RESUME_KEYS)
        saved = from_dict(checkpoint["config"], str(path))
        run_dir = run_dir_of(path)
        step = int(checkpoint["step"])
        if step >= saved.steps and (run_dir / "summary.json").is_file():
            console.print(f"already finished: {run_dir} trained all {saved.steps} steps; nothing to resume",
                          soft_wrap=True)
            return run_dir
        abandoned = set_aside_later_work(run_dir, step)
        if abandoned is not None:
            console.print(f"resuming from step {step}: the run's later checkpoints and results moved to {abandoned}",
                          soft_wrap=True)
        train_run(saved, load_scene(saved.data), run_dir, hooks, checkpoint, wall_start)
        return run_dir
    if config.degree_choice.on:
        config = with_choice_heads(config)
    check_options(config)
    scene = load_scene(config.data)
    if config.degree_choice.on:
        held_out_block(len(scene.train), config.degree_choice.held_out)  # too few views: fail before the run folder
    run_dir = new_run_dir(config.output_dir, scene.name, config.method)
    point_latest(run_dir)
    if config.ensemble > 1:
        train_ensemble(config, scene, run_dir, wall_start, hooks)
    else:
        train_run(config, scene, run_dir, hooks, wall_start=wall_start)
    return run_dir


def run_command(config: TrainConfig) -> None:
    """`splatu train`: train, print where the run went; Ctrl-C or SIGTERM prints how to resume and exits 130."""
    try:
        with sigterm_as_ctrl_c():
            run_dir = train(config)
    except TrainingInterrupted as stop:
        print(stop.message, file=sys.stderr)  # plain print: one line, never wrapped
        raise SystemExit(130) from None
    print(f"run saved to {run_dir}", file=sys.stderr)
