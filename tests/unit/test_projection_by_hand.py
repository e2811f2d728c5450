"""The projection's conventions checked from the pinhole model itself, not against tests/reference_rasterizer.py.

The exactness tests compare the fast rasterizer with a reference that writes the same EWA formulas, and pin that
reference by hand only for isotropic Gaussians seen by an identity camera, where a transposed camera rotation,
a quaternion rotating the wrong way or a sign of the off-diagonal term cannot show. Here the expected values come
from central finite differences of u = fx·x/z + cx, v = fy·y/z + cy applied to world points through a rotated
camera with an off-centre principal point, from Rodrigues' formula for the rotation, and from the Gaussian's
closed form at every pixel centre (j + 0.5, i + 0.5).
"""

from __future__ import annotations

import math

import pytest
import torch
from torch import Tensor

from splatu.camera import Camera, look_at
from splatu.rasterizer import rasterize
from splatu.rasterizer.projection import conic_rows, project_gaussians, quaternion_to_rotation

D = torch.float64
WIDTH, HEIGHT = 40, 30
K = torch.tensor([[52.0, 0.0, 23.7], [0.0, 47.0, 13.2], [0.0, 0.0, 1.0]], dtype=D)
WORLD_TO_CAMERA = look_at(torch.tensor([1.0, -2.0, 0.5], dtype=D), torch.tensor([0.2, 0.1, -0.3], dtype=D),
                          torch.tensor([0.0, 0.0, 1.0], dtype=D))
AXES = torch.tensor([[0.3, -0.5, 0.8], [1.0, 0.2, 0.0], [-0.1, 0.9, 0.4]], dtype=D)
ANGLES = (1.1, -2.3, 0.4)
MEANS = torch.tensor([[0.25, 0.05, -0.2], [0.1, 0.3, 0.0], [-0.1, -0.2, -0.4]], dtype=D)
SCALES = torch.tensor([[0.05, 0.2, 0.01], [0.01, 0.03, 0.12], [0.08, 0.02, 0.04]], dtype=D)


def rodrigues(axis: Tensor, angle: float) -> Tensor:
    """The rotation by `angle` radians about `axis`, right-handed: I + sin θ [a]ₓ + (1 − cos θ) [a]ₓ²."""
    a = axis / axis.norm()
    cross = torch.tensor([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]], dtype=D)
    return torch.eye(3, dtype=D) + math.sin(angle) * cross + (1 - math.cos(angle)) * cross @ cross


def quaternion(axis: Tensor, angle: float, length: float) -> Tensor:
    """The wxyz quaternion of that rotation, scaled to `length` (the projection normalises it)."""
    return length * torch.cat([torch.tensor([math.cos(angle / 2)], dtype=D), math.sin(angle / 2) * axis / axis.norm()])


QUATS = torch.stack([quaternion(a, t, s) for a, t, s in zip(AXES, ANGLES, (3.7, 0.2, 1.0), strict=True)])
ROTATIONS = torch.stack([rodrigues(a, t) for a, t in zip(AXES, ANGLES, strict=True)])


def pixel_of(camera_point: Tensor) -> Tensor:
    return torch.stack([K[0, 0] * camera_point[0] / camera_point[2] + K[0, 2],
                        K[1, 1] * camera_point[1] / camera_point[2] + K[1, 2]])


def world_pixel(point: Tensor) -> Tensor:
    return pixel_of(WORLD_TO_CAMERA[:3, :3] @ point + WORLD_TO_CAMERA[:3, 3])


def finite_difference_jacobian(f, point: Tensor, step: float = 1e-6) -> Tensor:
    """(2, 3) central differences of f at `point`."""
    columns = [(f(point + step * e) - f(point - step * e)) / (2 * step) for e in torch.eye(3, dtype=D)]
    return torch.stack(columns, dim=1)


