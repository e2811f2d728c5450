"""The orbit of `render-uncertainty --views orbit` (splatu.orbit) on a scene whose cameras are not centred."""

import dataclasses

import numpy as np
import pytest
import torch

from splatu.errors import SplatuError
from splatu.orbit import capture_frame, orbit_cameras
from tests.synthetic_scenes import look_at_camera, ring_cameras


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


@pytest.mark.parametrize("rounding", [0.0, 5e-9])
def test_an_orbit_of_cameras_turning_on_one_spot_is_refused_in_one_line(rounding):
    """Their optical axes meet at their common centre, so the orbit's radius was 0 and every orbit camera sat on the
    point it looked at: an all-zero rotation, views of nothing (coverage 0, U 1) and exit 0. At web-Mercator
    coordinates (2e7) float64 rounding leaves the normalised centres 5e-9 apart, which must count as one spot too."""
    K = np.array([[30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]])
    spot = np.array([1.0, 2.0, 3.0])
    cameras = [look_at_camera(spot + rounding * np.array([np.sin(3 * a), np.cos(5 * a), a]),
                              spot + np.array([np.cos(a), np.sin(a), 0.1]), K, 32, 24)
               for a in np.linspace(0.0, 1.5, 5)]
    with pytest.raises(SplatuError) as caught:
        orbit_cameras(cameras, 4)
    assert "share one position" in caught.value.what and "--views eval, train or cameras" in caught.value.fix
