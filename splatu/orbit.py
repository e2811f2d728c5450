"""An orbit of cameras around a capture, reaching directions the capture never saw (e.g. below).

The scene's frame is inferred from the training cameras alone, so it works for any loader:
`up` is the direction perpendicular to every camera's right axis (phone and drone captures are
held upright, without roll; the mean of the cameras' up vectors would lean towards wherever the
capture looks down), the centre is the point closest to every optical axis (what the capture
looks at), and the radius is the median camera distance to it. The orbit's elevation swings
from +max to −max and back as it circles once, so half of it looks from below the centre.

A capture taken from one side of its subject (a door from the front; fox) gets an arc instead of the circle: behind
the subject nothing was trained, and at half the radius the cameras sit among its surfaces. `plan_orbit` tells the
two apart by the azimuths the training cameras cover around the centre, and the arc loops over the captured side at
the cameras' own distance, reaching past it sideways and above and below (`ARC_MARGIN_DEGREES`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Literal

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


OrbitShape = Literal["auto", "circle", "arc"]
"""auto: the arc for a capture taken from one side (`is_one_sided`), the circle otherwise."""

DEFAULT_ELEVATION_DEGREES = 50.0
CIRCLE_RADIUS_SCALE = 0.5
"""The circle's default: ±50° at half the capture's radius. A capture walked around an object on a
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


PARALLEL_AXES = 1e-10
"""Optical axes this close to parallel meet nowhere (the ratio of the least to the greatest eigenvalue of the centre's
normal equations, about the mean squared angle in radians of the axes to their mean direction; axes parallel up to
float32 rounding differ by ~1e-7 rad). lstsq's least-norm point of such lines was the cameras' own middle, and the
orbit circled it looking sideways at nothing they saw."""


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
    spread = torch.linalg.eigvalsh(lhs)
    if float(spread[0]) <= PARALLEL_AXES * float(spread[-1]):
        raise SplatuError("the training cameras' optical axes are parallel (cameras that all look one way: a stereo "
                          "pair, a camera slid along a line), so there is no point they look at to orbit around",
                          "in the scene", "use --views eval, train or cameras instead")
    rhs = (projectors @ centres[:, :, None]).sum(dim=0)[:, 0]
    center = torch.linalg.lstsq(lhs, rhs[:, None]).solution[:, 0]
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


ARC_RADIUS_SCALE = 1.0
"""The arc's default: the training cameras' own distance. At half of it, 15 of lund_door's 24 orbit frames and 13 of
fox's looked at surfaces well short of the centre, from among them (docs/results.md, the orbit of a capture taken
from one side)."""

ARC_MARGIN_DEGREES = 15.0
"""How far past the captured azimuths the arc reaches on each side, into directions no training camera saw. Not
further: beyond fox's cameras lie other things of its room, and at 20° past them, at their distance, a surface at 0.14
of the way to the centre filled the view (lund_door's front stayed clear to 30°; docs/results.md). The arc's half-width
stays at most 90°, short of looking from behind the subject."""


@dataclass(frozen=True)
class AzimuthCover:
    """The smallest arc of azimuths around the capture's centre that holds every training camera, in radians."""

    middle: float  # from the frame's forward_axis towards up × forward_axis
    width: float


@dataclass(frozen=True)
class OrbitPlan:
    """Where the orbit goes: around the whole capture (`half_width` None) or over an arc of it, and how far out."""

    frame: CaptureFrame
    radius_scale: float
    cover: AzimuthCover
    middle: float  # radians: the arc's middle azimuth, from frame.forward_axis
    half_width: float | None  # radians: how far the arc swings either side of its middle; None for the circle

    def record(self, max_elevation_degrees: float) -> dict[str, Any]:
        """The orbit as render.json gives it: a render's frames are read against the path they were taken on, and an
        automatic shape must be visible after the run, not only in the note printed while it rendered."""
        return {"shape": "circle" if self.half_width is None else "arc", "radius_scale": self.radius_scale,
                "covered_azimuth_degrees": math.degrees(self.cover.width),
                "arc_degrees": None if self.half_width is None else math.degrees(2.0 * self.half_width),
                "max_elevation_degrees": max_elevation_degrees}


def azimuth_cover(cameras: list[Camera], frame: CaptureFrame) -> AzimuthCover:
    """The complement of the widest gap between the cameras' azimuths; cameras straight above or below the centre
    have none, and if every camera is there the cover is the full circle (the capture looks at it from all sides)."""
    side = torch.linalg.cross(frame.up, frame.forward_axis)
    offsets = torch.stack([c.center().double() for c in cameras]) - frame.center
    x, y = offsets @ frame.forward_axis, offsets @ side
    placed = torch.hypot(x, y) > 1e-6 * frame.radius
    if not bool(placed.any()):
        return AzimuthCover(0.0, 2.0 * math.pi)
    azimuths = torch.sort(torch.atan2(y[placed], x[placed])).values
    gaps = torch.diff(azimuths, append=azimuths[:1] + 2.0 * math.pi)
    widest = int(torch.argmax(gaps))
    width = 2.0 * math.pi - float(gaps[widest])
    start = float(azimuths[(widest + 1) % len(azimuths)])
    return AzimuthCover(math.remainder(start + 0.5 * width, 2.0 * math.pi), width)


