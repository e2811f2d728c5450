"""Ask a trained run how sure it is of a view you choose: the Python entry point for next-best-view planning.

`open_run(path).render(world_to_camera, K, width, height)` renders a candidate camera given in the data's own
frame (the frame of the scene's poses and of the run's splat.ply, OpenCV axes), with the run's own uncertainty
(ours, or an ensemble run's std) or a baseline's (`open_run(path, method=...)`), without decoding the scene's
images unless the method compares renders with the training images (the residuals). The model lives in the
normalised frame it was trained in; the camera is moved there rather than the model moved out, so the render is
exactly what `splatu render-uncertainty --method ...` computes for that view.

K is the pinhole the model saw, not the lens's: a distorted capture (COLMAP SIMPLE_RADIAL or OPENCV, nerfstudio
OPENCV) trained on images undistorted to OpenCV's alpha=0 pinhole, which differs from the file's K by up to a few
per cent, and --downscale N rounds each image side, so K scales by new side / old side, not by exactly 1/N.
`RunQuery.scene_cameras()` gives every camera of the scene as the run saw it, in the data's frame.
"""

from __future__ import annotations

import dataclasses
import math
import operator
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, NamedTuple, get_args

import numpy as np
import torch
from torch import Tensor

from splatu.baselines import (
    METHODS_FOR_PLAIN_RUNS,
    METHODS_FROM_TRAINING_VIEWS,
    METHODS_WITH_OURS,
    UncertaintySource,
    method_list,
    own_method,
)
from splatu.baselines.ensemble import ENSEMBLE_FILE
from splatu.baselines.load import build_method, load_any_run, method_scene, run_data
from splatu.camera import Camera
from splatu.checkpoint import pinned_unless_finished
from splatu.data.assemble import choose_split, scene_normalization
from splatu.data.config import DataConfig
from splatu.data.frames import (
    FLOAT32_MAX,
    MAX_IMAGE_SIDE,
    checked_matrix,
    downscaled,
    refuse_implausible_focal,
    refuse_unaffordable_render,
)
from splatu.data.principal_point import misplaced_principal_point
from splatu.data.resolve import POSTER, read_scene_files, scene_path
from splatu.errors import SplatuError
from splatu.model import GaussianModel
from splatu.nearest_view import NearestView, nearest_training_views
from splatu.train_config import TrainConfig
from splatu.world_frame import WorldTransform, normalised_world_to_camera, require_same_frame


@dataclass(frozen=True)
class ViewUncertainty:
    """One rendered candidate view; depth is in the data's units (the blended depth Σ w·z / alpha, so a faint pixel
    reads a full depth: weigh it by alpha; 0 where nothing is seen). The uncertainty is in [0, 1] and reads 1 where
    nothing is seen, for every method but the ensemble, whose RGB std reads 0 there unless `density_aware`, and
    residual, whose map reads its worst there, 1 / (1 + the typical training residual), below 1."""

    rgb: np.ndarray  # (H, W, 3)
    depth: np.ndarray  # (H, W), the blended depth Σ w·z / alpha (0 where alpha is 0)
    alpha: np.ndarray  # (H, W)
    uncertainty: np.ndarray  # (H, W)

    @property
    def coverage(self) -> float:
        """The view's mean alpha: how much of it the model covers (a view of empty space: coverage 0)."""
        return float(self.alpha.mean())

    @property
    def mean_uncertainty(self) -> float:
        """The view's mean U: what a planner ranks candidate views by. A view of nothing ranks first (see the class's
        docstring) but for an ensemble run, whose std reads 0 there: open it with `density_aware=True` for that."""
        return float(self.uncertainty.mean())


class SceneCamera(NamedTuple):
    """A camera of the run's scene as the run saw it, in the data's frame: `run.render(*camera)` renders it, and
    `run.render(*camera, off_centre_ok=True)` a tile's or crop's (whose principal point lies far off-centre or off
    the image, which trained with a warning), refused without it as a candidate K of another size would be."""

    world_to_camera: np.ndarray  # (4, 4) float64, OpenCV axes: the pose in the scene's files
    K: np.ndarray  # (3, 3) float64: the pinhole its image was undistorted to, at the run's --downscale
    width: int
    height: int


