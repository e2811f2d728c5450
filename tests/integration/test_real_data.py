"""Loaders on real captures from ../shared/data (skipped with the reason when absent).

lund_door proves our conventions (poses, K, undistortion, normalisation) against COLMAP's
own 2D observations; fox checks nerfstudio intrinsics, OPENCV undistortion and OpenGL poses.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pycolmap
import pytest
import torch

from splatu.data.config import DataConfig
from splatu.data.frames import downscaled
from splatu.data.images import compute_pixels, read_image
from splatu.data.process_images import ProcessImagesConfig, process_images
from splatu.data.resolve import load_camera_scene, load_scene, read_scene
from splatu.orbit import orbit_cameras, plan_orbit
from tests.conftest import shared_scene

pytestmark = pytest.mark.shared_data
DOWNSCALE = 8


def test_lund_door_points_reproject_onto_colmap_observations(tmp_path):
    root = shared_scene("lund_door")
    scene = load_scene(DataConfig(data=str(root), downscale=DOWNSCALE, cache_dir=tmp_path))
    cameras = {c.name: c for c in [*scene.train.cameras, *scene.eval.cameras]}
    assert len(cameras) == 12 and scene.points.shape == (11384, 3)
    assert scene.point_colors.shape == (11384, 3) and float(scene.point_colors.max()) <= 1.0

    reconstruction = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    errors = []
    for image in reconstruction.images.values():
        colmap_camera = reconstruction.cameras[image.camera_id]
        f, cx, cy, k = colmap_camera.params
        K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
        observations = [(p.xy, p.point3D_id) for p in image.points2D if p.has_point3D()]
        xy = np.array([o[0] for o in observations], dtype=np.float64)
        xyz = np.array([reconstruction.points3D[o[1]].xyz for o in observations])
        camera = cameras[image.name]
        # COLMAP's observations, undistorted with the same OpenCV model into our (downscaled) pinhole K.
        expected = cv2.undistortPoints(xy[:, None, :], K, np.array([k, 0.0, 0.0, 0.0]),
                                       P=camera.K.double().numpy()).reshape(-1, 2)
        points = (torch.tensor(xyz) - scene.center.double()) * scene.scale
        projected, depth = camera.to(dtype=torch.float64).project(points)
        assert bool((depth > 0).all())
        errors.append(np.linalg.norm(projected.numpy() - expected, axis=1))
    full_resolution_px = np.concatenate(errors) * DOWNSCALE
    assert len(full_resolution_px) == 73327
    assert np.median(full_resolution_px) < 1.0, np.median(full_resolution_px)


def test_fox_intrinsics_undistortion_and_a_common_look_at_point(tmp_path):
    root = shared_scene("fox")
    scene = load_scene(DataConfig(data=str(root), downscale=DOWNSCALE, cache_dir=tmp_path))
    cameras = [*scene.train.cameras, *scene.eval.cameras]
    assert len(cameras) == 67 and scene.train.images.shape[1:] == (240, 135, 3)

    # Intrinsics: the file's (1375.52, 1374.49, 554.558, 965.268) at 1/8, slightly zoomed by alpha=0 undistortion.
    K = cameras[0].K.double()
    assert K[0, 0].item() == pytest.approx(1375.52 / DOWNSCALE, rel=0.03)
    assert K[1, 1].item() == pytest.approx(1374.49 / DOWNSCALE, rel=0.03)
    assert K[0, 2].item() == pytest.approx(554.558 / DOWNSCALE, abs=2.0)
    assert K[1, 2].item() == pytest.approx(965.268 / DOWNSCALE, abs=2.0)
    K_file = np.array([[1375.52, 0, 554.558], [0, 1374.49, 965.268], [0, 0, 1]])
    D_file = np.array([0.0578421, -0.0805099, -0.000980296, 0.00015575])
    # alpha=0: every pixel of the undistorted image comes from inside the photo, and the crop is tight.
    K_full = K.numpy().copy()
    K_full[:2] *= DOWNSCALE
    v, u = np.mgrid[0:1920:8, 0:1080:8].astype(np.float64)
    border = (u == 0) | (v == 0) | (u >= 1072) | (v >= 1912)
    rays = np.stack([(u[border] + 0.5 - K_full[0, 2]) / K_full[0, 0], (v[border] + 0.5 - K_full[1, 2]) / K_full[1, 1],
                     np.ones(border.sum())], axis=1)
    distorted, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K_file, D_file)
    distorted = distorted.reshape(-1, 2)
    assert distorted.min() > -1.0 and (distorted[:, 0] < 1081).all() and (distorted[:, 1] < 1921).all()

    # Undistortion was applied: the loaded image matches OpenCV's own undistortion far better than a plain resize.
    name = scene.train.names[0]
    photo = read_image(root / name)
    shift = np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])  # OpenCV puts pixel centres at integers
    reference = cv2.undistort(photo, K_file - shift, D_file, None, K_full - shift)
    reference = cv2.resize(reference, (135, 240), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    plain = cv2.resize(photo, (135, 240), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    loaded = scene.train.images[0].numpy()
    to_reference, to_plain = np.abs(loaded - reference).mean(), np.abs(loaded - plain).mean()
    assert to_reference < 0.3 * to_plain, (to_reference, to_plain)

    # The optical axes pass near one point (the fox): least-squares closest point to all axes.
    centers = torch.stack([c.center() for c in cameras]).double().numpy()
    axes = np.stack([c.world_to_camera[2, :3].double().numpy() for c in cameras])  # camera +z in world
    projectors = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    point = np.linalg.solve(projectors.sum(0), np.einsum("nij,nj->i", projectors, centers))
    distances = np.linalg.norm(np.einsum("nij,nj->ni", projectors, point - centers), axis=1)
    ranges = np.linalg.norm(point - centers, axis=1)
    # Measured: 0.13 (axes miss the point by ~7 degrees, a hand-held capture); camera x or y axes give 0.64-0.85.
    assert np.median(distances / ranges) < 0.25
    in_front = np.einsum("ni,ni->n", point - centers, axes)
    assert (in_front > 0).all()  # the point is in front of every camera, so axes are +z forward


def _bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """`image` at (u, v) in splatu's convention (pixel centres at +0.5), edges clamped."""
    x, y = u - 0.5, v - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    ax, ay = (x - x0)[..., None], (y - y0)[..., None]
    height, width = image.shape[:2]
    xs = np.clip(x0, 0, width - 1), np.clip(x0 + 1, 0, width - 1)
    ys = np.clip(y0, 0, height - 1), np.clip(y0 + 1, 0, height - 1)
    return ((1 - ax) * (1 - ay) * image[ys[0], xs[0]] + ax * (1 - ay) * image[ys[0], xs[1]]
            + (1 - ax) * ay * image[ys[1], xs[0]] + ax * ay * image[ys[1], xs[1]])


