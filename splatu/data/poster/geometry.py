"""The stand-in's geometry: a chair with a poster leaning on it, inside a room.

Everything is an oriented box, so the renderer can intersect rays analytically (slab test)
and every pixel hits a real surface: the room's inside faces are the floor, walls and
ceiling. Units are metres; world +z is up; the chair faces +y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import IntEnum

import torch
from torch import Tensor


class Finish(IntEnum):
    """What a box is made of; textures.py turns (finish, face) into albedo and gloss."""

    ROOM = 0
    SEAT = 1
    WOOD = 2
    POSTER = 3


@dataclass(frozen=True)
class Box:
    """An oriented box: centre, local axes (orthonormal, right-handed) and half extents."""

    name: str
    center: tuple[float, float, float]
    axes: tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]
    half: tuple[float, float, float]
    finish: Finish


_IDENTITY = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))

SEAT_TOP = 0.47
"""Height of the seat's upper face; the camera path never goes below it."""
SEAT_BOTTOM = 0.43
TARGET = (0.0, -0.05, 0.68)
"""Where the cameras look: the middle of the poster."""


@dataclass(frozen=True)
class PosterScene:
    """Boxes as float64 tensors. Box 0 is the room (seen from inside); the rest are objects."""

    boxes: tuple[Box, ...]
    centers: Tensor  # (B, 3)
    rotations: Tensor  # (B, 3, 3), columns are the local axes in world coordinates
    halves: Tensor  # (B, 3)
    objects_center: Tensor  # (3,) axis-aligned bound of boxes 1.., for culling rays
    objects_half: Tensor  # (3,)
    aligned: tuple[bool, ...]  # per box: axes are the world axes, so the renderer can skip rotating rays

    def index(self, name: str) -> int:
        return next(i for i, b in enumerate(self.boxes) if b.name == name)

    def to(self, dtype: torch.dtype) -> PosterScene:
        """The same scene in another float precision (float32 is enough for anti-aliasing samples)."""
        return replace(self, centers=self.centers.to(dtype), rotations=self.rotations.to(dtype),
                       halves=self.halves.to(dtype), objects_center=self.objects_center.to(dtype),
                       objects_half=self.objects_half.to(dtype))


def _poster_box() -> Box:
    """A 6 mm board standing on the seat, its top leaning on the backrest panel."""
    length, thickness, bottom_y = 0.50, 0.006, 0.02
    backrest_front_y = -0.19
    sin_tilt = (bottom_y - backrest_front_y) / length
    cos_tilt = math.sqrt(1.0 - sin_tilt**2)
    # Local x runs along the picture's width as a viewer in front sees it (world -x), local y up
    # the picture, local z out of the picture's face (forward and up).
    x_axis = (-1.0, 0.0, 0.0)
    y_axis = (0.0, -sin_tilt, cos_tilt)
    z_axis = (0.0, cos_tilt, sin_tilt)
    center = tuple(
        b + 0.5 * length * y - 0.5 * thickness * z
        for b, y, z in zip((0.0, bottom_y, SEAT_TOP), y_axis, z_axis, strict=True)
    )
    return Box("poster", center, (x_axis, y_axis, z_axis), (0.20, 0.5 * length, 0.5 * thickness), Finish.POSTER)


def _chair_boxes() -> list[Box]:
    seat_half_z = 0.5 * (SEAT_TOP - SEAT_BOTTOM)
    boxes = [Box("seat", (0.0, 0.0, SEAT_BOTTOM + seat_half_z), _IDENTITY, (0.225, 0.225, seat_half_z), Finish.SEAT)]
    leg_half_z = 0.5 * SEAT_BOTTOM
    for sx in (-1, 1):
        for sy in (-1, 1):
            center = (0.195 * sx, 0.195 * sy, leg_half_z)
            boxes.append(Box(f"leg{sx:+d}{sy:+d}", center, _IDENTITY, (0.02, 0.02, leg_half_z), Finish.WOOD))
    for sx in (-1, 1):
        boxes.append(Box(f"post{sx:+d}", (0.195 * sx, -0.205, 0.54), _IDENTITY, (0.02, 0.015, 0.07), Finish.WOOD))
    boxes.append(Box("backrest", (0.0, -0.205, 0.78), _IDENTITY, (0.225, 0.015, 0.17), Finish.WOOD))
    return boxes


def _room_box() -> Box:
    return Box("room", (0.0, 0.0, 1.5), _IDENTITY, (4.0, 4.0, 1.5), Finish.ROOM)


def _bounds(boxes: list[Box]) -> tuple[Tensor, Tensor]:
    """Axis-aligned centre and half extents enclosing the given oriented boxes (with a margin)."""
    corners = []
    for box in boxes:
        rot = torch.tensor(box.axes, dtype=torch.float64).T
        signs = torch.tensor([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=torch.float64)
        local = signs * torch.tensor(box.half, dtype=torch.float64)
        corners.append(torch.tensor(box.center, dtype=torch.float64) + local @ rot.T)
    points = torch.cat(corners)
    lo, hi = points.min(dim=0).values, points.max(dim=0).values
    return 0.5 * (lo + hi), 0.5 * (hi - lo) + 1e-3


def build_scene() -> PosterScene:
    """The fixed stand-in scene (it does not depend on the seed; only cameras and points do)."""
    objects = [*_chair_boxes(), _poster_box()]
    boxes = (_room_box(), *objects)
    objects_center, objects_half = _bounds(objects)
    return PosterScene(
        boxes=boxes,
        centers=torch.tensor([b.center for b in boxes], dtype=torch.float64),
        rotations=torch.tensor([b.axes for b in boxes], dtype=torch.float64).transpose(1, 2).contiguous(),
        halves=torch.tensor([b.half for b in boxes], dtype=torch.float64),
        objects_center=objects_center,
        objects_half=objects_half,
        aligned=tuple(b.axes == _IDENTITY for b in boxes),
    )
