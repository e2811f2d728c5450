"""Exports in the data's own frame: SH rotation, quaternion composition, and a PLY that renders the same."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from splatu.camera import Camera
from splatu.errors import SplatuError
from splatu.model import GaussianModel, ModelConfig
from splatu.ply import load_ply, save_ply
from splatu.rasterizer.projection import quaternion_to_rotation
from splatu.sh import eval_sh, num_sh_bases
from splatu.world_frame import (
    WorldTransform,
    normalised_world_to_camera,
    require_same_frame,
    rotation_to_quaternion,
    sh_rotation,
)

TURN = torch.tensor([[0.36, 0.48, -0.8], [-0.8, 0.6, 0.0], [0.48, 0.64, 0.6]], dtype=torch.float64)
"""A proper rotation (det +1) about a skew axis by about 110°."""


def random_rotation(seed: int) -> torch.Tensor:
    q, r = torch.linalg.qr(torch.randn(3, 3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r))
    return q if torch.linalg.det(q) > 0 else -q


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_rotated_sh_in_rotated_directions_equals_the_original(degree):
    g = torch.Generator().manual_seed(degree)
    coeffs = torch.randn(num_sh_bases(degree), 2, generator=g, dtype=torch.float64)
    dirs = torch.randn(50, 3, generator=g, dtype=torch.float64)
    for rotation in (TURN, random_rotation(degree)):
        rotated = sh_rotation(rotation, degree) @ coeffs
        torch.testing.assert_close(eval_sh(rotated, dirs @ rotation.T, degree), eval_sh(coeffs, dirs, degree))
    if degree:  # a rotation really changes the coefficients (the test above is not vacuous)
        assert not torch.allclose(sh_rotation(TURN, degree), torch.eye(num_sh_bases(degree), dtype=torch.float64))


def test_quaternion_of_a_rotation_gives_that_rotation_back_at_any_angle():
    half_turn = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))  # trace −1: the hard case
    for rotation in (TURN, half_turn, torch.eye(3, dtype=torch.float64), *(random_rotation(s) for s in range(5))):
        back = quaternion_to_rotation(rotation_to_quaternion(rotation)[None])[0]
        torch.testing.assert_close(back, rotation)


def _model(n: int = 40) -> GaussianModel:
    g = torch.Generator().manual_seed(0)
    cfg = ModelConfig(sh_degree=3, u_sh_degree=2)
    model = GaussianModel.empty_like_config(n, cfg)
    with torch.no_grad():
        model.means.copy_((torch.rand(n, 3, generator=g) - 0.5) * 0.8)
        model.quats.copy_(torch.randn(n, 4, generator=g))
        model.log_scales.copy_(torch.log(torch.rand(n, 3, generator=g) * 0.08 + 0.02))
        model.opacity_logits.copy_(torch.randn(n, generator=g))
        model.sh_dc.copy_(torch.randn(n, 1, 3, generator=g) * 0.5)
        model.sh_rest.copy_(torch.randn(model.sh_rest.shape, generator=g) * 0.3)
        model.u_sh.copy_(torch.randn(model.u_sh.shape, generator=g))
    return model


def _camera_in_world(camera: Camera, to_world: WorldTransform) -> Camera:
    """The same camera with the world moved by `to_world`: x_cam·scale = R_c Rᵀ (x_w − t) + scale·t_c."""
    w2c = camera.world_to_camera.double()
    rotation = w2c[:3, :3] @ to_world.rotation.T
    world = torch.eye(4, dtype=torch.float64)
    world[:3, :3] = rotation
    world[:3, 3] = -rotation @ to_world.translation + to_world.scale * w2c[:3, 3]
    return dataclasses.replace(camera, world_to_camera=world.float(), near=camera.near * to_world.scale)


def test_a_ply_exported_in_the_world_frame_renders_the_same_from_the_same_camera_in_that_frame(tmp_path):
    model = _model()
    to_world = WorldTransform(TURN, torch.tensor([10.0, -3.0, 2.0], dtype=torch.float64), 2.5)
    save_ply(model, tmp_path / "splat.ply", to_world, uncertainty=True)
    exported = load_ply(tmp_path / "splat.ply", ModelConfig())

    torch.testing.assert_close(exported.means.double(), to_world.points(model.means), atol=1e-5, rtol=1e-6)
    torch.testing.assert_close(exported.log_scales, model.log_scales + math.log(2.5))
    K = torch.tensor([[40.0, 0, 24], [0, 40.0, 20], [0, 0, 1]])
    for position in ([0.3, -2.0, 0.4], [-1.5, 0.5, -1.2]):
        center = torch.tensor(position)
        forward = -center / center.norm()
        right = torch.linalg.cross(forward, torch.tensor([0.0, 0.0, 1.0]))
        right = right / right.norm()
        R = torch.stack([right, torch.linalg.cross(forward, right), forward])
        w2c = torch.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R, -R @ center
        camera = Camera(K, w2c, 48, 40)
        before = model.render(camera, 3, torch.zeros(3), with_uncertainty=True)
        after = exported.render(_camera_in_world(camera, to_world), 3, torch.zeros(3), with_uncertainty=True)
        assert float(before.alpha.detach().mean()) > 0.1  # the view sees the Gaussians
        torch.testing.assert_close(after.rgb, before.rgb, atol=2e-4, rtol=0)
        torch.testing.assert_close(after.uncertainty, before.uncertainty, atol=2e-4, rtol=0)
        torch.testing.assert_close(after.depth, before.depth * 2.5, atol=2e-3, rtol=1e-4)


@pytest.mark.parametrize("rotation", [torch.diag(torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64)),
                                      TURN @ torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64)),
                                      2.0 * torch.eye(3, dtype=torch.float64)])
def test_a_world_transform_refuses_a_mirror_or_a_matrix_that_is_no_rotation(rotation):
    """A mirror would turn every Gaussian inside out (its quaternion cannot express it); a scaled matrix is no
    rotation (the scale is its own field)."""
    with pytest.raises(ValueError, match="proper rotation"):
        WorldTransform(rotation, torch.zeros(3, dtype=torch.float64), 1.0)
    with pytest.raises(ValueError, match="positive scale"):
        WorldTransform(TURN, torch.zeros(3, dtype=torch.float64), -1.0)
    WorldTransform(TURN, torch.zeros(3, dtype=torch.float64), 1.0)


def test_a_world_transform_refuses_non_finite_or_misshapen_parts():
    """A NaN rotation has a NaN determinant, which no tolerance test rejects; an infinite scale is still > 0."""
    nan_turn = TURN.clone()
    nan_turn[0, 0] = float("nan")
    zero = torch.zeros(3, dtype=torch.float64)
    for rotation, translation, scale in ((nan_turn, zero, 1.0), (TURN, zero, float("inf")),
                                         (TURN, torch.tensor([0.0, float("inf"), 0.0]), 1.0), (TURN, zero[:2], 1.0)):
        with pytest.raises(ValueError, match="finite proper rotation"):
            WorldTransform(rotation, translation, scale)


def test_frames_that_differ_only_in_scale_do_not_match():
    """Cameras moved apart around the same centre give the same translation but another scale: a model trained in
    the old frame would come out at the wrong size, so the scene is refused; float noise is not a difference."""
    center = torch.tensor([5.0, -1.0, 2.0])
    trained = WorldTransform.from_normalization(center, 0.25)
    assert trained.matches(WorldTransform.from_normalization(center, 0.25 * (1 + 1e-9)))
    moved = WorldTransform.from_normalization(center, 0.26)
    assert not trained.matches(moved) and not moved.matches(trained)
    with pytest.raises(SplatuError, match="normalisation"):
        require_same_frame(trained, moved, "in run", "start a new run")
    require_same_frame(None, moved, "in run", "start a new run")  # checkpoints older than the record pass


def test_a_data_frame_camera_moved_into_the_model_frame_sees_the_same_pixels_at_scaled_depths():
    """What `splatu.query` renders: a candidate camera in the data's frame, moved into the normalised one."""
    from splatu.camera import look_at

    frame = WorldTransform(random_rotation(7), torch.tensor([3.0, -2.0, 5.0], dtype=torch.float64), 4.5)
    K = torch.tensor([[100.0, 0.0, 32.0], [0.0, 90.0, 24.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    data_w2c = look_at(torch.tensor([10.0, 4.0, -3.0], dtype=torch.float64), frame.translation,
                       torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    points = torch.randn(30, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 0.3
    uv_data, z_data = Camera(K, data_w2c, 64, 48).project(frame.points(points))
    uv_model, z_model = Camera(K, normalised_world_to_camera(data_w2c, frame), 64, 48).project(points)
    torch.testing.assert_close(uv_model, uv_data)
    torch.testing.assert_close(z_model * frame.scale, z_data)
    assert (z_data > 0).all() and not torch.allclose(z_model, z_data)  # in front, and the depths really scale


def test_scene_cameras_give_the_pose_from_the_file_and_the_undistorted_downscaled_K_the_run_trained_at(tmp_path):
    """A distorted capture trains on images undistorted to OpenCV's alpha=0 pinhole, and --downscale rounds each
    side: the K to query its views with is neither the file's K nor K / N. Only the scene's files are read."""
    import numpy as np

    from splatu.data.config import DataConfig
    from splatu.data.frames import world_to_camera_from_opengl
    from splatu.data.images import Distortion, undistorted_intrinsics
    from splatu.data.normalize import normalization
    from splatu.query import scene_cameras
    from tests.synthetic_scenes import ring_cameras, write_transforms

    cameras = ring_cameras(6, 41, 31)
    write_transforms(tmp_path / "transforms.json", cameras, [c.name for c in cameras],
                     top_extras={"k1": 0.08, "k2": -0.05})  # no image is written: none is read
    center, scale = normalization(torch.stack([c.center() for c in cameras]))
    frame = WorldTransform.from_normalization(center.float(), scale)
    found = scene_cameras(DataConfig(data=str(tmp_path), downscale=2), frame)
    assert list(found) == [c.name for c in cameras]
    file_K = cameras[0].K.numpy()
    K = undistorted_intrinsics(file_K, Distortion("OPENCV", (0.08, -0.05, 0.0, 0.0, 0.0)), 41, 31, "test")
    K[0] *= 20 / 41  # 41 / 2 rounds to 20, 31 / 2 to 16
    K[1] *= 16 / 31
    for camera in cameras:
        world_to_camera, got_K, width, height = found[camera.name]
        assert (width, height) == (20, 16)
        np.testing.assert_allclose(got_K, K, rtol=1e-12)
        assert np.abs(got_K[:2, :2] - file_K[:2, :2] / 2).max() > 0.1  # not the file's K halved
        np.testing.assert_allclose(world_to_camera, camera.world_to_camera.numpy(), atol=1e-12)
        np.testing.assert_allclose(
            world_to_camera, world_to_camera_from_opengl(np.array(_transform_matrix(tmp_path, camera.name))),
            atol=1e-12)
    elsewhere = WorldTransform.from_normalization(center.float() + 1.0, scale)
    with pytest.raises(SplatuError, match="normalisation differs"):
        scene_cameras(DataConfig(data=str(tmp_path), downscale=2), elsewhere)
    with pytest.raises(SplatuError, match="the run's scene is not at"):
        scene_cameras(DataConfig(data=str(tmp_path / "moved")), frame)


def _transform_matrix(root, name: str) -> list[list[float]]:
    import json

    return next(f["transform_matrix"] for f in json.loads((root / "transforms.json").read_text())["frames"]
                if f["file_path"] == name)


def test_the_frame_of_a_scene_far_from_the_origin_is_the_one_its_cameras_were_normalised_in(tmp_path):
    """Cameras in map coordinates (here 10⁶ off the origin, as a georeferenced capture has them) are normalised
    around their float64 mean; the recorded frame rounded that centre to float32, up to 3 cm off at 10⁶, so
    exports and candidate views (`splatu.query`, `--views cameras`) landed that far from where they belong."""
    from splatu.data.config import DataConfig
    from splatu.data.resolve import load_scene
    from splatu.world_frame import scene_frame
    from tests.synthetic_scenes import ring_cameras, write_nerfstudio_scene, write_transforms

    write_nerfstudio_scene(tmp_path / "scene")
    far = ring_cameras(8, 40, 30, offset=(1e6 + 0.3, -2e6 + 0.7, 50.0))
    write_transforms(tmp_path / "scene" / "transforms.json", far, [c.name for c in far])
    scene = load_scene(DataConfig(data=str(tmp_path / "scene"), eval_split="every-n", eval_every=4,
                                  cache_dir=tmp_path / "cache"))
    frame = scene_frame(scene)
    by_name = {c.name: c for c in far}
    for name, normalised in zip(scene.train.names, scene.train.cameras, strict=True):
        moved = normalised_world_to_camera(by_name[name].world_to_camera, frame)
        torch.testing.assert_close(moved.float(), normalised.world_to_camera, rtol=0, atol=1e-5)
    # a frame recorded before, with its centre rounded to float32, is still this scene's frame, not another one
    rounded = WorldTransform.from_normalization(frame.translation.float(), 1.0 / frame.scale)
    assert rounded.matches(frame) and frame.matches(rounded)
    assert not rounded.matches(WorldTransform.from_normalization(frame.translation + 1e-3, 1.0 / frame.scale))
