"""The pinhole camera: resizing scales K axis by axis; a principal point that does not fit its image size."""

from __future__ import annotations

import pytest
import torch

from splatu.camera import Camera
from splatu.data.principal_point import misplaced_principal_point


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
    (240.0, 320.0, 640, 480, None),  # a 4:3 swap: a training tile may lie there (the loader checks its image)
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


@pytest.mark.parametrize(("cx", "cy", "width", "height", "fault"), [
    (240.0, 320.0, 640, 480, "swapped"),  # a K made for 480x640 on a 640x480 candidate: 17% off, passed before
    (320.0, 240.0, 480, 640, "swapped"),  # the other way round
    (0.5135 * 480, 0.5027 * 640, 640, 480, "swapped"),  # a real capture's K (fox's 1.4% off its centre), swapped
    (0.375 * 720, 0.5 * 540, 720, 540, None),  # 12.5% off along one side only: a crop, not at the swapped centre
    (320.0, 240.0, 640, 480, None),  # centred
    (320.0, 330.0, 660, 640, None),  # near square: swapped, the point lies within a real capture's offset
    (320.0, 200.0, 640, 640, None),  # square: a swap changes nothing
    (240.0, 320.0, 640, 640, None),
    (554.558 / 2, 965.268 / 2, 1080, 1920, "resized"),  # the training scene's faults too
    (-1.0, 10.0, 40, 30, "outside"),
])
def test_a_candidate_camera_s_near_square_swap_is_caught(cx, cy, width, height, fault):
    """A candidate camera has no image to check and is refused on a fault, so a swapped 4:3 size, which moves the
    principal point too little for a training scene (where tiles sit anywhere), is caught once the point is clearly
    off-centre and at the swapped size's centre."""
    found = misplaced_principal_point(cx, cy, width, height, candidate=True)
    assert (found and found[0]) == fault
    if fault == "swapped":
        assert found[1].endswith(f"off the centre of the {width}x{height} image, but at the centre of a "
                                 f"{height}x{width} one")


@pytest.mark.parametrize("grid", [2, 3, 4])
def test_every_tile_of_a_grid_off_the_photo_s_centre_gets_the_same_answer(grid):
    """Tiles of a 600x400 photo centred at (300, 200): every tile whose principal point is not inside it is "outside"
    alike. At 2x2 the top-left tile, whose point is on its corner at (1, 1) of its size, was "resized" and the three
    others, at a fraction of 0 (where no scale of K moves it), passed."""
    width, height = 600 // grid, 400 // grid
    middle = (grid // 2, grid // 2) if grid % 2 else None  # an odd grid's middle tile has the photo's centre
    tiles = [(row, col) for row in range(grid) for col in range(grid) if (row, col) != middle]
    faults = {misplaced_principal_point(300.0 - col * width, 200.0 - row * height, width, height)[0]
              for row, col in tiles}
    assert faults == {"outside"}
    assert middle is None or misplaced_principal_point(width / 2, height / 2, width, height) is None


@pytest.mark.parametrize(("cx", "cy", "what"), [
    (0.0, 0.0, "principal point (0, 0) lies on the edge of the 64x48 image"),
    (64.0, 24.0, "principal point (64, 24) lies on the edge of the 64x48 image"),
    (64.0, 48.0, "principal point (64, 48) lies on the edge of the 64x48 image, as for a K made for an image 2 times "
     "this size"),
    (96.0, 72.0, "principal point (96, 72) lies outside the 64x48 image, as for a K made for an image 3 times this "
     "size"),
    (96.0, -1.0, "principal point (96, -1) lies outside the 64x48 image"),
])
def test_a_principal_point_on_or_off_the_edge_says_which_and_the_size_one_scale_of_k_was_made_for(cx, cy, what):
    assert misplaced_principal_point(cx, cy, 64, 48) == ("outside", what)
