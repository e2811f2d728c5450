"""The pinhole camera: resizing scales K axis by axis; a principal point that does not fit its image size."""

from __future__ import annotations

import pytest
import torch

from splatu.camera import Camera
from splatu.data.frames import misplaced_principal_point


def test_scaled_camera_scales_each_axis_by_its_own_size_ratio():
    """33×25 at half size rounds to 16×12 (round half to even), ratios 16/33 ≠ 12/25: fy follows the height."""
    K = torch.tensor([[30.0, 0.0, 16.5], [0.0, 31.0, 12.5], [0.0, 0.0, 1.0]], dtype=torch.float64)
    half = Camera(K, torch.eye(4, dtype=torch.float64), 33, 25).scaled(0.5)
    assert (half.width, half.height) == (16, 12)
    expected = torch.tensor([[30.0 * 16 / 33, 0.0, 16.5 * 16 / 33], [0.0, 31.0 * 12 / 25, 12.5 * 12 / 25],
                             [0.0, 0.0, 1.0]], dtype=torch.float64)
    torch.testing.assert_close(half.K, expected, rtol=1e-15, atol=0.0)


@pytest.mark.parametrize(("cx", "cy", "width", "height", "fault"), [
    (554.558, 965.268, 1080, 1920, None),  # fox: 1.4% off the centre
    (648.0, 968.0, 1296, 1936, None),  # lund_door: at the centre
    (0.7 * 1920, 540.0, 1920, 1080, None),  # 20% off, as far as a crop may take it without another explanation
    (0.85 * 1920, 540.0, 1920, 1080, None),  # an off-centre crop along one side: nothing else explains it
    (0.25 * 1920, 0.33 * 1080, 1920, 1080, None),  # off in both, but by fractions no one scale of K centres
    (240.0, 320.0, 640, 480, None),  # a 4:3 swap moves it too little to tell from a crop (the loader's image check)
    (965.268, 554.558, 1080, 1920, "swapped"),  # fox's cx and cy the wrong way round
    (554.558, 965.268, 1920, 1080, "swapped"),  # or its w and h
    (3000.0, 2000.0, 4000, 6000, "swapped"),  # 3:2
    (554.558 / 2, 965.268 / 2, 1080, 1920, "resized"),  # fox's K at --downscale 2, used at full size
    (0.75 * 64, 0.76 * 48, 64, 48, "resized"),  # a K made for an image 1.5 times this size
    (554.558 * 2, 965.268 * 2, 1080, 1920, "outside"),  # fox's full-size K at --downscale 2
    (-1.0, 10.0, 40, 30, "outside"),
])
def test_a_principal_point_is_refused_only_where_a_simple_mistake_explains_it(cx, cy, width, height, fault):
    found = misplaced_principal_point(cx, cy, width, height)
    assert (found and found[0]) == fault
    if found:
        assert found[1].startswith(f"principal point ({cx:.6g}, {cy:.6g})") and f"{width}x{height} image" in found[1]
