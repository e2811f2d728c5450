"""`--data NAME`: find the scene, detect its format, and load it as a Scene (or, its images left undecoded, as a
CameraScene).

`poster` means nerfstudio's real poster capture when the user has it (data/nerfstudio/poster
or $SPLATU_DATA/poster), else the built-in stand-in; anything else is a path, loaded by
format detection: nerfstudio transforms.json, NeRF-synthetic transforms_{train,val,test}.json,
or a COLMAP model (sparse/0, bin or txt).
"""

from __future__ import annotations

import dataclasses
import os
import shlex
from pathlib import Path

from splatu.config_values import changed_options
from splatu.data.assemble import MIN_DOWNSCALED_SIDE, assemble, assemble_cameras
from splatu.data.blender import is_blender, load_blender
from splatu.data.colmap import empty_sparse_dir, find_sparse_dir, load_colmap, scene_root_of
from splatu.data.config import DataConfig
from splatu.data.frames import RawScene, downscaled
from splatu.data.images import IMAGE_SUFFIXES, ImageCache, default_cache_dir
from splatu.data.nerfstudio import load_nerfstudio
from splatu.data.poster import build_poster_standin
from splatu.data.poster.config import PosterConfig
from splatu.data.scene import CameraScene, Scene
from splatu.errors import DownscaleError, SplatuError

POSTER = "poster"


def real_poster_candidates() -> list[Path]:
    """Where the real poster capture may live, in order."""
    places = [Path("data/nerfstudio/poster")]
    if os.environ.get("SPLATU_DATA"):
        places.append(Path(os.environ["SPLATU_DATA"]) / "poster")
    return places


def read_scene_files(path: Path, background: tuple[float, float, float], warn_off_centre: bool = True) -> RawScene:
    """Parse a scene folder or file by its format, at full size (`downscaled` gives it another), without decoding any
    image; `warn_off_centre` False leaves out the loaders' warning about principal points far off-centre, for a
    query of a scene its run already warned of."""
    if not path.exists():
        raise SplatuError("scene not found", f"in {path}",
                          "pass --data poster or the path of a nerfstudio, COLMAP or NeRF-synthetic scene")
    if path.is_file():
        if path.name.startswith("transforms_") and is_blender(path.parent):
            return load_blender(path.parent, background)
        if path.suffix == ".json":
            return load_nerfstudio(path, background, warn_off_centre)
    elif (path / "transforms.json").is_file():
        return load_nerfstudio(path, background, warn_off_centre)
    elif is_blender(path):
        return load_blender(path, background)
    elif (sparse := find_sparse_dir(path)) is not None:
        return load_colmap(path, sparse, warn_off_centre)
    elif (root := scene_root_of(path)) is not None:
        return load_colmap(root, path, warn_off_centre)
    elif (empty := empty_sparse_dir(path)) is not None:
        raise SplatuError("the COLMAP model folder is empty (no cameras, images or points3D file)", f"in {empty}",
                          "run the reconstruction again (splatu process-images) or export the model into it")
    raise unknown_format_error(path)


def is_scene_folder(path: Path) -> bool:
    """Whether `read_scene_files` finds a scene format directly in the folder `path`."""
    return (path / "transforms.json").is_file() or is_blender(path) or find_sparse_dir(path) is not None


def unknown_format_error(path: Path) -> SplatuError:
    """The error for a `--data` path with no scene format, with the likeliest fix: a scene's images/ or sparse/
    folder given for the scene itself names the scene folder, and a folder of bare photos (no poses yet) names
    `splatu process-images`, which makes the COLMAP model it needs."""
    what = "unknown scene format: no transforms.json, transforms_train.json or COLMAP sparse/0"
    if path.is_dir() and is_scene_folder(path.parent):
        return SplatuError(what, f"in {path}",
                           f"pass the scene folder it is in: --data {shlex.quote(str(path.parent))}")
    try:
        photos = sum(1 for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES) if path.is_dir() else 0
    except OSError:  # a folder it may not list: the plain error, not a traceback
        photos = 0
    if photos:
        held = f"{photos} photo{'s' if photos > 1 else ''}"
        return SplatuError(f"{what}; the folder holds {held} but no camera poses", f"in {path}",
                           f"run `splatu process-images {shlex.quote(str(path))}` first: it estimates them and "
                           "prints the train line")
    return SplatuError(what, f"in {path}", "point --data at a nerfstudio, NeRF-synthetic or COLMAP scene folder")


def colmap_data_path(root: Path) -> Path:
    """What `--data` must name to load the COLMAP model in root/sparse/0: the folder itself, unless a
    transforms.json or NeRF-synthetic split there wins over it in `read_scene_files`."""
    return root / "sparse" / "0" if (root / "transforms.json").is_file() or is_blender(root) else root


def real_poster_capture() -> Path | None:
    """The first place that holds the real poster capture, if any."""
    return next((place for place in real_poster_candidates() if (place / "transforms.json").is_file()), None)


def scene_path(cfg: DataConfig) -> Path:
    """The folder or file `--data` names; for `poster`, the real capture or the stand-in (built on first use, then
    cached). Nothing is printed here: the loaded scene is marked `stand_in`, and `train` says so in its scene line,
    once, rather than every command that loads it."""
    if cfg.data != POSTER:
        return Path(cfg.data).expanduser()
    return real_poster_capture() or build_poster_standin(cfg.poster, cfg.cache_dir or default_cache_dir())