QueryMethod = Literal["ours", "ensemble", "visibility", "fisher", "spread", "ours-spread", "residual", "ours-residual",
                      "angle", "ours-residual-angle", "ours-view-residual-angle"]
"""What `open_run` can render a candidate's uncertainty with: every method of `splatu render-uncertainty` but
random, whose noise ranks nothing."""

QUERY_METHODS: tuple[str, ...] = get_args(QueryMethod)


@dataclass(frozen=True)
class RunQuery:
    """A trained run, ready to render candidate views in the data's frame with one uncertainty method."""

    config: TrainConfig
    models: list[GaussianModel]  # the run's model, or an ensemble's members
    frame: WorldTransform
    method: QueryMethod
    source: UncertaintySource

    @torch.no_grad()
    def render(self, world_to_camera: np.ndarray | Tensor, K: np.ndarray | Tensor, width: int,
               height: int, *, off_centre_ok: bool = False) -> ViewUncertainty:
        """Render a camera: world-to-camera (4, 4) in the data's frame with OpenCV axes (x right, y down, z
        forward), pinhole intrinsics K (3, 3) in pixels, and the image size. Pixel (i, j) has its centre at
        (j + 0.5, i + 0.5), as in COLMAP and nerfstudio (OpenCV's calibration puts it at (j, i): add 0.5 to its cx
        and cy). For a distorted lens pass the pinhole the images were undistorted to (see `scene_cameras`).

        A principal point that a K of another size, or width and height swapped, explains is refused: a candidate
        has no image to show the mistake, which renders a shifted, zoomed view. A tile or crop of a larger photo
        (a tile scene's own `scene_cameras` too) has its point there by design: `off_centre_ok=True` says so and
        renders it. An explicit keyword, not a match against the scene's cameras, keeps the render a function of
        its arguments alone, as gsplat's rasterizer is: no hidden read of the scene's files (which may have
        moved), the same answer in every process, and a pasted K is still checked unless the caller vouches for it.
        """
        w2c, intrinsics, width, height = _checked_camera(world_to_camera, K, width, height, off_centre_ok,
                                                         len(self.models))
        camera = Camera(intrinsics, normalised_world_to_camera(w2c, self.frame), width, height)
        if float(torch.cat([camera.world_to_camera.abs().flatten(), intrinsics.abs().flatten()]).max()) > FLOAT32_MAX:
            raise SplatuError("the camera lies beyond float32's range (±3.4e38) in the model's frame, where it renders",
                              "in RunQuery.render", "pass a pose and K of the scene's own scale")
        out = self.source.render(camera)
        return ViewUncertainty(out.rgb.numpy(), (out.depth.double() * self.frame.scale).numpy(), out.alpha.numpy(),
                               out.uncertainty.numpy())

    def scene_cameras(self, data: str | Path | None = None) -> dict[str, SceneCamera]:
        """Every camera of the run's scene (training and held-out) by image name (a COLMAP image's name, a nerfstudio
        frame's file_path such as images/0001.jpg), as the run saw it: the pose from
        the scene's files and the undistorted, downscaled K and size its images trained at. Reads the scene's
        files, not its images (a NeRF-synthetic scene's first image per split, for its size); `data` is the scene's
        new location if it has moved. A tile or crop of a larger photo renders with `off_centre_ok=True` (see
        `render`)."""
        return scene_cameras(self.config.data, self.frame, data)

    def training_cameras(self, data: str | Path | None = None) -> dict[str, SceneCamera]:
        """The cameras the run trained on, as `scene_cameras` gives them (its split, as the run's options chose it):
        what `nearest_training_view` compares a candidate with."""
        return scene_cameras(self.config.data, self.frame, data, training_only=True)


def nearest_training_view(world_to_camera: np.ndarray | Tensor, training: Mapping[str, SceneCamera]) -> NearestView:
    """The training camera whose viewing direction is closest to this pose's (in the data's frame, OpenCV axes): its
    name, the angle between the two directions in degrees and the distance between the centres in the data's units,
    as render.json gives each candidate: how new a view is. A camera-to-world pose passed by mistake, which renders a
    plausible view without a word, stands out by its distance around an object, but need not in a forward-facing
    capture (`splatu.nearest_view`)."""
    if not training:
        raise SplatuError("no training cameras to compare with", "in nearest_training_view",
                          "pass run.training_cameras()")
    pose = torch.from_numpy(checked_matrix(_on_host(world_to_camera), "in nearest_training_view's world_to_camera",
                                           "pass an OpenCV world-to-camera pose without scale"))
    names = list(training)
    (nearest,) = nearest_training_views([pose], [torch.as_tensor(training[n].world_to_camera) for n in names], names)
    return nearest