@pytest.mark.parametrize("downscale", [1, 16])  # 1080 / 16 = 67.5: the width rounds to 68, an uneven factor
def test_fox_pixels_are_the_photo_seen_through_brown_conrady_by_hand(downscale):
    """Independent of OpenCV's model: each loaded pixel's ray (through splatu's K) is distorted with the
    Brown-Conrady formulas and the file's k1, k2, p1, p2, and the photo sampled there (averaged over the pixel's
    footprint when downscaled). Measured: 0.0009-0.0010 mean error (quantisation); the photo's K taken half a pixel
    off (OpenCV's integer centres) gives 0.006 at full size and 0.0026 at 1/16, K scaled by 1/16 instead of 68/1080
    gives 0.014, and p1 and p2 swapped fail both."""
    root = shared_scene("fox")
    raw = read_scene(DataConfig(data=str(root)))
    frame = downscaled(raw, downscale).frames[0]
    K = frame.camera.K.numpy()
    fx, fy, cx, cy = 1375.52, 1374.49, 554.558, 965.268
    k1, k2, p1, p2 = 0.0578421, -0.0805099, -0.000980296, 0.00015575
    photo = read_image(frame.image.path).astype(np.float64) / 255
    v, u = np.mgrid[0:frame.camera.height, 0:frame.camera.width].astype(np.float64)
    expected = np.zeros((*u.shape, 3))
    for a, b in np.ndindex(downscale, downscale):  # sample points spread evenly over each pixel
        x = (u + (a + 0.5) / downscale - K[0, 2]) / K[0, 0]
        y = (v + (b + 0.5) / downscale - K[1, 2]) / K[1, 1]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        assert (np.abs(fx * xd + cx - 540) <= 540.5).all() and (np.abs(fy * yd + cy - 960) <= 960.5).all()
        expected += _bilinear(photo, fx * xd + cx, fy * yd + cy) / downscale**2
    loaded = compute_pixels(frame.image).astype(np.float64) / 255
    assert np.abs(loaded - expected)[2:-2, 2:-2].mean() < 0.002


