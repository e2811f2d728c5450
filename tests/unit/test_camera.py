"""The pinhole camera: resizing scales K axis by axis."""

from __future__ import annotations

import torch

from splatu.camera import Camera


def test_scaled_camera_scales_each_axis_by_its_own_size_ratio():
    """33×25 at half size rounds to 16×12 (round half to even), ratios 16/33 ≠ 12/25: fy follows the height."""
    K = torch.tensor([[30.0, 0.0, 16.5], [0.0, 31.0, 12.5], [0.0, 0.0, 1.0]], dtype=torch.float64)
    half = Camera(K, torch.eye(4, dtype=torch.float64), 33, 25).scaled(0.5)
    assert (half.width, half.height) == (16, 12)
    expected = torch.tensor([[30.0 * 16 / 33, 0.0, 16.5 * 16 / 33], [0.0, 31.0 * 12 / 25, 12.5 * 12 / 25],
                             [0.0, 0.0, 1.0]], dtype=torch.float64)
    torch.testing.assert_close(half.K, expected, rtol=1e-15, atol=0.0)
