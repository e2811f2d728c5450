"""What a loader returns before splitting: every frame's camera and pixel recipes, plus points.

Loaders only parse their format, at full size; downscaling, splitting, normalisation and decoding are shared
(splatu/data/assemble.py), so every format behaves the same way.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from splatu.camera import Camera
from splatu.data.images import PixelRecipe
from splatu.errors import SplatuError

OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
"""Flips camera y and z: OpenGL/Blender axes (y up, looking along -z) to OpenCV (y down, +z forward)."""
FLOAT32_MAX = float(np.finfo(np.float32).max)
"""Cameras train in float32: a pose value beyond this is finite in the file but infinite in training."""
MAX_IMAGE_SIDE = 1 << 16
"""Larger than any camera's image side: pycolmap stores sizes unsigned, so a negative one reads as ~1.8e19, and
OpenCV's undistortion takes 32-bit sizes, so a nerfstudio w of 3e9 was an OpenCV traceback."""

RENDER_BYTES_PER_PIXEL = 240
"""Peak memory one render of one model takes per pixel: 206 bytes on the poster run (its 2000-step ours run) from
1920×1080 to 5120×2880 (peak RSS 985 to 3481 MiB), 226 between 3840×2160 and 5120×2880, read as resource.getrusage's
ru_maxrss after `open_run(RUN).render(w2c, K, W, H)` of its first scene camera with K scaled to W×H, one process per
size; `/usr/bin/time -v splatu render-uncertainty --load RUN --cameras FILE` of that camera at 3840×2160 peaked at
2.2 GB, at 1920×1080 at 1.1 GB."""
MEMBER_BYTES_PER_PIXEL = 25
"""What each further ensemble member adds per pixel: 10 members at 1920×1080 peaked 1113 MiB above their loading,
one model 653 MiB (the members' renders are all held to take their std)."""
RETAINED_BYTES_PER_PIXEL = 6 * 8
"""What render-uncertainty holds per pixel of each view rendered until all are written: rgb, depth, alpha and U as
float64."""
RENDER_BASE_BYTES = 1 << 30
"""Python, torch, the model and matplotlib: render-uncertainty's peak RSS at a few pixels was 0.7 GB on the poster."""


