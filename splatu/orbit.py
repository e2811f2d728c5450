"""An orbit of cameras around a capture, reaching directions the capture never saw (e.g. below).

The scene's frame is inferred from the training cameras alone, so it works for any loader:
`up` is the direction perpendicular to every camera's right axis (phone and drone captures are
held upright, without roll; the mean of the cameras' up vectors would lean towards wherever the
capture looks down), the centre is the point closest to every optical axis (what the capture
looks at), and the radius is the median camera distance to it. The orbit's elevation swings
from +max to −max and back as it circles once, so half of it looks from below the centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from splatu.camera import Camera, look_at, unit_vector
from splatu.errors import SplatuError


@dataclass(frozen=True)
class OrbitFrame:
    """One orbit camera and its elevation above the capture's horizontal plane, in degrees."""

    camera: Camera
    elevation_degrees: float


@dataclass(frozen=True)
class CaptureFrame:
    """Where a capture looks from: centre, up direction, radius, and azimuth-zero direction."""

    center: Tensor
    up: Tensor
    radius: float
    forward_axis: Tensor  # unit, perpendicular to up: azimuth 0 points from the centre towards it


DEFAULT_ELEVATION_DEGREES = 50.0
DEFAULT_RADIUS_SCALE = 0.5
"""The default orbit: ±50° at half the capture's radius. A capture walked around an object on a
floor (the poster stand-in: cameras 1.5 m from the poster's middle, which is 0.68 m = 0.46 radii
above the floor and 0.25 m = 0.17 radii above the seat's underside) leaves no room to orbit at the
full radius from below: ±60° there goes 0.87 radii down, through the floor, and renders the floor's
back. Passing right under the chair is impossible too (its seat is 0.43 m above the floor, between
four legs). At half the radius, the lowest camera is 0.38 radii below the centre: under the seat,
0.11 m above the floor, looking up at the underside no training camera saw."""


def _vertical(rotations: Tensor) -> Tensor:
    """The unit vector most perpendicular to every camera's right axis, signed like the cameras' mean up.

    When every right axis is the same (all cameras face one way) the vertical is undetermined, so
    the mean up is used.
    """
    rights = rotations[:, 0, :]
    mean_up = -rotations[:, 1, :].mean(dim=0)  # camera −y (OpenCV down is +y) in world
    values, vectors = torch.linalg.eigh(rights.T @ rights)
    if values[1] < 1e-3 * values[2]:
        return unit_vector(mean_up)
    up = vectors[:, 0]
    return up if float(up @ mean_up) >= 0.0 else -up


ORBIT_RADIUS_FLOOR = 1e-6
"""The smallest capture radius an orbit is made for, in the training cameras' normalised units: a capture with a
baseline spans about 1 there, while one turning on one spot keeps scale 1 and a radius of float64's rounding of its
coordinates (5e-9 at the 2e7 of web-Mercator metres), or a baseline `normalization` calls one spot."""


def capture_frame(cameras: list[Camera]) -> CaptureFrame:
    """Centre, up and radius of a set of (training) cameras, in float64."""
    if len(cameras) < 2:
        raise SplatuError(f"an orbit needs at least 2 training cameras, got {len(cameras)}", "in the scene",
                          "use --views eval or train instead")
    rotations = torch.stack([c.world_to_camera[:3, :3].double() for c in cameras])
    centres = torch.stack([c.center().double() for c in cameras])
    forwards = rotations[:, 2, :]  # camera +z in world
    up = _vertical(rotations)
    # least-squares point nearest to all optical axes: sum_i (I - f f^T)(c - o_i) = 0
    projectors = torch.eye(3, dtype=torch.float64) - forwards[:, :, None] * forwards[:, None, :]
    lhs = projectors.sum(dim=0)
    rhs = (projectors @ centres[:, :, None]).sum(dim=0)[:, 0]
    center = torch.linalg.lstsq(lhs, rhs[:, None]).solution[:, 0]
    if not torch.isfinite(center).all():
        center = centres.mean(dim=0)
    offsets = centres - center
    radius = float(offsets.norm(dim=1).median())
    if radius <= ORBIT_RADIUS_FLOOR:  # every orbit camera would sit on the point it looks at: an all-zero rotation
        raise SplatuError("the training cameras share one position (a capture turning on the spot), so an orbit "
                          "around what they look at has no radius", "in the scene",
                          "use --views eval, train or cameras instead")
    mean_offset = offsets.mean(dim=0)
    horizontal = mean_offset - (mean_offset @ up) * up
    if horizontal.norm() < 1e-9 * max(radius, 1e-12):  # cameras all around: any horizontal axis will do
        seed = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
        horizontal = seed - (seed @ up) * up if abs(float(seed @ up)) < 0.9 else torch.tensor([0.0, 1.0, 0.0]).double()
    return CaptureFrame(center, up, radius, unit_vector(horizontal))


def orbit_cameras(cameras: list[Camera], frames: int, max_elevation_degrees: float = DEFAULT_ELEVATION_DEGREES,
                  radius_scale: float = DEFAULT_RADIUS_SCALE) -> list[OrbitFrame]:
    """`frames` cameras circling the capture once; elevation = max·cos(azimuth), so half look from below. Each has
    the first camera's focal length and image size, and looks at the capture's centre from its image's centre."""
    if frames < 2:
        raise SplatuError(f"an orbit needs at least 2 frames, got {frames}", "in --orbit-frames", "pass 2 or more")
    if not 0.0 <= max_elevation_degrees <= 85.0:
        raise SplatuError(f"orbit elevation must be in [0, 85] degrees, got {max_elevation_degrees}",
                          "in --orbit-elevation", "pass e.g. 60 (looking straight down or up is degenerate)")
    frame = capture_frame(cameras)
    side = torch.linalg.cross(frame.up, frame.forward_axis)
    # the first camera's focal length and size, with its principal point at the image's centre, where the capture's
    # centre is looked at: a tile of a larger photo has it far off the tile (or off it), and its orbit showed a
    # window beside the centre, or none of it
    first = cameras[0]
    K = first.K.clone()
    K[0, 2], K[1, 2] = 0.5 * first.width, 0.5 * first.height
    template = replace(first, K=K)
    dtype = template.world_to_camera.dtype
    result = []
    for k in range(frames):
        azimuth = 2.0 * math.pi * k / frames
        elevation = math.radians(max_elevation_degrees) * math.cos(azimuth)
        horizontal = math.cos(azimuth) * frame.forward_axis + math.sin(azimuth) * side
        direction = math.cos(elevation) * horizontal + math.sin(elevation) * frame.up
        position = frame.center + frame.radius * radius_scale * direction
        camera = replace(template, world_to_camera=look_at(position, frame.center, frame.up).to(dtype),
                         name=f"orbit_{k:03d}")
        result.append(OrbitFrame(camera, math.degrees(elevation)))
    return result
