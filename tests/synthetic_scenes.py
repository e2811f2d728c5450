"""Small scenes written to disk in each supported format, for loader tests.

Cameras sit on a ring and look at the origin; images are seeded noise, so every pixel value
is known and any mix-up of frames or channels shows.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from splatu.camera import Camera
from splatu.data.frames import opengl_camera_to_world


def look_at_camera(center: np.ndarray, target: np.ndarray, K: np.ndarray, width: int, height: int,
                   name: str = "") -> Camera:
    """An OpenCV camera at `center` looking at `target`, world +z up."""
    forward = target - center
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward])  # rows: camera axes in world coordinates
    world_to_camera = np.eye(4)
    world_to_camera[:3, :3] = rotation
    world_to_camera[:3, 3] = -rotation @ center
    return Camera(K=torch.tensor(K), world_to_camera=torch.tensor(world_to_camera), width=width, height=height,
                  name=name)


def ring_cameras(n: int, width: int, height: int, radius: float = 4.0, offset=(10.0, -3.0, 2.0)) -> list[Camera]:
    """n cameras on a horizontal ring (off the origin, so normalisation has work to do)."""
    K = np.array([[0.9 * width, 0.0, width / 2 + 0.3], [0.0, 0.95 * width, height / 2 - 0.2], [0.0, 0.0, 1.0]])
    target = np.array(offset)
    cameras = []
    for i in range(n):
        angle = 2 * math.pi * i / n
        center = target + np.array([radius * math.cos(angle), radius * math.sin(angle), 1.0 + 0.1 * i])
        cameras.append(look_at_camera(center, target, K, width, height, name=f"images/frame_{i:03d}.png"))
    return cameras


def noise_image(seed: int, width: int, height: int, channels: int = 3) -> np.ndarray:
    """Seeded uint8 noise, (H, W, C) in RGB order."""
    return np.random.default_rng(seed).integers(0, 256, (height, width, channels), dtype=np.uint8)


def write_rgb(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB(A) uint8 array as an image file (OpenCV wants BGR)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    code = cv2.COLOR_RGBA2BGRA if rgb.shape[-1] == 4 else cv2.COLOR_RGB2BGR
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, code))


def write_nerfstudio_scene(root: Path, n: int = 8, width: int = 40, height: int = 30, **top_extras) -> list[Camera]:
    """A pinhole nerfstudio scene of n noise images; returns the cameras it wrote."""
    cameras = ring_cameras(n, width, height)
    for i, camera in enumerate(cameras):
        write_rgb(root / camera.name, noise_image(i, width, height))
    write_transforms(root / "transforms.json", cameras, [c.name for c in cameras], top_extras=top_extras)
    return cameras


def write_transforms(
    path: Path,
    cameras: Sequence[Camera],
    file_paths: Sequence[str],
    *,
    frame_extras: Sequence[Mapping[str, Any]] | None = None,
    top_extras: Mapping[str, Any] | None = None,
) -> None:
    """Write pinhole cameras as a nerfstudio transforms.json with per-frame intrinsics.

    `file_paths` are relative to the json's folder. `frame_extras` adds keys per frame
    (mask_path, depth_file_path, observed_mask_path, ...); `top_extras` adds top-level keys
    (ply_file_path, train_filenames, val_filenames, test_filenames, camera_model, k1, ...).
    """
    if len(cameras) != len(file_paths) or (frame_extras is not None and len(frame_extras) != len(cameras)):
        raise ValueError("cameras, file_paths and frame_extras must have the same length")
    frames = []
    for i, (camera, file_path) in enumerate(zip(cameras, file_paths, strict=True)):
        K = camera.K.detach().to(torch.float64).cpu().numpy()
        frame: dict[str, Any] = {
            "file_path": file_path,
            "transform_matrix": opengl_camera_to_world(camera),
            "fl_x": float(K[0, 0]), "fl_y": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
            "w": camera.width, "h": camera.height,
        }
        if frame_extras is not None:
            frame.update(frame_extras[i])
        frames.append(frame)
    content: dict[str, Any] = {"camera_model": "OPENCV", **(top_extras or {}), "frames": frames}
    path.write_text(json.dumps(content, indent=2))