def hand_covariances() -> Tensor:
    """(N, 2, 2) J Σ Jᵀ with J the finite-difference Jacobian of world point → pixel and Σ = R S² Rᵀ (no blur)."""
    sigmas = ROTATIONS @ torch.diag_embed(SCALES**2) @ ROTATIONS.transpose(1, 2)
    jacobians = torch.stack([finite_difference_jacobian(world_pixel, m) for m in MEANS])
    return jacobians @ sigmas @ jacobians.transpose(1, 2)


def test_wxyz_quaternions_of_any_length_rotate_as_rodrigues_says():
    torch.testing.assert_close(quaternion_to_rotation(QUATS), ROTATIONS, rtol=0, atol=1e-14)
    quarter_turn_about_z = quaternion_to_rotation(torch.tensor([[math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)]],
                                                               dtype=D))[0]
    torch.testing.assert_close(quarter_turn_about_z @ torch.tensor([1.0, 0.0, 0.0], dtype=D),
                               torch.tensor([0.0, 1.0, 0.0], dtype=D), rtol=0, atol=1e-15)


@pytest.mark.parametrize("blur", [0.3, 0.1])
def test_projected_means_depths_and_covariances_match_the_pinhole_model_by_finite_differences(blur):
    """All three Gaussians sit inside the image's x/z, y/z range, so the Jacobian clamp leaves them alone."""
    proj = project_gaussians(MEANS, QUATS, SCALES, WORLD_TO_CAMERA, K, WIDTH, HEIGHT, 0.01, 1e10, False, blur)
    assert proj.visible.all()
    torch.testing.assert_close(proj.means2d, torch.stack([world_pixel(m) for m in MEANS]), rtol=0, atol=1e-12)
    torch.testing.assert_close(proj.depths, MEANS @ WORLD_TO_CAMERA[2, :3] + WORLD_TO_CAMERA[2, 3], rtol=0, atol=1e-14)
    expected = hand_covariances() + blur * torch.eye(2, dtype=D)
    got = torch.stack([proj.cov2d[:, 0], proj.cov2d[:, 1], proj.cov2d[:, 1], proj.cov2d[:, 2]], -1).reshape(-1, 2, 2)
    torch.testing.assert_close(got, expected, rtol=1e-7, atol=1e-8)
    # the sheared conic the compositor reads is inv(cov2d): σ = ½A(v − S·w)² + ½Q·w², with w the longer axis
    A, S, Q = conic_rows(proj.log_conics, D)
    along, across, cross = A, A * S * S + Q, -A * S
    conic = torch.stack([torch.where(proj.swapped, across, along), cross, cross,
                         torch.where(proj.swapped, along, across)], -1).reshape(-1, 2, 2)
    torch.testing.assert_close(conic, torch.linalg.inv(expected), rtol=1e-7, atol=1e-8)
    lam_max = torch.linalg.eigvalsh(expected)[:, 1]
    assert proj.radii.tolist() == torch.ceil(3 * lam_max.sqrt()).int().tolist()


def test_the_jacobian_is_the_pinhole_one_at_x_over_z_and_y_over_z_clamped_to_the_widened_image_range():
    """gsplat's limits: x/z in [−cx/fx − 0.3·tan, (W − cx)/fx + 0.3·tan] with tan = ½W/fx (y alike with fy, cy, H),
    i.e. ±1.3·tan(half-FoV) for a centred principal point. A mean past the right and the top edge gets the pinhole
    Jacobian of the camera-space point moved onto those limits, at its own depth."""
    z = 2.0
    beyond = torch.tensor([[5.0 * z, -3.0 * z, z]], dtype=D)  # camera space, x/z = 5, y/z = −3
    lim_x = (WIDTH - K[0, 2]) / K[0, 0] + 0.3 * 0.5 * WIDTH / K[0, 0]
    lim_y = -K[1, 2] / K[1, 1] - 0.3 * 0.5 * HEIGHT / K[1, 1]
    clamped = torch.tensor([lim_x * z, lim_y * z, z], dtype=D)
    rotation, scales = ROTATIONS[0], SCALES[:1]
    means = beyond @ rotation  # world = Rᵀ·camera, with this rotation as the camera's
    pose = torch.eye(4, dtype=D)
    pose[:3, :3] = rotation
    proj = project_gaussians(means, QUATS[:1], scales, pose, K, WIDTH, HEIGHT, 0.01, 1e10, False, 0.3)
    J = finite_difference_jacobian(pixel_of, clamped)
    sigma = rotation @ ROTATIONS[0] @ torch.diag(scales[0] ** 2) @ ROTATIONS[0].T @ rotation.T
    expected = J @ sigma @ J.T + 0.3 * torch.eye(2, dtype=D)
    torch.testing.assert_close(proj.cov2d[0], torch.stack([expected[0, 0], expected[0, 1], expected[1, 1]]),
                               rtol=1e-7, atol=1e-8)


