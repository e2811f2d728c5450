"""How new a view is: the training view whose viewing direction is closest, by angle, and how far off it stands."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import Tensor

from splatu.camera import camera_center


class NearestView(NamedTuple):
    """The training view closest in viewing direction to a camera."""

    name: str
    angle_degrees: float  # between the two viewing directions
    distance: float  # between the two camera centres, in the units of the poses given (times `unit`)


def nearest_training_views(world_to_cameras: Sequence[Tensor], training: Sequence[Tensor], names: Sequence[str],
                           unit: float = 1.0) -> list[NearestView]:
    """Per world-to-camera pose (4, 4), the training pose whose viewing direction is closest. For a candidate it says
    how new its view is. A pose written in the wrong convention (camera-to-world for world-to-camera) stands out by
    its distance around an object (the poster stand-in's training poses inverted: 22–29 times the cameras' spacing)
    but need not in a forward-facing capture (lund_door's: 0.3–2.7 times; docs/results.md). `unit` scales distances
    (data units per unit of the poses given)."""
    training_poses = torch.stack([pose.double() for pose in training])
    forward = training_poses[:, 2, :3]  # OpenCV: the camera's +z, the third row of R
    centres = camera_center(training_poses)
    nearest = []
    for pose in world_to_cameras:
        pose = pose.double()
        direction, centre = pose[2, :3], camera_center(pose)
        best = int((forward @ direction).argmax())
        # atan2(|a × b|, a · b), not acos(a · b): exact near 0°, where a rounding of the cosine is a visible angle
        sine = torch.linalg.cross(forward[best], direction).norm()
        angle = torch.rad2deg(torch.atan2(sine, forward[best] @ direction))
        nearest.append(NearestView(names[best], float(angle), float((centres[best] - centre).norm()) * unit))
    return nearest
