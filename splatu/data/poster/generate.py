"""Build the poster stand-in on disk in nerfstudio format, with ground truth, cached by config.

Output (under cache_root/poster-standin-<hash>/): transforms.json, images/*.png (RGB),
depth/*.npy (float32 camera z), observed/*.png (255 where a training camera sees the pixel's
surface point, else 0) and points3D.ply (initial points). Every pixel hits a real surface
(the room's floor, walls or ceiling at worst), so depth and the observed mask are defined
everywhere. The directory appears atomically, so a second call, or a concurrent one, finds it
complete or not at all.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from splatu.atomic import temporary_sibling
from splatu.data.frames import STANDIN_KEY, opengl_camera_to_world
from splatu.data.images import write_png
from splatu.data.ply import write_ply_points
from splatu.data.poster.config import PosterConfig
from splatu.data.poster.geometry import TARGET, build_scene
from splatu.data.poster.path import camera_path
from splatu.data.poster.render import render
from splatu.data.poster.visibility import observed_mask
from splatu.data.splits import contiguous_split
from splatu.errors import SplatuError
from splatu.train_progress import view_progress

GENERATOR_VERSION = 1
"""Bump when the generator's output changes, so that old caches are not reused."""


def validate(cfg: PosterConfig) -> None:
    """Reject settings that cannot make a usable scene, with a one-line error."""
    checks = [
        (cfg.frames >= 4, f"frames={cfg.frames} is too few", "use 4 or more (--poster.frames)"),
        (cfg.width >= 8 and cfg.height >= 8, f"image size {cfg.width}x{cfg.height} is too small", "use 8 px or more"),
        (cfg.interp_every >= 2, f"interp_every={cfg.interp_every} must be at least 2", "use 8 (the default)"),
        (cfg.points >= 0, f"points={cfg.points} is negative", "use 0 or more initial points"),
        (cfg.point_noise >= 0, f"point_noise={cfg.point_noise} is negative", "use e.g. 0.005"),
        (cfg.supersample >= 1, f"supersample={cfg.supersample} must be at least 1", "use 1 or 2"),
        (1 <= cfg.vertical_fov_degrees <= 150, f"vertical_fov_degrees={cfg.vertical_fov_degrees} is out of range",
         "use a value between 1 and 150"),
        (0 < cfg.arc_degrees <= 360, f"arc_degrees={cfg.arc_degrees} is out of range", "use a value in (0, 360]"),
    ]
    for ok, what, fix in checks:
        if not ok:
            raise SplatuError(what, "in the poster stand-in settings", fix)


def standin_splits(cfg: PosterConfig) -> tuple[list[int], list[int], list[int]]:
    """(train, val, test) frame indices: val is the seeded contiguous block (an unseen angle); of the
    rest, every interp_every-th frame, counted from mid-stride, is test. Most test frames lie between two training
    frames; one next to the block or at an end of the path has a training frame on one side only (141 and 149 of the
    default 150 frames: 2 of the 15 `interp` views)."""
    remaining, val = contiguous_split(cfg.frames, cfg.eval_block, cfg.seed, "--poster.eval-block",
                                      "in the poster stand-in settings")
    offset = cfg.interp_every // 2
    test = [f for k, f in enumerate(remaining) if k % cfg.interp_every == offset]
    train = [f for k, f in enumerate(remaining) if k % cfg.interp_every != offset]
    if not test or len(train) < 2:
        raise SplatuError(
            f"{cfg.frames} frames less a block of {cfg.eval_block} leave {len(train)} train, {len(test)} test frames",
            "in the poster stand-in settings", "use more frames, a smaller eval block or a smaller interp_every",
        )
    return train, val, test


