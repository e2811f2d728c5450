"""From a parsed scene file to a Scene: choose the split, normalise, decode the pixels.

Shared by every format, so splits, normalisation, size checks and the image cache behave
the same whatever the input was.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from splatu.data.config import DataConfig
from splatu.data.frames import Frame, RawScene
from splatu.data.images import ImageCache, PixelRecipe, load_pixels
from splatu.data.normalize import (
    coincident_within,
    coordinate_size,
    normalization,
    normalize_camera,
    normalize_points,
)
from splatu.data.scene import CameraScene, CameraViews, PerView, Scene, Views, per_view
from splatu.data.splits import contiguous_split, every_n_split, list_split
from splatu.errors import SplatuError

DEFAULT_EVAL_FRACTION = 0.22
"""eval_block=0 holds out this fraction of frames (the paper held out 50 of 226 poster frames)."""
MIN_DOWNSCALED_SIDE = 8
"""--downscale may not shrink an image below this many pixels a side: there would be nothing to train on."""


def _read_eval_list(path: Path | None) -> list[str]:
    """The names an --eval-list file holds. It is read as UTF-8 with or without a byte-order mark (Windows editors
    write one, and it made the first name unknown); other bytes were a UnicodeDecodeError traceback."""
    if path is None:
        raise SplatuError("eval split `list` needs a list file", "in --eval-list",
                          "pass --eval-list FILE with one image name per line")
    if not path.is_file():
        raise SplatuError("eval list file not found", f"in {path}", "pass an existing --eval-list file")
    try:  # decoded whole, the mark removed after: utf-8-sig would count a bad byte's offset from after the mark
        text = path.read_bytes().decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError as err:
        raise SplatuError(f"eval list is not UTF-8 text (byte {err.start})", f"in {path}",
                          "save it as UTF-8, one image name per line") from None
    return [line.strip().removeprefix("./") for line in text.splitlines() if line.strip()]


def choose_split(raw: RawScene, cfg: DataConfig) -> tuple[list[int], list[int], dict[str, list[int]], bool]:
    """(train, eval, extra eval sets, whether the split is the file's own) as frame indices."""
    n_frames = len(raw.frames)
    if n_frames < 2:
        raise SplatuError(f"too few images ({n_frames}): training and evaluation need at least 2",
                          f"in {raw.source}", "add more images to the scene")
    extras: dict[str, list[int]] = {}
    own = cfg.eval_split == "auto" and "train" in raw.file_splits and "eval" in raw.file_splits
    if own:
        train, held_out = raw.file_splits["train"], raw.file_splits["eval"]
        extras = {k: v for k, v in raw.file_splits.items() if k not in ("train", "eval")}
    elif cfg.eval_split in ("auto", "contiguous"):
        block = cfg.eval_block or max(1, round(DEFAULT_EVAL_FRACTION * n_frames))
        train, held_out = contiguous_split(n_frames, block, cfg.split_seed, where=f"in {raw.source}")
    elif cfg.eval_split == "every-n":
        train, held_out = every_n_split(n_frames, cfg.eval_every)
    else:
        names = [f.name for f in raw.frames]
        train, held_out = list_split(names, _read_eval_list(cfg.eval_list), str(cfg.eval_list))
    for split, indices in (("train", train), ("eval", held_out)):
        if not indices:
            raise SplatuError(f"the {split} split is empty", f"in {raw.source}",
                              "choose another --eval-split or fix the scene's split lists")
    return train, held_out, extras, own


def check_downscaled_size(frames: list[Frame], downscale: int) -> None:
    """Refuse a --downscale that leaves images too small to train on, naming the largest usable one. The factor
    was typed or saved: the one `train` chooses itself never shrinks a side below MIN_DOWNSCALED_SIDE."""
    for frame in frames:
        width, height = frame.camera.width, frame.camera.height
        if downscale > 1 and min(width, height) < MIN_DOWNSCALED_SIDE:
            full_w, full_h = frame.image.width, frame.image.height
            largest = min(full_w, full_h) // MIN_DOWNSCALED_SIDE
            what = (f"the {full_w}x{full_h} image is already below {MIN_DOWNSCALED_SIDE} px a side, too small for "
                    f"--downscale {downscale}" if min(full_w, full_h) < MIN_DOWNSCALED_SIDE else
                    f"--downscale {downscale} shrinks the {full_w}x{full_h} image to {width}x{height} px, below "
                    f"{MIN_DOWNSCALED_SIDE} px a side")
            raise SplatuError(what, f"in {frame.image.path}",
                              f"pass --downscale {largest} or less" if largest > 1 else "drop --downscale")


def _decode(recipes: list[PixelRecipe | None], cache: ImageCache) -> list[np.ndarray | None]:
    return [None if r is None else load_pixels(r, cache) for r in recipes]


def _ones_where_missing(arrays: list[np.ndarray | None], frames: list[Frame]) -> list[np.ndarray] | None:
    """Per-frame (H, W) float32 arrays, ones of its camera's size for a frame that has none; None when none has one."""
    if all(a is None for a in arrays):
        return None
    return [np.ones((f.camera.height, f.camera.width), np.float32) if a is None else np.ascontiguousarray(a)
            for a, f in zip(arrays, frames, strict=True)]


def _per_view(arrays: list[np.ndarray] | None) -> PerView | None:
    return None if arrays is None else per_view([torch.from_numpy(a) for a in arrays])


def _mask_files(frames: list[Frame], cache: ImageCache) -> list[np.ndarray] | None:
    """The split's mask files as `Views.mask_files` holds them, None when no frame has one."""
    masks = _decode([f.mask for f in frames], cache)
    return _ones_where_missing([None if m is None else (m > 0).astype(np.float32) for m in masks], frames)


def build_views(frames: list[Frame], center: torch.Tensor, scale: float, cache: ImageCache,
                keep_observed: bool) -> Views:
    """Decode one split's frames, each at its camera's size: stacked when they share one, else per view (`PerView`).

    object_masks: float32 (H, W) per view in [0, 1], alpha times any mask file, when any frame has one;
    alphas: float32 (H, W), the image alpha alone (1 for opaque frames), when any frame is RGBA;
    mask_files: float32 (H, W), the mask files alone (1 for frames without one), when any frame has one, each
    0 where its file is 0 and 1 elsewhere, as nerfstudio reads them (a mask saved as 0/1 weighted the pixels it
    keeps by 1/255, training on near-black images and scoring them at 59 dB);
    depths: float32 (H, W) camera z in normalised units; observed: bool (H, W). Ground
    truth that only some frames of the split have is left out (None) rather than padded.
    """
    pixels = _decode([f.image for f in frames], cache)
    images = per_view([torch.from_numpy(np.ascontiguousarray(p[..., :3], np.float32)) for p in pixels])
    alphas = _ones_where_missing([p[..., 3] if p.shape[-1] == 4 else None for p in pixels], frames)
    masks = _mask_files(frames, cache)
    alpha, mask_files = _per_view(alphas), _per_view(masks)
    object_masks = (alpha if mask_files is None else mask_files if alphas is None
                    else _per_view([a * m for a, m in zip(alphas, masks, strict=True)]))
    depths = _decode([f.depth for f in frames], cache)
    observed = _decode([f.observed for f in frames], cache) if keep_observed else [None]
    return Views(
        cameras=[normalize_camera(f.camera, center, scale).to(dtype=torch.float32) for f in frames],
        images=images,
        names=[f.name for f in frames],
        object_masks=object_masks,
        depths=(per_view([torch.from_numpy(d * np.float32(scale)) for d in depths])
                if all(d is not None for d in depths) else None),
        observed=per_view([torch.from_numpy(o > 0.5) for o in observed]) if all(o is not None for o in observed)
        else None,
        alphas=alpha,
        alpha_background=frames[0].image.background,
        mask_files=mask_files,
    )


OUTLYING_CAMERA_RATIO = 1e6
"""A camera this many times farther from the cameras' median position than their median distance to it is a
broken pose, not a capture: normalisation would squeeze every other camera to within float32 rounding of a point."""


def refuse_outlying_camera(frames: list[Frame], centers: torch.Tensor, source: str) -> None:
    """One line naming the frame whose camera sits absurdly far from all the others (e.g. a translation of 1e20)."""
    distance = (centers - centers.median(dim=0).values).norm(dim=-1)
    typical, worst = float(distance.median()), int(distance.argmax())
    farthest = float(distance[worst])
    if typical > coincident_within(centers):
        if farthest > OUTLYING_CAMERA_RATIO * typical:
            raise SplatuError(f"the camera of {frames[worst].name!r} is {farthest / typical:.3g} times farther from "
                              "the others' median position than they are", f"in {source}",
                              "fix or remove that frame's pose")
    # cameras that coincide but for rounding (a capture turning on one spot) have no typical distance: their
    # coordinates' own size stands in (1e6 m from a capture in metres, 3e12 from one at geo-referenced 3e6)
    elif farthest > OUTLYING_CAMERA_RATIO * coordinate_size(centers):
        raise SplatuError(f"the camera of {frames[worst].name!r} is {farthest:.3g} from the position most cameras "
                          f"share, over {OUTLYING_CAMERA_RATIO:.0e} times the size of their coordinates",
                          f"in {source}", "fix or remove that frame's pose")


def scene_normalization(raw: RawScene) -> tuple[torch.Tensor, float]:
    """The (centre, scale) a parsed scene is normalised with: the cameras of all its frames define them, so the
    split does not move the frame (and `splatu.query` finds the same one from the files alone)."""
    centers = torch.stack([f.camera.center() for f in raw.frames])
    refuse_outlying_camera(raw.frames, centers, raw.source)
    return normalization(centers)


def assemble(raw: RawScene, cfg: DataConfig, cache: ImageCache) -> Scene:
    """Split, normalise (`scene_normalization`) and decode a parsed scene."""
    check_downscaled_size(raw.frames, cfg.downscale or 1)
    train, held_out, extras, own = choose_split(raw, cfg)
    center, scale = scene_normalization(raw)
    points = torch.as_tensor(np.asarray(raw.points, dtype=np.float64)).reshape(-1, 3)

    def views(indices: list[int]) -> Views:
        return build_views([raw.frames[i] for i in indices], center, scale, cache, keep_observed=own)

    return Scene(
        name=raw.name,
        source=raw.source,
        train=views(train),
        eval=views(held_out),
        points=normalize_points(points, center, scale).to(torch.float32),
        point_colors=None if raw.point_colors is None else torch.as_tensor(raw.point_colors, dtype=torch.float32),
        center=center,  # float64, as the cameras were normalised: float32 is centimetres off at map coordinates
        scale=scale,
        extra_eval={name: views(indices) for name, indices in extras.items()},
        own_split=own,
        stand_in=raw.stand_in,
    )


def assemble_cameras(raw: RawScene, cfg: DataConfig, cache: ImageCache, masks: bool) -> CameraScene:
    """Split and normalise a parsed scene as `assemble` does, decoding no image: its training cameras, with their
    mask files when `masks` asks for them."""
    check_downscaled_size(raw.frames, cfg.downscale or 1)
    train = [raw.frames[i] for i in choose_split(raw, cfg)[0]]
    center, scale = scene_normalization(raw)
    return CameraScene(center, scale, CameraViews(
        [normalize_camera(f.camera, center, scale).to(dtype=torch.float32) for f in train], [f.name for f in train],
        _per_view(_mask_files(train, cache)) if masks else None))


def refuse_split_flags_the_scene_overrides(cfg: DataConfig, scene: Scene) -> None:
    """A new run's --eval-block and --split-seed must shape its split: refused when the scene's file brings its
    own. Only new runs check this; a saved config that carried an ignored one still loads."""
    if (cfg.eval_block or cfg.split_seed) and scene.own_split:
        flag, poster_flag = ("--eval-block", "--poster.eval-block") if cfg.eval_block else ("--split-seed",
                                                                                          "--poster.seed")
        stand_in = f" (the built-in poster's is {poster_flag})" if scene.name == "poster" else ""
        raise SplatuError(f"{flag} is not used: the scene has its own train/eval split", f"in {scene.source}",
                          f"drop {flag}{stand_in}, or pass --eval-split contiguous to split by blocks")