def refuse_unused_poster_options(cfg: DataConfig) -> None:
    """A new run's `--poster.*` options must shape the scene it trains on: they build the stand-in only, so they
    are refused on another scene, and when the real capture is found and used instead. Saved configs still load."""
    changed = [f"--poster.{name.replace('_', '-')}" for name in changed_options(cfg.poster, PosterConfig())]
    if not changed:
        return
    flags, shape = ", ".join(changed), "shapes" if len(changed) == 1 else "shape"
    if cfg.data != POSTER:
        raise SplatuError(f"{flags} only {shape} the built-in poster stand-in, not --data {cfg.data}",
                          "in the options", f"drop {flags}")
    real = real_poster_capture()
    if real is not None:
        raise SplatuError(f"{flags} {shape} the built-in stand-in, but --data poster trains on the real capture",
                          f"in {real}", f"drop {flags}, or move the capture away to train on the stand-in")


def with_chosen_downscale(cfg: DataConfig, raw: RawScene) -> DataConfig:
    """`cfg` with --downscale chosen, from the sizes of its scene `raw` as parsed, when it is not given: the smallest
    power of two that brings every image's longer side to --max-image-size or less (nerfstudio's rule), short of
    shrinking a side below MIN_DOWNSCALED_SIDE. A new run records the factor in its config, so its renders and
    resumes load the same sizes; a saved config without one (older runs) loads at full size, as it trained."""
    if cfg.downscale is not None:
        return cfg
    sizes = [(f.camera.width, f.camera.height) for f in raw.frames]
    longest, shortest = max(max(size) for size in sizes), min(min(size) for size in sizes)
    factor = 1
    while longest / factor > cfg.max_image_size and shortest // (2 * factor) >= MIN_DOWNSCALED_SIDE:
        factor *= 2
    return dataclasses.replace(cfg, downscale=factor)


def downscale_note(given: DataConfig, chosen: DataConfig, longest: int) -> str | None:
    """What `train` says when it chose the downscale itself and shrank the images: the factor and how to undo it.
    `longest` is the longer side of the largest image as loaded: above --max-image-size when a smaller fraction
    would have shrunk a side below MIN_DOWNSCALED_SIDE."""
    if given.downscale is not None or chosen.downscale in (None, 1):
        return None
    limit = chosen.max_image_size
    size = (f"their longer side at most {limit} px (--max-image-size)" if longest <= limit else
            f"their longer side still above {limit} px (--max-image-size), as a smaller fraction would shrink a side "
            f"below {MIN_DOWNSCALED_SIDE} px")
    return (f"note: images loaded at 1/{chosen.downscale} of their size, {size}; --downscale 1 trains at full size, "
            "with slower steps")


def new_run_error(err: DownscaleError, given: DataConfig) -> SplatuError:
    """`err`, raised loading a new run's scene, with what only a new run can do: train at full size without the
    copy (a saved run loads at the factor its config.yml records, so resume, render and the rest are told only to
    make the copy again or remove it). A factor `train` chose itself (`given` has no --downscale) is said to be its
    choice, with the flag that sets another: the user typed none."""
    what = err.what if given.downscale is not None else (
        f"{err.what} (1/{err.factor} is the factor train chose to bring the images within --max-image-size "
        f"{given.max_image_size}; --downscale N sets another)")
    fix = f"{err.fix} (or train at full size with --downscale 1)" if err.copy_at_fault else err.fix
    return SplatuError(what, err.where, fix)


def read_scene(cfg: DataConfig) -> RawScene:
    """The scene `cfg` names, parsed at full size; the real poster capture or the stand-in, named or given by its
    path, is filed under "poster"."""
    cfg.validate()
    raw = read_scene_files(scene_path(cfg), cfg.background)
    if cfg.data == POSTER or raw.stand_in:
        raw.name = POSTER
    return raw


def assemble_scene(raw: RawScene, cfg: DataConfig) -> Scene:
    """Parsed scene `raw` at `cfg`'s downscale (full size without one: a run saved before train chose it), split,
    normalised and decoded (through the on-disk image cache)."""
    return assemble(downscaled(raw, cfg.downscale or 1), cfg, ImageCache(cfg.cache_dir or default_cache_dir()))


def load_scene(cfg: DataConfig) -> Scene:
    """The scene `cfg` names, split, normalised and decoded."""
    return assemble_scene(read_scene(cfg), cfg)


def load_new_scene(given: DataConfig) -> tuple[DataConfig, Scene]:
    """A new run's options, with the downscale chosen when not `given` (`with_chosen_downscale`), and its scene: the
    scene's files are parsed once, for the factor and the scene both."""
    raw = read_scene(given)
    cfg = with_chosen_downscale(given, raw)
    try:
        return cfg, assemble_scene(raw, cfg)
    except DownscaleError as err:
        raise new_run_error(err, given) from None


def load_camera_scene(cfg: DataConfig, masks: bool = False) -> CameraScene:
    """The scene `cfg` names as `load_scene` splits and normalises it, without decoding its images (with its training
    mask files when `masks` asks for them): for renders that need no ground truth (`CameraScene`)."""
    raw = downscaled(read_scene(cfg), cfg.downscale or 1)
    return assemble_cameras(raw, cfg, ImageCache(cfg.cache_dir or default_cache_dir()), masks)