@pytest.mark.parametrize(("blur", "antialiased"), [(0.3, False), (0.1, True)])
def test_a_rendered_gaussian_is_its_closed_form_at_every_pixel_centre(blur, antialiased):
    """α(p) = o·exp(−½ dᵀ cov2d⁻¹ d) at p = (j + 0.5, i + 0.5), with o scaled by sqrt(det Σ₂ / det(Σ₂ + blur·I))
    when antialiased (Mip-Splatting, gsplat); the expected depth of one Gaussian is its camera z."""
    opacity = 0.8
    out = rasterize(MEANS[:1], QUATS[:1], SCALES[:1], torch.tensor([opacity], dtype=D), torch.ones(1, 1, dtype=D),
                    WORLD_TO_CAMERA, K, WIDTH, HEIGHT, blur=blur, antialiased=antialiased)
    cov = hand_covariances()[0]
    blurred = cov + blur * torch.eye(2, dtype=D)
    if antialiased:
        opacity *= math.sqrt(torch.linalg.det(cov) / torch.linalg.det(blurred))
    rows, cols = torch.meshgrid(torch.arange(HEIGHT, dtype=D), torch.arange(WIDTH, dtype=D), indexing="ij")
    d = torch.stack([cols + 0.5, rows + 0.5], -1) - world_pixel(MEANS[0])
    alpha = opacity * torch.exp(-0.5 * torch.einsum("hwi,ij,hwj->hw", d, torch.linalg.inv(blurred), d))
    alpha = torch.where(alpha >= 1 / 255, alpha, 0.0)
    assert int((alpha > 0).sum()) > 20
    torch.testing.assert_close(out.alpha, alpha, rtol=0, atol=1e-7)
    z = MEANS[0] @ WORLD_TO_CAMERA[2, :3] + WORLD_TO_CAMERA[2, 3]
    torch.testing.assert_close(out.depth[alpha > 0], z.expand(int((alpha > 0).sum())), rtol=1e-12, atol=0)


def test_look_at_poses_are_opencv_and_their_centre_is_the_eye():
    """+z towards the target lands on the principal point, the world's up points to smaller image y, right to larger
    x; the centre −Rᵀt (the origin of the SH view directions, mean − centre) is the eye."""
    eye, target, up = torch.tensor([1.0, -2.0, 0.5], dtype=D), torch.tensor([0.2, 0.1, -0.3], dtype=D), AXES[2]
    camera = Camera(K, look_at(eye, target, up), WIDTH, HEIGHT)
    torch.testing.assert_close(camera.center(), eye, rtol=0, atol=1e-14)
    assert torch.det(camera.world_to_camera[:3, :3]).item() == pytest.approx(1.0)
    forward = (target - eye) / (target - eye).norm()
    upright = up - (up @ forward) * forward
    points = torch.stack([target, target + 0.1 * upright, target + 0.1 * torch.linalg.cross(forward, upright)])
    uv, z = camera.project(points)
    torch.testing.assert_close(uv[0], K[:2, 2], rtol=0, atol=1e-12)
    assert z[0].item() == pytest.approx(float((target - eye).norm()))
    assert uv[1, 1] < uv[0, 1] and uv[1, 0] == pytest.approx(uv[0, 0])
    assert uv[2, 0] > uv[0, 0] and uv[2, 1] == pytest.approx(uv[0, 1])