def cache_key(cfg: PosterConfig) -> str:
    blob = json.dumps({"generator_version": GENERATOR_VERSION, "config": asdict(cfg)}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


CACHE_FIX = ("free space on that disk (it takes about 32 MB), or pass --cache-dir or set SPLATU_CACHE to a writable "
             "folder")


def _generate(cfg: PosterConfig, out: Path) -> None:
    """Render every frame of the stand-in into `out`, counted by a bar on a terminal only (a first `--data poster`
    waits ~11 s for it; off a terminal, loading a scene says nothing)."""
    scene = build_scene()
    cameras = camera_path(cfg)
    train, val, test = standin_splits(cfg)
    train_cameras = [cameras[i] for i in train]
    train_set = set(train)
    generator = torch.Generator().manual_seed(cfg.seed)
    target = torch.tensor(TARGET, dtype=torch.float64)
    noise_std = cfg.point_noise * float(torch.stack([c.center() - target for c in cameras]).norm(dim=1).mean())
    quota = [cfg.points // len(train) + (1 if k < cfg.points % len(train) else 0) for k in range(len(train))]
    point_xyz, point_rgb = [], []
    for sub in ("images", "depth", "observed"):
        (out / sub).mkdir(parents=True)
    frames = []
    with view_progress() as bar:
        for index, camera in enumerate(bar.track(cameras, description="building the poster stand-in")):
            view = render(scene, camera, cfg.supersample)
            if not bool(torch.isfinite(view.depth).all()):
                raise AssertionError(f"ray missed every surface in {camera.name}; the room must enclose all cameras")
            rgb8 = (view.rgb * 255.0).round().clamp(0, 255).to(torch.uint8).numpy()
            seen = observed_mask(scene, view.points, train_cameras, camera.center().double())
            write_png(out / "images" / f"{camera.name}.png", rgb8, CACHE_FIX)
            np.save(out / "depth" / f"{camera.name}.npy", view.depth.to(torch.float32).numpy())
            write_png(out / "observed" / f"{camera.name}.png",
                      (seen.reshape(cfg.height, cfg.width).to(torch.uint8) * 255).numpy(), CACHE_FIX)
            if index in train_set:
                picks = torch.randperm(cfg.width * cfg.height, generator=generator)[: quota[len(point_xyz)]]
                noise = noise_std * torch.randn(picks.numel(), 3, generator=generator, dtype=torch.float64)
                point_xyz.append((view.points[picks] + noise).numpy())
                point_rgb.append(rgb8.reshape(-1, 3)[picks.numpy()])
            frames.append({
                "file_path": f"images/{camera.name}.png",
                "transform_matrix": opengl_camera_to_world(camera),
                "depth_file_path": f"depth/{camera.name}.npy",
                "observed_mask_path": f"observed/{camera.name}.png",
            })
    write_ply_points(out / "points3D.ply", np.concatenate(point_xyz), np.concatenate(point_rgb) / 255.0)
    K = cameras[0].K
    transforms = {
        "camera_model": "PINHOLE",
        "fl_x": float(K[0, 0]), "fl_y": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
        "w": cfg.width, "h": cfg.height,
        "frames": frames,
        "train_filenames": [frames[i]["file_path"] for i in train],
        "val_filenames": [frames[i]["file_path"] for i in val],
        "test_filenames": [frames[i]["file_path"] for i in test],
        "ply_file_path": "points3D.ply",
        STANDIN_KEY: {
            "generator_version": GENERATOR_VERSION,
            "config": asdict(cfg),
            "world": "metres, +z up; the chair stands at the origin facing +y",
            "depth": "float32 camera-space z (OpenCV +z, along the optical axis), not ray length",
            "observed": "255 where the pixel's first-hit surface point is seen, unoccluded, by a training camera",
            "val": "a contiguous block of the path (an unseen angle)",
            "test": "every interp_every-th remaining frame (interpolation)",
        },
    }
    (out / "transforms.json").write_text(json.dumps(transforms, indent=2) + "\n", encoding="utf-8")


@contextmanager
def _single_thread() -> Iterator[None]:
    """Run torch on one thread: its small elementwise ops gain little from two, and on a shared
    2-core machine two threads that spin waiting for each other ran far slower than one."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def build_poster_standin(cfg: PosterConfig, cache_root: Path) -> Path:
    """Directory of the stand-in for `cfg` under cache_root, generating it on the first call only."""
    validate(cfg)
    standin_splits(cfg)
    final = Path(cache_root) / f"poster-standin-{cache_key(cfg)}"
    if (final / "transforms.json").is_file():
        return final
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SplatuError(f"cannot create the cache directory ({err.strerror})", f"in {final.parent}",
                          "choose a writable cache directory") from err
    staging = temporary_sibling(final)
    shutil.rmtree(staging, ignore_errors=True)
    try:
        with _single_thread():
            _generate(cfg, staging)
        os.rename(staging, final)
    except OSError as err:
        if not (final / "transforms.json").is_file():  # else another process finished it first: use that one
            raise SplatuError(f"could not write the built-in scene ({err.strerror or err})", f"in {final.parent}",
                              CACHE_FIX) from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return final