def open_run(path: str | Path, head: str | None = None, method: QueryMethod | None = None,
             data: str | Path | None = None, density_aware: bool = False) -> RunQuery:
    """A run's folder (or one of its checkpoints), to render with `method`: ours (optionally one of the run's extra
    uncertainty heads), an ensemble run's member disagreement (`density_aware` as in `splatu eval-ause`), or a
    baseline; by default the run's own, as render-uncertainty's (`own_method`): the ensemble's for an ensemble run,
    else ours. The baselines that look at the training views first (visibility, fisher, angle and the residuals) read
    the scene here, once (only the residuals decode its images: they compare renders with them); `data` is the
    scene's new location if it has moved, for those methods alone (the others never read the scene here)."""
    target = Path(path).expanduser()
    is_ensemble = (target / ENSEMBLE_FILE).is_file()
    # an ensemble opened as it renders by default is told about as the run: the method was not the caller's, and it
    # renders with no other
    own_ensemble = method is None and is_ensemble
    if method is None:
        method = own_method(is_ensemble)
    if method == "random":  # a baseline for eval-ause's scores, not a ranking
        raise SplatuError("method=\"random\" is not offered from Python: its uniform noise would rank candidate "
                          "views at random (it is eval-ause's baseline)", "in open_run",
                          f"pass method= one of {method_list(QUERY_METHODS)}")
    if method not in QUERY_METHODS:
        raise SplatuError(f"unknown method {method!r}", "in open_run",
                          f"pass method= one of {method_list(QUERY_METHODS)}")
    if density_aware and method != "ensemble":  # as render-uncertainty refuses it: it would be ignored
        raise SplatuError("density_aware only applies with method=\"ensemble\"", "in open_run",
                          "drop density_aware, or pass method=\"ensemble\" for an ensemble run")
    subject = ("an ensemble run, rendered with its members' std by default," if own_ensemble
               else f'method="{method}"')
    if head is not None and method not in METHODS_WITH_OURS:
        raise SplatuError(f"head picks an uncertainty head of ours; {subject} has "
                          f"{'no uncertainty head' if own_ensemble else 'none'}", "in open_run",
                          "drop head" if own_ensemble else
                          f"drop head, or pass method= one of {method_list(METHODS_WITH_OURS)}")
    if data is not None and method not in METHODS_FROM_TRAINING_VIEWS:  # it renders the model alone
        to_cameras = ("drop data= here, and pass it to run.scene_cameras() and run.training_cameras(), which read the "
                      "scene")
        raise SplatuError(f"data= is where the scene is, which {subject} never reads", "in open_run",
                          to_cameras if own_ensemble else
                          f"{to_cameras}, or pass method= one of {method_list(METHODS_FROM_TRAINING_VIEWS)}")
    if is_ensemble != (method == "ensemble"):  # an ensemble's members trained without the loss: they have no U
        raise SplatuError("this is an ensemble run, whose uncertainty is its members' disagreement" if is_ensemble
                          else "method=\"ensemble\" needs an ensemble run (with ensemble.json)", f"in {path}",
                          "drop method=, or pass method=\"ensemble\"" if is_ensemble else
                          "open one trained with `splatu train --method ensemble`, or pass another method=")
    pinned, note = pinned_unless_finished(target)
    if note is not None:  # a ranking of an intermediate model, not the finished run's
        warnings.warn(note, stacklevel=2)
    try:
        run = load_any_run(pinned, head)
        if method in METHODS_WITH_OURS and run.config.uncertainty.off:
            raise SplatuError("this run was trained without the uncertainty loss, so it has no uncertainty to render",
                              f"in {path}", "open a run trained with `splatu train --method splatu`, or pass "
                              f"method= one of {method_list(METHODS_FOR_PLAIN_RUNS)}")
        if any(frame is None for frame in run.frames):
            raise SplatuError("this run's checkpoint predates the record of its data frame, so a camera in the data's "
                              "frame cannot be placed", f"in {path}", "train the run again with this version")
        frame = run.frames[0]
        assert frame is not None  # checked above
        for other in run.frames[1:]:
            require_same_frame(other, frame, f"in {path}", "train the ensemble again: its members differ in scene")
        scene = (method_scene(method, run_data(run, None if data is None else str(data)))
                 if method in METHODS_FROM_TRAINING_VIEWS else None)
        source = build_method(method, run, scene, density_aware).source
    except SplatuError as error:  # the CLI's advice, in the arguments a Python caller passes
        fix = error.fix.replace("--head", "head=").replace("--data PATH", "data=PATH").replace("--data", "data=")
        raise SplatuError(error.what, error.where, fix) from None
    return RunQuery(run.config, run.models, frame, method, source)


