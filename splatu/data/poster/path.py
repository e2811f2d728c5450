"""The video-like camera path: an arc around the chair's front and sides, always above the seat.

Like the real poster capture (a phone walked around a chair), azimuth sweeps `arc_degrees`
centred on the chair's front while height and distance drift smoothly; a seeded, smooth
jitter (a few low-frequency sinusoids) perturbs position and aim like a hand-held camera.
The lowest possible height is MEAN_HEIGHT - HEIGHT_SWING - JITTER = 0.87 m, well above the seat (0.47 m).
"""

from __future__ import annotations

import math
import random

import torch
from torch import Tensor

from splatu.camera import Camera, look_at
from splatu.data.poster.config import PosterConfig
from splatu.data.poster.geometry import TARGET

FRONT_AZIMUTH = math.pi / 2
"""The chair faces +y."""
MEAN_HEIGHT, HEIGHT_SWING = 1.15, 0.25
MEAN_RADIUS, RADIUS_SWING = 1.4, 0.12
JITTER = 0.03
"""Amplitude (metres) of the smooth hand-held jitter of each coordinate of position and aim."""
WORLD_UP = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
"""The cameras are held upright: world +z is up in every image."""


def intrinsics(cfg: PosterConfig) -> Tensor:
    """Square-pixel pinhole K with the principal point at the image centre."""
    focal = 0.5 * cfg.height / math.tan(math.radians(cfg.vertical_fov_degrees) / 2)
    return torch.tensor(
        [[focal, 0.0, cfg.width / 2], [0.0, focal, cfg.height / 2], [0.0, 0.0, 1.0]], dtype=torch.float64
    )


def _smooth_jitter(s: float, phases: list[float]) -> float:
    """A smooth function of path position s in [0, 1]: three sinusoids of 1.3, 2.7 and 4.1 cycles."""
    return sum(math.sin(2 * math.pi * f * s + p) for f, p in zip((1.3, 2.7, 4.1), phases, strict=True)) / 3


def camera_path(cfg: PosterConfig) -> list[Camera]:
    """`cfg.frames` cameras along the path, named frame_00000, frame_00001, ..."""
    rng = random.Random(cfg.seed)
    phases = [[rng.uniform(0, 2 * math.pi) for _ in range(3)] for _ in range(6)]
    swing_phase = rng.uniform(0, 2 * math.pi)
    K = intrinsics(cfg)
    target0 = torch.tensor(TARGET, dtype=torch.float64)
    cameras = []
    for i in range(cfg.frames):
        s = i / max(cfg.frames - 1, 1)
        azimuth = FRONT_AZIMUTH + math.radians(cfg.arc_degrees) * (s - 0.5)
        radius = MEAN_RADIUS + RADIUS_SWING * math.sin(2 * math.pi * s + swing_phase)
        height = MEAN_HEIGHT + HEIGHT_SWING * math.sin(2 * math.pi * 1.5 * s + swing_phase)
        jitter = [JITTER * _smooth_jitter(s, p) for p in phases]
        eye = torch.tensor(
            [radius * math.cos(azimuth) + jitter[0], radius * math.sin(azimuth) + jitter[1], height + jitter[2]],
            dtype=torch.float64,
        )
        target = target0 + torch.tensor(jitter[3:], dtype=torch.float64)
        cameras.append(Camera(K=K.clone(), world_to_camera=look_at(eye, target, WORLD_UP), width=cfg.width,
                              height=cfg.height, name=f"frame_{i:05d}"))
    return cameras
