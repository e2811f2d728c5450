"""`splatu render-uncertainty`: RGB, depth, alpha and uncertainty maps of a trained run.

For the chosen views (eval, train, or an orbit that also looks from below) and method, it
writes, under <run>/uncertainty/<label>-<views>/ (the label: the method and any option that changes its
maps) unless --output says otherwise (what an earlier render wrote there is replaced once the new render is
written in full, see `swap_in`):

    npy/NAME_{rgb,depth,alpha,uncertainty}.npy   raw float maps (depth in the data's units, as splatu.query's: the
                                                 blended depth Σ w·z / alpha, 0 where alpha is 0)
    png/NAME_{rgb,uncertainty,depth,alpha}.png   colour-mapped on one scale shared by all views (render.json's
                                                 uncertainty_scale and depth_scale); depth black where alpha is 0
    colorbar_{uncertainty,depth,error}.png       the legends of those shared scales (error's only when GT exists)
    panels/NAME.png                              GT | render | uncertainty | error (GT and error when GT exists)
    maps/                                        the layout `eval-ause --maps` scores (when GT exists)
    orbit.gif                                    for --views orbit
    render.json                                  per-view mean uncertainty, elevations, the orbit's shape, timings,
                                                 the --cameras file
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, NamedTuple

import numpy as np
import torch
import tyro
from rich.console import Console

from splatu.atomic import (
    atomic_write_text,
    file_identity,
    leftover_temporaries,
    temporary_sibling,
    what_a_stop_left,
)
from splatu.baselines import UncertaintyRender, UncertaintySource
from splatu.camera import Camera
from splatu.checkpoint import pinned_unless_finished, run_folder
from splatu.data.frames import refuse_unaffordable_render
from splatu.data.images import write_png
from splatu.data.nerfstudio import read_cameras, transforms_file
from splatu.data.scene import CameraScene, Scene, Views
from splatu.errors import (
    FREE_AND_RERUN,
    SplatuError,
    creatable_dir,
    no_empty_folders_left,
    os_error_behind,
    require_at_least,
    require_at_most,
    require_file,
    unwritable_folder,
)
from splatu.figures import (
    DEPTH_CMAP,
    ERROR_CMAP,
    UNCERTAINTY_CMAP,
    ColourScale,
    colour_map,
    save_colour_bar,
    save_orbit_gif,
    save_panel,
)
from splatu.interrupts import finish_first, saying_what_is_left
from splatu.maps import MapEntry, file_stems, write_entry, write_maps_dir
from splatu.nearest_view import nearest_training_views
from splatu.orbit import (
    DEFAULT_ELEVATION_DEGREES,
    OrbitPlan,
    OrbitShape,
    one_sided_note,
    orbit_along,
    plan_orbit,
)
from splatu.run_dir import DEMO_RUN
from splatu.train_progress import view_progress
from splatu.uncertainty_options import UncertaintyOptions
from splatu.world_frame import normalised_world_to_camera, scene_frame

if TYPE_CHECKING:
    from splatu.baselines.load import LoadedRun  # at run time imported where used: it pulls in the trainer stack

ViewSet = Literal["eval", "train", "orbit", "cameras"]


MAX_GIF_FPS = 50
"""A GIF stores each frame's delay in hundredths of a second, and browsers play a delay under 0.02 s as 0.1 s: at
--gif-fps 1000 the orbit GIF held no delay and played at 10 frames per second, slower than at --gif-fps 20."""


@dataclass
class RenderUncertaintyConfig:
    """Options of `splatu render-uncertainty`."""

    load: Path = DEMO_RUN
    """A training run directory, or one of its checkpoint files, or an ensemble run (rendered with --method ensemble
    by default)."""
    uncertainty: Annotated[UncertaintyOptions, tyro.conf.OmitArgPrefixes] = field(default_factory=UncertaintyOptions)
    """Which uncertainty to render, and the options that change its maps."""
    # None until `run` resolves it from --cameras; parsed as the view sets alone, with the default told in words
    views: Annotated[ViewSet | None, tyro.conf.arg(
        constructor=ViewSet, help_behavior_hint="(default: eval, or cameras with --cameras)")] = None
    """eval / train: the scene's cameras (with ground truth); orbit: generated views round the capture (a circle, or
    an arc over the side a one-sided capture was taken from: --orbit-shape) that also look from below; cameras:
    the candidate cameras of --cameras (render.json gives each view's mean uncertainty, to rank them by)."""
    cameras: Path | None = None
    """Candidate cameras to render (implies --views cameras): a transforms.json-style file of cameras in the data's
    own frame (the scene's poses and splat.ply's): per frame a file_path naming the view (no file need exist) and an
    OpenGL camera-to-world transform_matrix; fl_x, fl_y, cx, cy, w and h at the scene's full resolution, and a
    distorted capture's k1, k2, p1, p2 (K is then undistorted as the loader's is), at the top level or per frame, as
    nerfstudio writes them. They render at the run's --downscale, as its own cameras do. A COLMAP images.txt pose
    [R(qvec) | tvec] is written as its inverse with the y and z columns negated. Empty space reads the highest U (1;
    residual's is just below), so a view of nothing ranks first, with every method but two: an ensemble run's std
    reads 0 there (its members agree on nothing), so such a view ranks last unless --density-aware, and random reads
    noise (0.5 on average). render.json gives each view's coverage."""
    off_centre_ok: bool = False
    """With --cameras: its cameras are tiles or crops of larger photos (a tile scene's own, say), whose principal
    point lies far off-centre or off the image by design; without it such a camera is refused, as a K made for
    another size or with w and h swapped would render a shifted, zoomed view without a word."""
    output: Path | None = None
    """Output folder; default <run>/uncertainty/<label>-<views>, the label being the method and the options that change
    its maps (e.g. ensemble-density-aware)."""
    max_views: int = 0
    """Render at most this many views (evenly spaced; an orbit's round its loop); 0 renders all."""
    orbit_frames: int = 24
    """Frames of the orbit (--views orbit)."""
    orbit_elevation: float = DEFAULT_ELEVATION_DEGREES
    """The orbit's elevation swings between +this and −this degrees around the capture's centre."""
    orbit_shape: OrbitShape = "auto"
    """circle: once round the capture; arc: a loop over the side the capture was taken from, reaching 15° past it
    either side; auto: the arc when every training camera is on one side of the capture's centre (a door from the
    front, fox), which a note then says, the circle otherwise (a capture walked around an object)."""
    orbit_radius_scale: float | None = None
    """Orbit radius as a multiple of the median training-camera distance to the centre; default 0.5 for the circle
    (the from-below views stay above the floor of a capture walked around an object: see splatu.orbit), 1 for the
    arc (at half the radius the cameras of a one-sided capture sit among its surfaces)."""
    gif_fps: int = 6
    """Frames per second of the orbit GIF, at most 50."""

    def __post_init__(self) -> None:
        for flag, value, minimum in (("--max-views", self.max_views, 0), ("--orbit-frames", self.orbit_frames, 1),
                                     ("--gif-fps", self.gif_fps, 1)):
            require_at_least(value, minimum, flag)
        require_at_most(self.gif_fps, MAX_GIF_FPS, "--gif-fps")
        if self.orbit_radius_scale is not None:
            require_at_least(self.orbit_radius_scale, 1e-3, "--orbit-radius-scale")


@dataclass
class RenderedView:
    """One rendered view as numpy maps, with its ground truth when the scene has one."""

    name: str
    maps: dict[str, np.ndarray]  # rgb (H, W, 3), depth, alpha, uncertainty (H, W)
    gt: np.ndarray | None = None
    mask: np.ndarray | None = None
    unobserved: np.ndarray | None = None
    elevation_degrees: float | None = None
    nearest_training_view: dict[str, Any] | None = None
    """The training view closest in viewing direction (`nearest_training_views`)."""
    source_name: str | None = None
    """The view's name as the scene or the --cameras file gives it (a COLMAP image's name, a frame's file_path), of
    which `name` is the file stem: `close0.2` is written as `close0_*.npy`, `images/0001.jpg` as `images_0001_*`."""


@dataclass(frozen=True)
class ViewSpec:
    """What to render: cameras, optional ground truth, and orbit elevations."""

    cameras: list[Camera]
    names: list[str]
    views: Views | None = None
    indices: list[int] | None = None
    elevations: list[float] | None = None
    depth_unit: float = 1.0
    """Data units per model unit: depths are written in the data's units (the frame of the scene's poses, of
    --cameras and of splat.ply), as `splatu.query` gives them, not in the model's normalised ones."""
    note: str | None = None
    """What the command says about the views before rendering them (why the orbit is an arc)."""
    orbit: dict[str, Any] | None = None
    """The orbit's shape and size (`OrbitPlan.record`), for render.json; None for other views."""


def _evenly(count: int, limit: int, closed: bool = False) -> list[int]:
    """`limit` indices (all for 0) spread over `count` views: from the first to the last, or, round a `closed` loop
    (the orbit), a step of count / limit apart, as the last frame is next to the first: 4 of 24 orbit frames were
    0, 8, 15 and 23, two of them 15° apart, where 0, 6, 12 and 18 go round the loop."""
    if limit <= 0 or limit >= count:
        return list(range(count))
    if closed:
        return [round(i * count / limit) for i in range(limit)]
    return sorted({round(i * (count - 1) / (limit - 1)) for i in range(limit)}) if limit > 1 else [0]


def view_spec(scene: Scene | CameraScene, which: ViewSet, config: RenderUncertaintyConfig,
              downscale: int = 1, members: int = 1) -> ViewSpec:
    """Cameras of the eval or train split (with their ground truth: `scene` is then a `Scene`), a generated orbit, or
    the --cameras file's, at the run's `downscale` as its own cameras are; those refused if a render of `members`
    models would not fit in memory (the scene's own views trained here)."""
    frame = scene_frame(scene)  # the run's own (build_method checked), also for checkpoints older than its record
    if which == "cameras":
        assert config.cameras is not None  # run() refuses --views cameras without it
        cameras = [dataclasses.replace(c, world_to_camera=normalised_world_to_camera(c.world_to_camera, frame))
                   for c in read_cameras(config.cameras, downscale, config.off_centre_ok)]
        keep = _evenly(len(cameras), config.max_views)
        refuse_unaffordable_render([(cameras[i].width, cameras[i].height) for i in keep], members,
                                   f"in {config.cameras}", "give smaller w and h, scaling fl_x, fl_y, cx and cy with "
                                   "them, or split the frames over several files")
        return ViewSpec([cameras[i] for i in keep], file_stems([cameras[i].name for i in keep], f"in {config.cameras}"),
                        depth_unit=frame.scale)
    if which == "orbit":
        plan = plan_orbit(scene.train.cameras, config.orbit_shape, config.orbit_radius_scale)
        frames = orbit_along(plan, scene.train.cameras[0], config.orbit_frames, config.orbit_elevation)
        keep = _evenly(len(frames), config.max_views, closed=True)
        return ViewSpec([frames[i].camera for i in keep], [frames[i].camera.name for i in keep],
                        elevations=[frames[i].elevation_degrees for i in keep], depth_unit=frame.scale,
                        note=orbit_note(plan, config), orbit=plan.record(config.orbit_elevation))
    assert isinstance(scene, Scene)  # `_setup` decodes the images of eval and train views, their ground truth
    views = {"eval": scene.eval, "train": scene.train}[which]
    if len(views) == 0:
        raise SplatuError(f"the scene's {which} split is empty", "in the run's scene", "pick another --views")
    keep = _evenly(len(views), config.max_views)
    return ViewSpec([views.cameras[i] for i in keep], file_stems([views.names[i] for i in keep]), views, keep,
                    depth_unit=frame.scale)


def orbit_note(plan: OrbitPlan, config: RenderUncertaintyConfig) -> str | None:
    """The note saying why, when --orbit-shape auto chose the arc; None when the shape was given or is the circle."""
    if config.orbit_shape != "auto" or plan.half_width is None:
        return None
    return one_sided_note(plan, config.orbit_radius_scale is None)


def _numpy(render: UncertaintyRender, name: str) -> dict[str, np.ndarray]:
    maps = {key: getattr(render, key).detach().double().cpu().numpy() for key in ("rgb", "depth", "alpha",
                                                                                     "uncertainty")}
    for key, value in maps.items():
        if not np.isfinite(value).all():
            raise RuntimeError(f"the {key} map of view {name!r} has non-finite values: a rendering bug")
    return maps


@torch.no_grad()
def render_views(source: UncertaintySource, spec: ViewSpec) -> tuple[list[RenderedView], list[float]]:
    """Render every view (no gradients), showing progress on a terminal (`view_progress`: an ensemble's or a
    baseline's views at full resolution take minutes); returns the views and the seconds each took."""
    rendered, seconds = [], []
    with view_progress() as bar:
        views = zip(spec.cameras, spec.names, strict=True)
        for k, (camera, name) in enumerate(bar.track(views, total=len(spec.cameras), description="render")):
            started = time.perf_counter()
            maps = _numpy(source.render(camera), name)
            seconds.append(time.perf_counter() - started)
            maps["depth"] *= spec.depth_unit
            view = RenderedView(name, maps)
            if spec.views is not None and spec.indices is not None:
                i = spec.indices[k]
                view.gt = spec.views.target(i, source.background).double().numpy()
                if spec.views.object_masks is not None:
                    view.mask = spec.views.object_masks[i].bool().numpy().reshape(view.gt.shape[:2])
                if spec.views.observed is not None:
                    view.unobserved = ~spec.views.observed[i].bool().numpy().reshape(view.gt.shape[:2])
            if spec.elevations is not None:
                view.elevation_degrees = spec.elevations[k]
            rendered.append(view)
    return rendered, seconds


def map_entries(views: list[RenderedView]) -> list[MapEntry]:
    """The views that have ground truth and a pixel to score, as the entries eval-ause scores: a view its mask
    file excludes entirely has no sparsification curve."""
    return [MapEntry(v.name, v.maps["rgb"], v.gt, v.maps["uncertainty"], v.mask, v.unobserved)
            for v in views if v.gt is not None and (v.mask is None or v.mask.any())]


NOTHING_DRAWN = np.zeros(3, dtype=np.uint8)
"""The depth PNG's colour where alpha is 0: black, which viridis never reaches, since the raw depth there is 0 and
would otherwise read as the nearest depth on the scale."""


DEPTH_PERCENTILES = (1.0, 99.0)
"""The depth PNGs' colour range, as percentiles of the covered pixels' depths: a few floaters near the camera or far
behind set the extremes (fox: 0.4 to 24.7 with half its pixels nearer than 4.5): the scene was one dark colour."""


def shared_scales(views: list[RenderedView]) -> dict[str, ColourScale]:
    """One colour scale per quantity for all views: [0, 1] when U stays in it, else [0, max]; depth from the 1st to
    the 99th percentile of the pixels at least half covered (DEPTH_PERCENTILES), clamped beyond; error only when a
    view has ground truth, as there is no error map otherwise."""
    u_max = max(float(v.maps["uncertainty"].max()) for v in views)
    hit = np.concatenate([v.maps["depth"][v.maps["alpha"] > 0.5].ravel() for v in views])
    hit = hit[np.isfinite(hit)]  # a scale of NaN would colour nothing and read back as nothing
    depth_lo, depth_hi = (tuple(float(d) for d in np.percentile(hit, DEPTH_PERCENTILES)) if hit.size else (0.0, 1.0))
    errors = [np.abs(v.maps["rgb"] - v.gt).sum(axis=-1) for v in views if v.gt is not None]
    scales = {
        "uncertainty": ColourScale(0.0, max(1.0, u_max), UNCERTAINTY_CMAP, "uncertainty U"),
        "depth": ColourScale(depth_lo, max(depth_hi, depth_lo + 1e-6), DEPTH_CMAP,
                             "depth, data units (black: nothing drawn)"),
        "alpha": ColourScale(0.0, 1.0, "gray", "accumulated alpha"),
    }
    if errors:
        error_max = max(float(np.percentile(e, 99.5)) for e in errors)
        scales["error"] = ColourScale(0.0, max(error_max, 1e-6), ERROR_CMAP, "error Σ_c |Î − I|")
    return scales


OWNED = ("npy", "png", "panels", "maps", "orbit.gif")
"""What a render writes under names of its own choosing: cleared first, so no view of an earlier render survives
(colorbar_*.png and render.json are always rewritten)."""


SWAPPING = ".render-swapping"
"""Present in an output folder only while `swap_in` replaces its render: a folder that a second Ctrl-C or a kill
left half-swapped, without its render.json, is still known to be render-uncertainty's."""
STAGING = "render"
"""A render is written whole into <out>/.render.tmp-PID first (`temporary_sibling`; see `swap_in`)."""


def refuse_foreign_output(out: Path, default_folder: bool) -> None:
    """Refuse an --output folder that holds `OWNED` names another tool may have written. A folder is ours when it
    is the default <run>/uncertainty/<label>-<views> or holds our render.json (or `SWAPPING`). Checked before the
    scene loads, so a refusal costs nothing."""
    present = [name for name in OWNED if (out / name).exists()]
    ours = default_folder or (out / "render.json").is_file() or (out / SWAPPING).is_file()
    if present and not ours:
        raise SplatuError(f"--output already holds {present[0]!r}, not written by render-uncertainty",
                          f"in {out}", "pass a new or empty --output folder (or the folder of an earlier render)")


def remove(paths: list[Path]) -> None:
    """Delete files and folders (a symlink is removed, never followed)."""
    for path in paths:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()


def swap_in(staging: Path, out: Path) -> None:
    """Put the whole render written in `staging` in place of the earlier one in `out`, so that a command that fails
    (a moved scene, a corrupt image, a full disk, Ctrl-C) leaves the earlier render whole, and no view of it
    survives the new one. The earlier entries are listed now, not when the command started: eval-ause may have
    written maps/ since, or a user removed a file. A Ctrl-C or SIGTERM waits for the renames (a second one
    aborts); render.json goes first and comes back last, so even a kill leaves no earlier render.json beside files
    it does not list, and `SWAPPING` marks the folder meanwhile."""
    with finish_first():
        (out / SWAPPING).touch()
        (out / "render.json").unlink(missing_ok=True)
        remove([out / name for name in OWNED if (out / name).exists() or (out / name).is_symlink()])
        for entry in sorted(staging.iterdir(), key=lambda path: path.name == "render.json"):
            os.replace(entry, out / entry.name)
        (out / SWAPPING).unlink()


def write_outputs(out: Path, views: list[RenderedView], orbit: bool, fps: int) -> dict[str, ColourScale]:
    """Raw maps, colour-mapped PNGs, colour bars, panels, the maps layout and (orbit) the GIF."""
    for folder in ("npy", "png", "panels"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    scales = shared_scales(views)
    for key in ("uncertainty", "depth", "error"):
        if key in scales:  # no error map, so no error legend, without ground truth (an orbit, candidate cameras)
            save_colour_bar(out / f"colorbar_{key}.png", scales[key])
    with view_progress() as bar:  # PNGs and matplotlib panels: several seconds for a few dozen views
        for view in bar.track(views, description="write"):
            write_view(out, view, scales)
    for entry in map_entries(views):  # none for orbit views: they have no ground truth to score
        write_entry(out / "maps", entry)  # `out` is the staging folder, swapped in whole: no staging of its own
    if orbit:
        titles = [f"{v.name}  elevation {v.elevation_degrees:+.0f}°" for v in views]
        save_orbit_gif(out / "orbit.gif", [v.maps["rgb"] for v in views], [v.maps["uncertainty"] for v in views],
                       scales["uncertainty"], titles, fps)
    return scales


def write_view(out: Path, view: RenderedView, scales: dict[str, ColourScale]) -> None:
    """One view's raw maps, colour-mapped PNGs and panel, on the render's shared `scales`."""
    for key, value in view.maps.items():
        np.save(out / "npy" / f"{view.name}_{key}.npy", value.astype(np.float32))
    write_png(out / "png" / f"{view.name}_rgb.png",
              (np.clip(view.maps["rgb"], 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8), FREE_AND_RERUN)
    for key in ("uncertainty", "depth", "alpha"):
        image = colour_map(view.maps[key], scales[key])
        if key == "depth":
            image[view.maps["alpha"] <= 0.0] = NOTHING_DRAWN
        write_png(out / "png" / f"{view.name}_{key}.png", image, FREE_AND_RERUN)
    error = None if view.gt is None else np.abs(view.maps["rgb"] - view.gt).sum(axis=-1)
    save_panel(out / "panels" / f"{view.name}.png", view.maps["rgb"], view.maps["uncertainty"],
               scales["uncertainty"], view.gt, error, scales.get("error"))


def pinned_load(load: Path, written: str) -> Path:
    """`--load`, pinned to its newest checkpoint while it is training or unfinished (`pinned_unless_finished`), with a
    note on stderr: `written`, what the command writes, is named after that checkpoint."""
    pinned, note = pinned_unless_finished(load)
    if note is not None:
        named = "it" if pinned.is_file() else "their steps"
        Console(stderr=True).print(f"note: {note}; {written} is named after {named}", soft_wrap=True)
    return pinned


def _load(load: Path, options: UncertaintyOptions) -> tuple[LoadedRun, UncertaintyOptions]:
    """The run, and the options with the method resolved for it (`UncertaintyOptions.for_run`), checked against it
    (imports kept here: they pull in the whole trainer stack); the options typed are checked by each command first
    (`UncertaintyOptions.check`). Everything after it uses these options, never the method as typed."""
    from splatu.baselines.load import check_method, load_any_run

    run = load_any_run(load, options.head)
    typed = options.method is not None
    options = options.for_run(len(run.models) > 1)
    assert options.method is not None  # for_run resolved it
    check_method(options.method, run, typed)
    return run, options


def _setup(run, options: UncertaintyOptions, views: ViewSet):
    """The run's scene, its images decoded only when the views' ground truth or the method needs them
    (`method_scene`), and the method's renderer; `options` as `_load` resolved them."""
    from splatu.baselines.load import build_method, method_scene, run_data

    assert options.method is not None  # _load resolved it
    scene = method_scene(options.method, run_data(run, options.data), ground_truth=views in ("eval", "train"))
    return scene, build_method(options.method, run, scene, options.density_aware, options.fisher_probes,
                               options.seed)


class EvalMaps(NamedTuple):
    """What `render_eval_maps` wrote: where, the views as stored there (see write_maps_dir), whether the scene is the
    built-in stand-in (`Scene.stand_in`), the label of what was loaded (`UncertaintyOptions.label`), and the options
    that rendered it, the method resolved for the run (`UncertaintyOptions.for_run`)."""

    root: Path
    entries: list[MapEntry]
    stand_in: bool
    label: str
    options: UncertaintyOptions


def render_eval_maps(load: Path, options: UncertaintyOptions, root: Path | None = None) -> EvalMaps:
    """Render the eval split into the maps layout only (what `eval-ause --load` scores), at `root` (default: the
    run's <run>/uncertainty/<label>-eval/maps, beside render-uncertainty's files)."""
    run, options = _load(load, options)
    label = options.label(load, run.member_steps)
    if root is None:
        root = run_folder(load) / "uncertainty" / f"{label}-eval" / "maps"
        creatable_dir(root.parent, "run folder (eval-ause --load writes the maps it scores there), or pass "
                                  "--output elsewhere to write them beside it")
    else:
        creatable_dir(root.parent, "--output folder")
    scene, built = _setup(run, options, "eval")
    spec = view_spec(scene, "eval", RenderUncertaintyConfig(load=load))
    views, seconds = render_views(built.source, spec)
    entries = map_entries(views)
    if not entries:
        raise SplatuError("no eval view has a pixel to score (its mask file or its image's alpha excludes each)",
                          "in the scene's eval images", "fix the masks or the images' alpha, or hold out other views "
                          "(--eval-split)")
    timing = {**train_timing(run), "setup_seconds": built.setup_seconds,
              "render_seconds_per_view": float(np.median(seconds))}
    # in place of an earlier render's, whose stale views must not be scored
    return EvalMaps(root, write_maps_dir(root, entries, {"timing.json": json.dumps(timing)}), scene.stand_in, label,
                    options)


def train_timing(run: LoadedRun) -> dict[str, float | None]:
    """What the run's training cost, as render.json and eval-ause's timing.json name it: `train_step_seconds`, the
    time inside training steps (summary.json's train_seconds; an ensemble's, its members' summed), is the one measure
    every method reports, so ours and the ensemble compare on it; `train_compile_seconds`, the time the steps spent
    compiling the rasterizer's kernels (each session's first step, ~10 s to a minute), is left out of it, so that a
    resumed run or one ensemble member compiling for all does not skew the comparison; `train_wall_seconds` (scene
    loading, evaluations, every session of an ensemble) is beside them. All None for a run or ensemble not
    finished; `train_compile_seconds` also for one saved before compiles were timed apart, or whose torch could
    not time them (`kernels.compile_seconds`), whose `train_step_seconds` includes them."""
    return {"train_step_seconds": run.train_seconds, "train_compile_seconds": run.train_compile_seconds,
            "train_wall_seconds": run.wall_seconds}


ORBIT_OPTIONS = ("orbit_frames", "orbit_elevation", "orbit_shape", "orbit_radius_scale", "gif_fps")


def with_views_resolved(config: RenderUncertaintyConfig) -> RenderUncertaintyConfig:
    """`config` with its view set chosen when none was typed: the candidate cameras of --cameras, else the eval
    split. A file of cameras given alone asks for nothing else, so it is not refused for a missing --views."""
    if config.views is not None:
        return config
    return dataclasses.replace(config, views="cameras" if config.cameras is not None else "eval")


def run(config: RenderUncertaintyConfig) -> None:
    """Render the views, then write them. A command that fails while writing (a full disk, Ctrl-C) leaves the output
    folder as it found it: an earlier render whole, a folder that existed as it was, and no folder it made itself.
    The views it had written by then are deleted with its staging folder, not kept: their colour scales were fitted
    to every view, and `eval-ause --maps` would score a part of the views as if it were the whole render."""
    config = with_views_resolved(config)
    orbit_only = [f"--{n.replace('_', '-')}" for n in ORBIT_OPTIONS
                  if getattr(config, n) != getattr(RenderUncertaintyConfig, n)]  # the class holds the defaults
    if orbit_only and config.views != "orbit":
        flags = " ".join(orbit_only)
        raise SplatuError(f"{flags} only {'applies' if len(orbit_only) == 1 else 'apply'} with --views orbit",
                          "in the command's options", f"drop {flags}, or pass --views orbit")
    if config.views == "cameras" and config.cameras is None:
        raise SplatuError("--views cameras renders the candidate cameras of a file, and none was given",
                          "in the command's options", "pass --cameras FILE (a transforms.json-style file)")
    if config.views != "cameras" and config.cameras is not None:
        raise SplatuError(f"--cameras FILE renders candidate cameras, not --views {config.views}",
                          "in the command's options", f"drop --views {config.views}, or drop --cameras")
    if config.off_centre_ok and config.cameras is None:  # the scene's own views (train, eval) render as they are
        raise SplatuError("--off-centre-ok only applies with --cameras FILE",
                          "in the command's options", "drop --off-centre-ok, or pass --cameras FILE")
    if config.cameras is not None:
        require_file(transforms_file(config.cameras), "camera file",
                     "pass the path of a transforms.json-style file of cameras, or of the folder holding it")
    config.uncertainty.check()
    config = dataclasses.replace(config, load=pinned_load(config.load, "what is written"))
    run_info, options = _load(config.load, config.uncertainty)
    config = dataclasses.replace(config, uncertainty=options)  # render.json records the method resolved
    # after loading the run, so a mistyped --load creates no folder; before the scene, so a bad --output costs nothing
    label = options.label(config.load, run_info.member_steps)
    out = creatable_dir(config.output or run_folder(config.load) / "uncertainty" / f"{label}-{config.views}",
                        "--output folder")
    refuse_foreign_output(out, config.output is None)
    earlier = file_identity(out / "render.json")
    with saying_what_is_left(lambda: left_by_a_stop(out, earlier)):
        scene, built = _setup(run_info, options, config.views)
        spec = view_spec(scene, config.views, config, run_info.config.data.downscale or 1, len(run_info.models))
        if spec.note is not None:
            Console(stderr=True).print(spec.note, soft_wrap=True)
        views, seconds = render_views(built.source, spec)
        nearest = nearest_training_views([c.world_to_camera for c in spec.cameras],
                                         [c.world_to_camera for c in scene.train.cameras], scene.train.names,
                                         spec.depth_unit)
        for view, camera, closest in zip(views, spec.cameras, nearest, strict=True):
            view.nearest_training_view = closest._asdict()
            view.source_name = camera.name or view.name
        with no_empty_folders_left(out):
            record = write_in_place(out, views, config, train_timing(run_info), built.setup_seconds, seconds,
                                    spec.orbit)
    most = max(record["per_view"], key=lambda view: view["mean_uncertainty"])
    which = "candidate" if config.views == "cameras" else config.views
    Console().print(f"rendered {len(views)} {which} view{'' if len(views) == 1 else 's'} with {options.method} "
                    f"({record['render_seconds_per_view']:.2f} s/view median) to {out}; the most uncertain is "
                    f"{most['source_name']} (mean U {most['mean_uncertainty']:.3f}, coverage {most['coverage']:.0%})",
                    soft_wrap=True)
    for line in ranking(record["per_view"]):
        Console().print(line, soft_wrap=True, highlight=False, markup=False)  # a file_path may hold [brackets]
    note = None if config.views != "cameras" else blind_candidates_note(record["per_view"], config.cameras)
    if note is not None:
        Console(stderr=True).print(note, soft_wrap=True, highlight=False, markup=False)


BLIND_COVERAGE = 0.01
"""A candidate whose model covers less than this of its pixels sees (next to) nothing of the scene."""


def blind_candidates_note(per_view: list[dict[str, Any]], cameras: Path | None) -> str | None:
    """A note when no candidate sees the model: their poses are then likely in another frame (another scene's, a
    viewer's, or a COLMAP world-to-camera not inverted), and ranking them by U ranks only empty space."""
    if not per_view or max(view["coverage"] for view in per_view) >= BLIND_COVERAGE:
        return None
    return (f"note: none of the {len(per_view)} candidate cameras of {cameras} sees the model (each covers under "
            f"{BLIND_COVERAGE:.0%} of its pixels); if they should, give their poses in the data's own frame, the frame "
            "of the scene's camera poses (see --cameras in --help), not another scene's or a viewer's")


RANKED = 5
"""Views the command lists by mean U after its summary: candidates of empty space tie at the top, and the summary's
one name was the first of them."""


def ranking(per_view: list[dict[str, Any]]) -> list[str]:
    """The `RANKED` views of highest mean U, one line each with its coverage and nearest training view (render.json
    holds them all); nothing for a single view, which the summary names."""
    if len(per_view) < 2:
        return []
    ranked = sorted(per_view, key=lambda view: -view["mean_uncertainty"])[:RANKED]
    lines = [f"by mean U ({len(ranked)} of {len(per_view)}; render.json lists every view):"]
    for place, view in enumerate(ranked, 1):
        nearest = view["nearest_training_view"]
        seen = "" if nearest is None else f", {nearest['angle_degrees']:.1f}° from {nearest['name']}"
        lines.append(f"  {place}. {view['source_name']} (mean U {view['mean_uncertainty']:.3f}, coverage "
                     f"{view['coverage']:.0%}{seen})")
    return lines


def left_by_a_stop(out: Path, earlier: tuple[int, int] | None) -> str:
    """What a Ctrl-C or SIGTERM left in `out`, whose render.json was `earlier` (`file_identity`): a render is written
    in staging and swapped in whole (`write_in_place`), and a stop during the swap waits for its end; only a second
    stop there cuts it short."""
    if (out / SWAPPING).exists():
        return (f"a second stop cut short the swap of the new render into {out}, which may hold parts of it and of "
                "the earlier one; run the command again to write it whole")
    return what_a_stop_left(out / "render.json", earlier, "render", out)


def write_in_place(out: Path, views: list[RenderedView], config: RenderUncertaintyConfig,
                   training: dict[str, float | None], setup_seconds: float, seconds: list[float],
                   orbit: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write the render into a staging folder inside `out`, then swap it in whole (see `swap_in`); the staging
    folder is removed whatever happens (a SIGTERM too: `run` calls it within `saying_what_is_left`, where SIGTERM
    unwinds as Ctrl-C does). Returns what render.json holds."""
    remove(leftover_temporaries(out, STAGING))  # a render killed outright (SIGKILL, OOM) left its staging
    staging = temporary_sibling(out / STAGING)
    try:
        record = write_render(staging, views, config, training, setup_seconds, seconds, orbit)
        swap_in(staging, out)
    except OSError as err:  # a full disk: np.save and matplotlib raise it as it is
        if os_error_behind(err) is None:
            raise
        raise unwritable_folder(out, err) from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return record


def write_render(out: Path, views: list[RenderedView], config: RenderUncertaintyConfig,
                 training: dict[str, float | None], setup_seconds: float, seconds: list[float],
                 orbit: dict[str, Any] | None = None) -> dict[str, Any]:
    """Every file of a render, render.json last (`training`: `train_timing`; `orbit`: `OrbitPlan.record` for
    --views orbit); returns what render.json holds."""
    scales = write_outputs(out, views, config.views == "orbit", config.gif_fps)
    record = {
        **config.uncertainty.record(), "views": config.views,
        # the file --views cameras ranked: every candidate file renders into the same default folder
        "cameras": None if config.cameras is None else str(transforms_file(config.cameras).resolve()),
        "orbit": orbit,
        **training, "setup_seconds": setup_seconds,
        "render_seconds_per_view": float(np.median(seconds)),
        "uncertainty_scale": [scales["uncertainty"].vmin, scales["uncertainty"].vmax],
        # the depths, in data units, that the depth PNGs' viridis runs between (beyond them it saturates), so a
        # depth can be read back from a PNG; black there is alpha 0, where the raw depth is 0
        "depth_scale": [scales["depth"].vmin, scales["depth"].vmax],
        # name: the stem of the view's files; source_name: the name the scene or --cameras gave it (close0.2, whose
        # files are close0_*), to match a ranking to the candidates, to scene_cameras and to nearest_training_view
        "per_view": [{"name": v.name, "source_name": v.source_name,
                      "mean_uncertainty": float(v.maps["uncertainty"].mean()),
                      "coverage": float(v.maps["alpha"].mean()),  # empty space reads the highest U (not the ensemble's)
                      "elevation_degrees": v.elevation_degrees, "nearest_training_view": v.nearest_training_view}
                     for v in views],
    }
    atomic_write_text(out / "render.json", json.dumps(record, indent=2), FREE_AND_RERUN)
    return record