def physical_memory() -> int | None:
    """The machine's physical memory in bytes, or None where the OS does not say (os.sysconf is POSIX)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


NO_CGROUP_LIMIT = 1 << 62
"""cgroup v1 writes "no limit" as about 2⁶³ rounded down to a page (9223372036854771712); v2 writes "max"."""


def cgroup_memory_limit(proc_cgroup: Path = Path("/proc/self/cgroup"),
                        root: Path = Path("/sys/fs/cgroup")) -> int | None:
    """The tightest memory limit of this process's cgroup and its ancestors (v2 memory.max, v1 memory.limit_in_bytes),
    or None without one: a container's limit, not the host's memory, is where the kernel kills a render (a container
    limited to 8 GB on a 64 GB host)."""
    try:
        lines = proc_cgroup.read_text().splitlines()
    except OSError:
        return None
    limits = []
    for line in lines:
        fields = line.split(":", 2)
        if len(fields) != 3:
            continue
        _, controllers, path = fields
        if not controllers:
            base = root if (root / "cgroup.controllers").exists() else root / "unified"
            name = "memory.max"
        elif "memory" in controllers.split(","):
            base, name = root / "memory", "memory.limit_in_bytes"
        else:
            continue
        parts = [part for part in path.split("/") if part]
        for depth in range(len(parts) + 1):
            try:
                text = base.joinpath(*parts[:depth], name).read_text().strip()
            except OSError:
                continue
            if text.isdigit() and int(text) < NO_CGROUP_LIMIT:
                limits.append(int(text))
    return min(limits, default=None)


def usable_memory() -> int | None:
    """The memory this process may use: the machine's, or its container's limit where that is lower."""
    known = [limit for limit in (physical_memory(), cgroup_memory_limit()) if limit is not None]
    return min(known, default=None)


def refuse_unaffordable_render(sizes: list[tuple[int, int]], members: int, where: str, fix: str) -> None:
    """One line when rendering views of these sizes, each side within MAX_IMAGE_SIDE, would need more memory than the
    process may use (`RENDER_BYTES_PER_PIXEL`): a 14400×25600 render grew to 21 GB before the OS killed it. All but
    the largest view count only what is kept of them (`RETAINED_BYTES_PER_PIXEL`), as render-uncertainty keeps them."""
    usable = usable_memory()
    if usable is None or not sizes:
        return
    width, height = max(sizes, key=lambda size: size[0] * size[1])
    per_pixel = RENDER_BYTES_PER_PIXEL + MEMBER_BYTES_PER_PIXEL * (members - 1)
    kept = sum(w * h for w, h in sizes) - width * height
    estimate = RENDER_BASE_BYTES + per_pixel * width * height + RETAINED_BYTES_PER_PIXEL * kept
    if estimate > usable:
        views = "" if len(sizes) == 1 else f" (and {len(sizes) - 1} more views kept until written)"
        raise SplatuError(f"a {width}×{height} render{views} needs about {estimate / 1e9:.1f} GB (~{per_pixel} bytes "
                          f"per pixel), more than the {usable / 1e9:.1f} GB of memory this process may use", where, fix)


ROTATION_TOLERANCE = 1e-3
"""How far Rᵀ·R of a pose may be from the identity: poses written with a few decimals, or in float32, are off by
1e-7 to 1e-4 and render as intended; a scale of 1.001 or more (a similarity, not a pose) is refused."""

MAX_FIELD_OF_VIEW = 179.0
"""Degrees. The widest rectilinear lenses see about 120-130 degrees across (fisheyes are undistorted to a narrower
pinhole); at 179 the image's edge pixels look within half a degree of the image plane, so a wider field of view is
a focal length in other units than pixels (a phone's 4.3 mm for a 4000 px photo gives 179.8), or a typo."""
MAX_FOCAL_PER_SIDE = 1e4
"""The longest telephoto and telescope cameras have focal lengths of tens to about a thousand times their image's
larger side; 1e4 times is a field of view of 0.006 degrees, which no real capture has."""


@dataclass
class Frame:
    """One view: its undistorted pinhole camera at the target size (scene's own world units)."""

    name: str
    camera: Camera
    image: PixelRecipe
    mask: PixelRecipe | None = None
    depth: PixelRecipe | None = None
    observed: PixelRecipe | None = None
    copies: Path | None = None
    """The folder holding the image whose sibling `<its name>_N` may hold it pre-downscaled to 1/N (nerfstudio's and
    COLMAP's images_N), for formats that keep such copies."""


@dataclass
class RawScene:
    """A parsed scene file: all frames in order, initial points, and the file's own splits."""

    name: str
    source: str
    frames: list[Frame]
    points: np.ndarray  # (M, 3) float, may be empty
    point_colors: np.ndarray | None = None  # (M, 3) in [0, 1]
    file_splits: dict[str, list[int]] = field(default_factory=dict)
    """Frame indices the file itself assigns: "train", "eval", and extra eval sets by name."""
    stand_in: bool = False
    """Whether this is the built-in poster stand-in (see `Scene.stand_in`)."""


def downscaled(raw: RawScene, factor: int) -> RawScene:
    """`raw`, parsed at full size, at 1/`factor`: every camera scaled, and every file decoded to its size (the image
    from its images_N copy where there is one). One place for every format, so that `train` can choose the factor
    from the sizes of the scene it has parsed, without parsing it again."""
    if factor == 1:
        return raw
    return replace(raw, frames=[_downscaled_frame(frame, factor) for frame in raw.frames])


def _downscaled_frame(frame: Frame, factor: int) -> Frame:
    camera = frame.camera.scaled(1.0 / factor)
    size = {"target_width": camera.width, "target_height": camera.height}

    def resized(recipe: PixelRecipe | None) -> PixelRecipe | None:  # masks and depths are never pre-downscaled
        return None if recipe is None else replace(recipe, **size)

    copy = None if frame.copies is None else (frame.copies.parent / f"{frame.copies.name}_{factor}" /
                                              frame.image.path.relative_to(frame.copies))
    image = (replace(frame.image, path=copy, source_downscale=factor, full_size=frame.image.path, **size)
             if copy is not None and copy.is_file()
             else replace(frame.image, **size))
    return replace(frame, camera=camera, image=image, mask=resized(frame.mask), depth=resized(frame.depth),
                   observed=resized(frame.observed))


STANDIN_KEY = "splatu_standin"
"""The block of the built-in stand-in's transforms.json that describes it, and marks it as the stand-in however it
is loaded (`--data poster` or the path of its cached folder)."""


def checked_matrix(value: object, where: str, fix: str) -> np.ndarray:
    """A finite 4x4 rigid transform within float32's range from a JSON value (3x4 or 4x4), or a one-line error
    naming `where`. Its entries must be JSON numbers: numpy read true as 1.0 and "0.5" as 0.5 without a word."""
    rows = value if isinstance(value, list) and all(isinstance(row, list) for row in value) else []
    odd = [v for row in rows for v in row if isinstance(v, bool) or not isinstance(v, int | float)]
    if odd:
        raise SplatuError(f"pose holds {odd[0]!r}, which is not a number", where, fix)
    try:
        matrix = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        matrix = np.zeros((0,))
    if matrix.shape == (3, 4):
        matrix = np.vstack([matrix, [0.0, 0.0, 0.0, 1.0]])
    if matrix.shape != (4, 4):
        raise SplatuError("pose is not a 3x4 or 4x4 matrix", where, fix)
    if not np.isfinite(matrix).all():
        raise SplatuError("pose has non-finite values (NaN or Inf)", where, fix)
    if (largest := float(np.abs(matrix).max())) > FLOAT32_MAX:
        raise SplatuError(f"pose has a value beyond float32's range ({largest:.3g})", where, fix)
    if np.abs(matrix[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-6:  # it would be ignored: a rigid pose is read as 3x4
        raise SplatuError(f"pose's last row is {matrix[3].tolist()}, not [0, 0, 0, 1]", where, fix)
    rotation = matrix[:3, :3]
    if np.abs(rotation.T @ rotation - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(rotation) <= 0:
        raise SplatuError("pose rotation is not a rotation matrix", where, fix)
    return matrix


def field_of_view(focal: float, side: int) -> float:
    """Degrees across `side` pixels with the principal point at the centre: a measure of the focal length alone,
    since an off-centre principal point with a focal length of 1e-30 spans anything from 0 to 180 degrees."""
    return math.degrees(2 * math.atan(0.5 * side / focal))


def focal_from_angle(angle: float, side: int) -> float:
    """The focal length in pixels of a field of view of `angle` radians across `side` pixels (instant-ngp's and
    NeRF-synthetic's camera_angle_x), the inverse of `field_of_view`."""
    return 0.5 * side / math.tan(0.5 * angle)


def refuse_implausible_focal(K: np.ndarray, width: int, height: int, where: str, fix: str) -> None:
    """One line for a positive pinhole focal length no camera has (a field of view of nearly 180 or nearly 0
    degrees, as from a focal length of 1e-30 or 1e30 px): such a camera trained silently into garbage."""
    fov = (field_of_view(K[0, 0], width), field_of_view(K[1, 1], height))
    shown = f"focal length {K[0, 0]:.3g} x {K[1, 1]:.3g} px for a {width}x{height} image"
    if max(fov) >= MAX_FIELD_OF_VIEW:
        raise SplatuError(f"{shown} gives a field of view of {fov[0]:.4g} x {fov[1]:.4g} degrees, wider than any "
                          f"camera's (below {MAX_FIELD_OF_VIEW:g})", where, fix)
    if max(K[0, 0], K[1, 1]) > MAX_FOCAL_PER_SIDE * max(width, height):
        raise SplatuError(f"{shown} is over {MAX_FOCAL_PER_SIDE:g} times the image's larger side (a field of view "
                          f"of {fov[0]:.2g} x {fov[1]:.2g} degrees), longer than any camera's", where, fix)


def world_to_camera_from_opengl(camera_to_world_gl: np.ndarray) -> np.ndarray:
    """OpenCV world-to-camera from an OpenGL camera-to-world matrix (nerfstudio, Blender)."""
    camera_to_world_cv = camera_to_world_gl @ OPENGL_TO_OPENCV
    rotation = camera_to_world_cv[:3, :3]
    world_to_camera = np.eye(4)
    world_to_camera[:3, :3] = rotation.T
    world_to_camera[:3, 3] = -rotation.T @ camera_to_world_cv[:3, 3]
    return world_to_camera


def opengl_camera_to_world(camera: Camera) -> list[list[float]]:
    """nerfstudio's transform_matrix for `camera`, the inverse of world_to_camera_from_opengl: camera-to-world
    with the y and z axes flipped to OpenGL's, exact in float64 since a rotation's inverse is its transpose."""
    rotation = camera.world_to_camera[:3, :3].double()
    camera_to_world = torch.eye(4, dtype=torch.float64)
    camera_to_world[:3, :3] = rotation.T
    camera_to_world[:3, 3] = camera.center().double()
    camera_to_world[:3, 1:3] *= -1
    return camera_to_world.tolist()