def scene_cameras(recorded: DataConfig, frame: WorldTransform, data: str | Path | None = None,
                  training_only: bool = False) -> dict[str, SceneCamera]:
    """The cameras of the scene `recorded` names (at `data` if given) in the data's frame, as the loaders make them
    for training (only its training split's with `training_only`), without the loaders' off-centre warning; a
    scene that is missing, or normalised unlike `frame` (another scene), is one SplatuError line."""
    config = recorded if data is None else dataclasses.replace(recorded, data=str(data))
    path = scene_path(config)
    where = "in RunQuery.scene_cameras"
    if config.data != POSTER and not path.exists():
        raise SplatuError(f"the run's scene is not at {path}", where, "pass data= with the scene's location")
    # quietly: the run warned of principal points far off-centre as it trained, and a query may run in a loop
    raw = downscaled(read_scene_files(path, config.background, warn_off_centre=False), config.downscale or 1)
    center, scale = scene_normalization(raw)
    require_same_frame(frame, WorldTransform.from_normalization(center, scale), f"in {path}",
                       "pass data= with the scene this run was trained on")
    frames = [raw.frames[i] for i in choose_split(raw, config)[0]] if training_only else raw.frames
    return {f.name: SceneCamera(f.camera.world_to_camera.double().numpy().copy(), f.camera.K.double().numpy().copy(),
                                f.camera.width, f.camera.height) for f in frames}


def _checked_camera(world_to_camera: np.ndarray | Tensor, K: np.ndarray | Tensor, width: int, height: int,
                    off_centre_ok: bool, members: int = 1) -> tuple[Tensor, Tensor, int, int]:
    """The camera as float64 tensors and int sizes, or one clear error: a wrong shape, a non-finite entry, a pose
    that is not a rigid motion, a bad size, or a K of another image size or orientation (unless `off_centre_ok`
    vouches for a tile's principal point) would otherwise render a wrong or blank image without a word; a size a
    render of `members` models has not the memory for would grow until the OS killed the process."""
    # the loaders' own check of a pose (finite, rigid within their tolerance, last row 0 0 0 1; 3x4 or 4x4)
    w2c = torch.from_numpy(checked_matrix(_on_host(world_to_camera), "in RunQuery.render's world_to_camera",
                                          "pass an OpenCV world-to-camera pose without scale"))
    intrinsics = _numbers(_on_host(K), "K")
    if intrinsics.shape != (3, 3):
        raise SplatuError(f"K must be a (3, 3) matrix, got shape {tuple(intrinsics.shape)}",
                          "in RunQuery.render", "pass K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels")
    if not intrinsics.isfinite().all():  # said apart from the shape: "got shape (3, 3)" read as no fault at all
        raise SplatuError(f"K has non-finite entries (NaN or Inf): {intrinsics.tolist()}", "in RunQuery.render",
                          "pass K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in finite pixels")
    sizes = [_pixels(n, name) for n, name in ((width, "width"), (height, "height"))]
    # no larger than the loaders take: a 10⁶ × 10⁶ image would need terabytes, and fail in torch's allocator
    if not all(0 < n <= MAX_IMAGE_SIDE for n in sizes):
        raise SplatuError(f"the image size must be positive integers up to {MAX_IMAGE_SIDE}, got {width}×{height}",
                          "in RunQuery.render", "pass width and height in pixels")
    refuse_unaffordable_render([(sizes[0], sizes[1])], members, "in RunQuery.render",
                               "pass a smaller width and height, and scale K's first two rows by the same factor")
    fix = "pass K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels of this image size"
    if not (intrinsics[0, 0] > 0 and intrinsics[1, 1] > 0):
        raise SplatuError("K's focal lengths must be positive", "in RunQuery.render", fix)
    width, height = sizes
    refuse_implausible_focal(intrinsics.numpy(), width, height, "in RunQuery.render", fix)
    # the rasterizer reads fx, fy, cx and cy alone, so any other entry would be dropped without a word
    if float((intrinsics[2] - torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)).abs().max()) > 1e-9:
        raise SplatuError(f"K's last row is {intrinsics[2].tolist()}, not [0, 0, 1]", "in RunQuery.render",
                          f"{fix} (for another image size, scale K's first two rows only)")
    if max(abs(float(intrinsics[0, 1])), abs(float(intrinsics[1, 0]))) > 1e-9 * float(intrinsics[:2, :2].abs().max()):
        raise SplatuError(f"K has a skew ({float(intrinsics[0, 1]):.3g}, {float(intrinsics[1, 0]):.3g}), which "
                          "splatu's pinhole camera does not model", "in RunQuery.render", fix)
    # K for another image size (the file's full-resolution K at the run's --downscale size), or width and height
    # passed the wrong way round, rendered a zoomed, shifted view without a word
    fault = None if off_centre_ok else misplaced_principal_point(float(intrinsics[0, 2]), float(intrinsics[1, 2]),
                                                                  width, height, candidate=True)
    if fault is not None:
        fix = ("pass the width before the height, or swap K's cx and cy" if fault[0] == "swapped" else
               "pass the K of this size (run.scene_cameras() gives each view's at the run's --downscale), or scale "
               "K's first two rows by new size / old size")
        raise SplatuError(f"K's {fault[1]}", "in RunQuery.render",
                          f"{fix}; for a tile or crop of a larger photo (a tile scene's own cameras too), pass "
                          "off_centre_ok=True")
    return w2c, intrinsics, width, height