def test_second_load_hits_the_image_cache(tmp_path):
    root = shared_scene("lund_door")
    cfg = DataConfig(data=str(root), downscale=DOWNSCALE, cache_dir=tmp_path)
    first = load_scene(cfg)
    assert len(list((tmp_path / "pixels").glob("*.npy"))) == 12
    second = load_scene(cfg)
    assert torch.equal(first.train.images, second.train.images)


@pytest.mark.slow
def test_process_images_reconstructs_lund_door_and_the_loader_reads_it(tmp_path, capfd):
    """~30-45 s on 2 busy cores: SIFT on 12 photos at 484 px, exhaustive matching, incremental mapping. Two photos
    are of another size (one camera per photo; one shared camera dropped them), and the scene folder already holds
    a transforms.json, which `--data <folder>` would load instead, so the printed line names sparse/0."""
    photos = tmp_path / "photos"
    photos.mkdir()
    for i, path in enumerate(sorted((shared_scene("lund_door") / "images").glob("*.JPG"))):
        size = (270, 404) if i in (3, 8) else (324, 484)
        cv2.imwrite(str(photos / path.name), cv2.resize(cv2.imread(str(path)), size, interpolation=cv2.INTER_AREA))
    (tmp_path / "scene").mkdir()
    (tmp_path / "scene" / "transforms.json").write_text("{}")
    output = process_images(ProcessImagesConfig(images=photos, output=tmp_path / "scene", max_image_size=640))
    data = output / "sparse" / "0"
    assert f"train on it with: splatu train --data {data}" in capfd.readouterr().err.splitlines()
    scene = load_scene(DataConfig(data=str(data), cache_dir=tmp_path / "cache", eval_split="every-n"))
    assert len(scene.train) + len(scene.eval) >= 10
    assert scene.points.shape[0] > 1000
    sizes = {(camera.height, camera.width) for camera in [*scene.train.cameras, *scene.eval.cameras]}
    assert sizes == {(484, 324), (404, 270)}


def test_the_default_orbit_of_a_one_sided_capture_keeps_to_its_side_and_out_of_its_surfaces(tmp_path):
    """lund_door (a door from the front, 40° of azimuth) and fox (93°) were orbited like a capture walked around:
    a full circle at half the radius, which put lund_door's orbit cameras 0.59 from its SfM points (the training
    cameras are at least 1.6 from them) and rendered walls and floaters in 15 of 24 frames."""
    fox = load_camera_scene(DataConfig(data=str(shared_scene("fox")), downscale=DOWNSCALE, cache_dir=tmp_path))
    assert plan_orbit(fox.train.cameras).half_width is not None
    door = load_scene(DataConfig(data=str(shared_scene("lund_door")), downscale=DOWNSCALE, cache_dir=tmp_path))
    plan = plan_orbit(door.train.cameras)
    assert plan.half_width is not None and plan.radius_scale == 1.0
    assert math.degrees(plan.cover.width) == pytest.approx(40.0, abs=1.0)

    def nearest_point(cameras) -> torch.Tensor:
        return torch.cdist(torch.stack([c.center().float() for c in cameras]), door.points).min(dim=1).values

    clearance = float(nearest_point(door.train.cameras).min())
    orbit = [f.camera for f in orbit_cameras(door.train.cameras, 24)]
    assert float(nearest_point(orbit).min()) > 0.5 * clearance
    frame = plan.frame
    facing = torch.stack([c.center().double() - frame.center for c in orbit]) @ frame.forward_axis
    assert bool((facing > 0.5 * frame.radius).all())  # every orbit camera in front of the door, none behind it
