"""What a loader returns before splitting: every frame's camera and pixel recipes, plus points.

Loaders only parse their format; splitting, normalisation and decoding are shared
(splatu/data/assemble.py), so every format behaves the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

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


@dataclass
class Frame:
    """One view: its undistorted pinhole camera at the target size (scene's own world units)."""

    name: str
    camera: Camera
    image: PixelRecipe
    mask: PixelRecipe | None = None
    depth: PixelRecipe | None = None
    observed: PixelRecipe | None = None


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
    if np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-3 or np.linalg.det(rotation) <= 0:
        raise SplatuError("pose rotation is not a rotation matrix", where, fix)
    return matrix


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