def _pixels(n: object, name: str) -> int:
    """`n` as an int if it is a whole number: a Python, numpy or torch integer (a nerfstudio `Cameras`' width is a
    one-element tensor), or an integral float (`W * scale` gives 144.0); else one line naming its type or value: a
    bool (True is 1), a fraction or a string ("144" read from a file) was told apart from a bad size by nothing."""
    where, fix = "in RunQuery.render", "pass width and height as whole numbers of pixels (int(...) of a string)"
    if isinstance(n, Tensor | np.ndarray):
        count = n.size if isinstance(n, np.ndarray) else n.numel()
        if count != 1:
            raise SplatuError(f"the image {name} is an array of shape {tuple(n.shape)}, not a number of pixels", where,
                              fix)
        n = n.item()  # one element, numpy's or torch's, as the Python number it holds
    if isinstance(n, bool | np.bool_):
        raise SplatuError(f"the image {name} is a bool ({bool(n)}), not a number of pixels", where, fix)
    try:
        return operator.index(n)  # type: ignore[arg-type]
    except TypeError:
        pass
    if isinstance(n, float | np.floating):
        value = float(n)
        if value.is_integer():
            return int(value)
        raise SplatuError(f"the image {name} {value!r} is not a whole number of pixels", where,
                          "round it (int(round(...))) and scale K by the same factor" if math.isfinite(value)
                          else fix)
    raise SplatuError(f"the image {name} is a {type(n).__name__} ({n!r:.40}), not a number of pixels", where, fix)


def _on_host(value: object) -> object:
    """A tensor as a float64 numpy array on the CPU, anything else as given: numpy reads no CUDA tensor (its TypeError
    read as "pose is not a 3x4 or 4x4 matrix"), nor one that requires grad (a pose being optimised: torch's
    RuntimeError), and reads any other through torch's `__array__`, which numpy 2 warns is deprecated."""
    return value.detach().to("cpu", torch.float64).numpy() if isinstance(value, Tensor) else value


def _numbers(value: object, name: str) -> Tensor:
    """`value` as a float64 tensor, or one line for a ragged list or a non-number (numpy's ValueError or TypeError)."""
    try:
        return torch.as_tensor(np.asarray(value, dtype=np.float64))
    except (TypeError, ValueError):
        raise SplatuError(f"{name} is not an array of numbers ({type(value).__name__})", "in RunQuery.render",
                          "pass a numpy array, a tensor or nested lists of numbers") from None
