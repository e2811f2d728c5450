"""Exact first-hit ray casting against the scene's oriented boxes (analytic slab test).

Rays are parametrised as origin + t * direction with
unnormalised directions, so t means whatever the caller scales the directions to: camera z
for primary rays (direction has camera-space z = 1), the fraction of the way to a target
point for visibility rays. Arithmetic is elementwise (no matmul), so results are
bit-identical whatever the thread count. Precision follows the inputs (scene and rays): float64
for depth and visibility, float32 for anti-aliasing samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from splatu.data.poster.geometry import PosterScene

T_MIN = 1e-9
"""Hits closer than this to the origin are ignored (origins never sit on a surface)."""
RELATIVE_TOLERANCE = 1e-6
"""A surface hit closer than this fraction of the way short of the target does not block it (`blocked`)."""


@dataclass(frozen=True)
class Hits:
    """First hit of every ray; box is -1 and t is inf where a ray hits nothing."""

    t: Tensor  # (N,)
    box: Tensor  # (N,) long
    axis: Tensor  # (N,) long, the local axis of the face that was hit
    side: Tensor  # (N,) +1 or -1: which of the box's two faces on that axis
    local: Tensor  # (N, 3) hit point in the box's local coordinates


def to_local(vectors: Tensor, rotation: Tensor) -> Tensor:
    """rotation^T @ v for each row v (rotation (3, 3) or per row (N, 3, 3)), elementwise for reproducibility."""
    return (
        vectors[..., 0:1] * rotation[..., 0, :]
        + vectors[..., 1:2] * rotation[..., 1, :]
        + vectors[..., 2:3] * rotation[..., 2, :]
    )


def _first_of_three(values: tuple[Tensor, Tensor, Tensor], pick) -> tuple[Tensor, Tensor]:
    """Elementwise max or min of three tensors and which one it was (ties: the lowest index).

    Written out because torch's max/min over a dimension of size 3 is much slower on the CPU than two elementwise
    calls.
    """
    best = pick(pick(values[0], values[1]), values[2])
    index = torch.where(values[0] == best, 0, torch.where(values[1] == best, 1, 2))
    return best, index


def _slab(origin: Tensor, directions: Tensor, half: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """First hit of rays with an axis-aligned box centred at 0: (t, axis, side); t = inf on a miss.

    A ray starting outside hits the face it enters through; one starting inside (the room) hits
    the face it leaves through.
    """
    tiny = torch.finfo(directions.dtype).tiny
    lows, highs, signs = [], [], []
    for k in range(3):
        d = directions[:, k]
        inverse = 1.0 / torch.where(d == 0, tiny, d)
        t_a = (-half[k] - origin[..., k]) * inverse
        t_b = (half[k] - origin[..., k]) * inverse
        lows.append(torch.minimum(t_a, t_b))
        highs.append(torch.maximum(t_a, t_b))
        signs.append(torch.sign(d))
    t_near, axis_near = _first_of_three(tuple(lows), torch.maximum)
    t_far, axis_far = _first_of_three(tuple(highs), torch.minimum)
    entering = (t_near > T_MIN) & (t_near <= t_far)
    leaving = (t_near <= T_MIN) & (t_far > T_MIN)
    t = torch.where(entering, t_near, torch.where(leaving, t_far, float("inf")))
    axis = torch.where(entering, axis_near, axis_far)
    direction_sign = torch.where(axis == 0, signs[0], torch.where(axis == 1, signs[1], signs[2]))
    side = torch.where(entering, -direction_sign, direction_sign)
    return t, axis, side


def _box_frame(scene: PosterScene, index: int, origin: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
    """Origin and directions in box `index`'s local frame (a shift only, for axis-aligned boxes)."""
    shifted = origin - scene.centers[index]
    if scene.aligned[index]:
        return shifted, directions
    rot = scene.rotations[index]
    return to_local(shifted, rot), to_local(directions, rot)


def _nearest(
    scene: PosterScene, boxes: range, origin: Tensor, directions: Tensor, rows: Tensor, hits: dict[str, Tensor]
) -> None:
    """Update `hits` (t, box, axis, side) in place with the given boxes, for the ray subset `rows`."""
    d = directions[rows]
    o = origin if origin.dim() == 1 else origin[rows]
    for index in boxes:
        t_box, axis_box, side_box = _slab(*_box_frame(scene, index, o, d), scene.halves[index])
        closer = t_box < hits["t"][rows]
        where = rows[closer]
        hits["t"][where] = t_box[closer]
        hits["box"][where] = index
        hits["axis"][where] = axis_box[closer]
        hits["side"][where] = side_box[closer]


def _enters_objects(scene: PosterScene, origin: Tensor, directions: Tensor, before: Tensor) -> Tensor:
    """Rays whose path up to `before` meets the objects' common bounding box (cheap culling)."""
    t_bound, _, _ = _slab(origin - scene.objects_center, directions, scene.objects_half)
    offset = (origin - scene.objects_center).abs()
    half = scene.objects_half
    inside = (offset[..., 0] < half[0]) & (offset[..., 1] < half[1]) & (offset[..., 2] < half[2])
    return inside | (t_bound < before)


def cast(scene: PosterScene, origin: Tensor, directions: Tensor) -> Hits:
    """First hit along origin + t * directions (N, 3) over all boxes; origin is (3,) or per ray (N, 3).

    Object boxes are tested only for rays that meet their common bounding box before the room,
    which keeps the cost near two slab tests per ray.
    """
    t, axis, side = _slab(*_box_frame(scene, 0, origin, directions), scene.halves[0])
    hits = {"t": t, "box": torch.where(torch.isfinite(t), 0, -1), "axis": axis, "side": side}
    candidates = _enters_objects(scene, origin, directions, hits["t"]).nonzero()[:, 0]
    if candidates.numel():
        _nearest(scene, range(1, len(scene.boxes)), origin, directions, candidates, hits)

    box = hits["box"]
    local = torch.zeros_like(directions)
    for index in range(len(scene.boxes)):
        rows = (box == index).nonzero()[:, 0]
        o = origin if origin.dim() == 1 else origin[rows]
        o_local, d_local = _box_frame(scene, index, o, directions[rows])
        local[rows] = o_local + hits["t"][rows, None] * d_local
    return Hits(t=hits["t"], box=box, axis=hits["axis"], side=hits["side"], local=local)


def blocked(scene: PosterScene, origins: Tensor, targets: Tensor) -> Tensor:
    """Whether each segment origin -> target (N, 3 each) is blocked by an object before the target.

    The room cannot block: origins and targets are inside it. A hit counts as blocking when it
    is more than RELATIVE_TOLERANCE (a fraction of the segment) short of the target, so a target lying
    on a surface does not block itself.
    """
    directions = targets - origins
    n = directions.shape[0]
    result = torch.zeros(n, dtype=torch.bool)
    limit = torch.full((n,), 1.0 - RELATIVE_TOLERANCE, dtype=directions.dtype)
    rows = _enters_objects(scene, origins, directions, limit).nonzero()[:, 0]
    if rows.numel() == 0:
        return result
    o, d = origins[rows], directions[rows]
    for index in range(1, len(scene.boxes)):
        t_box, _, _ = _slab(*_box_frame(scene, index, o, d), scene.halves[index])
        result[rows[t_box < 1.0 - RELATIVE_TOLERANCE]] = True
    return result
