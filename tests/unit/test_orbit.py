"""The orbit of `render-uncertainty --views orbit` (splatu.orbit) on a scene whose cameras are not centred."""

import dataclasses

import pytest
import torch

from splatu.orbit import capture_frame, orbit_cameras
from tests.synthetic_scenes import ring_cameras


@pytest.mark.parametrize(("row", "col"), [(0, 0), (1, 2), (2, 2)])
def test_an_orbit_of_tiles_looks_at_the_capture_s_centre_from_its_image_s_centre(row, col):
    """Tiles cut from larger photos (a 3x3 grid of 96x72 photos: 32x24 tiles with the photo's K shifted to each) now
    train, with a warning. The orbit copied the first camera's K, principal point and all, so a corner tile's orbit
    put the capture's centre at (-15.7, -12.2) of a 32x24 image: every frame showed a window beside it."""
    tiles = []
    for photo in ring_cameras(6, 96, 72):
        K = photo.K.clone()
        K[0, 2] -= col * 32
        K[1, 2] -= row * 24
        tiles.append(dataclasses.replace(photo, K=K, width=32, height=24))
    centre = capture_frame(tiles).center
    for frame in orbit_cameras(tiles, 4):
        w2c, K = frame.camera.world_to_camera.double(), frame.camera.K.double()
        x, y, z = w2c[:3, :3] @ centre.double() + w2c[:3, 3]
        uv = torch.stack([K[0, 0] * x / z + K[0, 2], K[1, 1] * y / z + K[1, 2]])
        assert float(z) > 0 and torch.allclose(uv, torch.tensor([16.0, 12.0], dtype=torch.float64), atol=1e-3)
        assert (frame.camera.width, frame.camera.height) == (32, 24)
        assert frame.camera.K[0, 0] == tiles[0].K[0, 0] and frame.camera.K[1, 1] == tiles[0].K[1, 1]