def is_one_sided(cover: AzimuthCover) -> bool:
    """Every training camera on one side of a vertical plane through the centre: a door from the front (lund_door,
    40° of azimuth) or fox (93°), not the poster stand-in walked round its chair (234°)."""
    return cover.width < math.pi


def plan_orbit(cameras: list[Camera], shape: OrbitShape = "auto", radius_scale: float | None = None) -> OrbitPlan:
    """The orbit for these training cameras; `shape` and `radius_scale`, when given, override what the capture's
    layout would choose."""
    frame = capture_frame(cameras)
    cover = azimuth_cover(cameras, frame)
    arc = shape == "arc" or (shape == "auto" and is_one_sided(cover))
    if not arc:
        return OrbitPlan(frame, CIRCLE_RADIUS_SCALE if radius_scale is None else radius_scale, cover, 0.0, None)
    half_width = min(0.5 * cover.width + math.radians(ARC_MARGIN_DEGREES), 0.5 * math.pi)
    # around a capture taken from all sides the widest gap is a matter of rounding: face where most cameras are
    middle = cover.middle if is_one_sided(cover) else 0.0
    return OrbitPlan(frame, ARC_RADIUS_SCALE if radius_scale is None else radius_scale, cover, middle, half_width)


def one_sided_note(plan: OrbitPlan, radius_chosen: bool) -> str:
    """Why the orbit is an arc, said once when the capture's layout chose it (`radius_chosen`: its radius too)."""
    assert plan.half_width is not None
    distance = f" at the cameras' own distance (--orbit-radius-scale {plan.radius_scale:g})" if radius_chosen else ""
    return (f"note: the training cameras cover {math.degrees(plan.cover.width):.0f}° of azimuth around what they look "
            f"at, a capture from one side, so the orbit loops over the {math.degrees(2 * plan.half_width):.0f}° arc "
            f"in front of it{distance} rather than circling behind, where nothing was trained; --orbit-shape circle "
            "circles it")


def orbit_cameras(cameras: list[Camera], frames: int, max_elevation_degrees: float = DEFAULT_ELEVATION_DEGREES,
                  radius_scale: float | None = None, shape: OrbitShape = "auto") -> list[OrbitFrame]:
    """`frames` cameras on the orbit `plan_orbit` chooses for these training cameras (`orbit_along`)."""
    return orbit_along(plan_orbit(cameras, shape, radius_scale), cameras[0], frames, max_elevation_degrees)


def orbit_along(plan: OrbitPlan, first: Camera, frames: int,
                max_elevation_degrees: float = DEFAULT_ELEVATION_DEGREES) -> list[OrbitFrame]:
    """`frames` cameras on `plan`'s closed loop, each looking at the capture's centre from its image's centre, with
    the `first` training camera's focal length and image size. The circle goes round once with elevation =
    max·cos(azimuth), so half of it looks from below; the arc runs azimuth = middle + half_width·sin(t) and
    elevation = max·cos(t): from above the captured side to past its one edge, below it, past the other edge and
    back (see `plan_orbit`). Taking the plan, a caller that also records it renders the very path it records."""
    if frames < 2:
        raise SplatuError(f"an orbit needs at least 2 frames, got {frames}", "in --orbit-frames", "pass 2 or more")
    if not 0.0 <= max_elevation_degrees <= 85.0:
        raise SplatuError(f"orbit elevation must be in [0, 85] degrees, got {max_elevation_degrees}",
                          "in --orbit-elevation", "pass e.g. 60 (looking straight down or up is degenerate)")
    frame = plan.frame
    side = torch.linalg.cross(frame.up, frame.forward_axis)
    # the first camera's focal length and size, with its principal point at the image's centre, where the capture's
    # centre is looked at: a tile of a larger photo has it far off the tile (or off it), and its orbit showed a
    # window beside the centre, or none of it
    K = first.K.clone()
    K[0, 2], K[1, 2] = 0.5 * first.width, 0.5 * first.height
    template = replace(first, K=K)
    dtype = template.world_to_camera.dtype
    result = []
    for k in range(frames):
        phase = 2.0 * math.pi * k / frames
        azimuth = phase if plan.half_width is None else plan.middle + plan.half_width * math.sin(phase)
        elevation = math.radians(max_elevation_degrees) * math.cos(phase)
        horizontal = math.cos(azimuth) * frame.forward_axis + math.sin(azimuth) * side
        direction = math.cos(elevation) * horizontal + math.sin(elevation) * frame.up
        position = frame.center + frame.radius * plan.radius_scale * direction
        camera = replace(template, world_to_camera=look_at(position, frame.center, frame.up).to(dtype),
                         name=f"orbit_{k:03d}")
        result.append(OrbitFrame(camera, math.degrees(elevation)))
    return result
