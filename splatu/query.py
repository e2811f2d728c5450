"""Ask a trained run how sure it is of a view you choose: the Python entry point for next-best-view planning.

`open_run(path).render(world_to_camera, K, width, height)` renders a candidate camera given in the data's own
frame (the frame of the scene's poses and of the run's splat.ply, OpenCV axes), without reading the scene's
images. The model lives in the normalised frame it was trained in; the camera is moved there rather than the
model moved out, so the render is exactly what `splatu render-uncertainty` computes for that view.
"""

from __future__ import annotations

from dataclasses import dataclass
from numbers import Integral
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from splatu.camera import Camera
from splatu.checkpoint import load_run
from splatu.data.frames import ROTATION_TOLERANCE, refuse_implausible_focal
from splatu.errors import SplatuError
from splatu.model import GaussianModel
from splatu.train_config import TrainConfig, eval_background
from splatu.world_frame import WorldTransform, normalised_world_to_camera


@dataclass(frozen=True)
class ViewUncertainty:
    """One rendered candidate view; depth is in the data's units, uncertainty in [0, 1] (1 where nothing is seen)."""

    rgb: np.ndarray  # (H, W, 3)
    depth: np.ndarray  # (H, W), expected depth Σ w·z (0 where nothing is seen)
    alpha: np.ndarray  # (H, W)
    uncertainty: np.ndarray  # (H, W)

    @property
    def mean_uncertainty(self) -> float:
        """The view's mean U: what a planner ranks candidate views by (empty space counts as unknown, U = 1)."""
        return float(self.uncertainty.mean())


@dataclass(frozen=True)
class RunQuery:
    """A trained run, ready to render candidate views in the data's frame."""

    config: TrainConfig
    model: GaussianModel
    frame: WorldTransform

    @torch.no_grad()
    def render(self, world_to_camera: np.ndarray | Tensor, K: np.ndarray | Tensor, width: int,
               height: int) -> ViewUncertainty:
        """Render a camera: world-to-camera (4, 4) in the data's frame with OpenCV axes (x right, y down, z
        forward), pinhole intrinsics K (3, 3) in pixels, and the image size."""
        w2c, intrinsics, width, height = _checked_camera(world_to_camera, K, width, height)
        camera = Camera(intrinsics, normalised_world_to_camera(w2c, self.frame), width, height)
        out = self.model.render(camera, self.config.model.sh_degree, eval_background(self.config),
                                with_uncertainty=True)
        assert out.uncertainty is not None  # with_uncertainty=True
        return ViewUncertainty(out.rgb.numpy(), (out.depth.double() * self.frame.scale).numpy(), out.alpha.numpy(),
                               out.uncertainty.numpy())


def open_run(path: str | Path, head: str | None = None) -> RunQuery:
    """A single run's folder (or one of its checkpoints), optionally as one of its extra uncertainty heads."""
    run = load_run(Path(path).expanduser(), head)
    if run.config.uncertainty.off:
        raise SplatuError("this run was trained without the uncertainty loss, so it has no uncertainty to render",
                          f"in {path}", "open a run trained with `splatu train --method splatu`")
    if run.frame is None:
        raise SplatuError("this run's checkpoint predates the record of its data frame, so a camera in the data's "
                          "frame cannot be placed", f"in {path}", "train the run again with this version")
    return RunQuery(run.config, run.model, run.frame)


def _checked_camera(world_to_camera: np.ndarray | Tensor, K: np.ndarray | Tensor, width: int,
                    height: int) -> tuple[Tensor, Tensor, int, int]:
    """The camera as float64 tensors and int sizes, or one clear error: a wrong shape, a non-finite entry, a pose
    that is not a rigid motion, or a bad size would otherwise render a wrong or blank image without a word."""
    w2c = torch.as_tensor(np.asarray(world_to_camera, dtype=np.float64))
    intrinsics = torch.as_tensor(np.asarray(K, dtype=np.float64))
    if w2c.shape != (4, 4) or intrinsics.shape != (3, 3):
        raise SplatuError(f"a camera needs world_to_camera (4, 4) and K (3, 3), got {tuple(w2c.shape)} and "
                          f"{tuple(intrinsics.shape)}", "in RunQuery.render", "pass the matrices in those shapes")
    if not (w2c.isfinite().all() and intrinsics.isfinite().all()):
        raise SplatuError("the camera holds NaN or Inf", "in RunQuery.render", "pass a finite pose and K")
    rotation = w2c[:3, :3]
    # as loose as the loaders (a pose from a file, rounded to a few decimals or stored in float32, trains there)
    rigid = (float((rotation @ rotation.T - torch.eye(3, dtype=torch.float64)).abs().max()) <= ROTATION_TOLERANCE
             and float(torch.linalg.det(rotation)) > 0
             and torch.equal(w2c[3], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)))
    if not rigid:
        raise SplatuError("world_to_camera is not a rigid motion (its 3×3 block must be a rotation, its last row "
                          "0 0 0 1)", "in RunQuery.render", "pass an OpenCV world-to-camera pose without scale")
    sizes = (width, height)  # any whole number (np.int64 from an array of sizes), but not a bool (True is 1)
    if not all(isinstance(n, Integral) and not isinstance(n, bool) and n > 0 for n in sizes):
        raise SplatuError(f"the image size must be positive integers, got {width}×{height}", "in RunQuery.render",
                          "pass width and height in pixels")
    fix = "pass K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels of this image size"
    if not (intrinsics[0, 0] > 0 and intrinsics[1, 1] > 0):
        raise SplatuError("K's focal lengths must be positive", "in RunQuery.render", fix)
    width, height = int(width), int(height)
    refuse_implausible_focal(intrinsics.numpy(), width, height, "in RunQuery.render", fix)
    # the rasterizer reads fx, fy, cx and cy alone, so any other entry would be dropped without a word
    if float((intrinsics[2] - torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)).abs().max()) > 1e-9:
        raise SplatuError(f"K's last row is {intrinsics[2].tolist()}, not [0, 0, 1]", "in RunQuery.render",
                          f"{fix} (for another image size, scale K's first two rows only)")
    if max(abs(float(intrinsics[0, 1])), abs(float(intrinsics[1, 0]))) > 1e-9 * float(intrinsics[:2, :2].abs().max()):
        raise SplatuError(f"K has a skew ({float(intrinsics[0, 1]):.3g}, {float(intrinsics[1, 0]):.3g}), which "
                          "splatu's pinhole camera does not model", "in RunQuery.render", fix)
    return w2c, intrinsics, width, height
