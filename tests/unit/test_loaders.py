"""Scene loaders: nerfstudio, NeRF-synthetic and COLMAP parsing, undistortion, splits, normalisation, cache."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest
import torch

from splatu.cli import entrypoint
from splatu.data import colmap, images
from splatu.data.config import DataConfig
from splatu.data.frames import downscaled, world_to_camera_from_opengl
from splatu.data.images import (
    Distortion,
    ImageCache,
    PixelRecipe,
    as_float,
    compute_pixels,
    load_pixels,
    truncated_format,
)
from splatu.data.nerfstudio import load_nerfstudio, read_cameras
from splatu.data.normalize import normalize_camera
from splatu.data.ply import read_ply_points, write_ply_points
from splatu.data.poster import PosterConfig
from splatu.data.poster.path import camera_path
from splatu.data.resolve import (
    downscale_note,
    load_camera_scene,
    load_new_scene,
    load_scene,
    read_scene,
    read_scene_files,
    refuse_unused_poster_options,
    with_chosen_downscale,
)
from splatu.errors import DownscaleError, SplatuError
from tests.conftest import shared_scene
from tests.synthetic_scenes import noise_image, ring_cameras, write_nerfstudio_scene, write_rgb, write_transforms


def config(path: Path, tmp_path: Path, **overrides) -> DataConfig:
    return DataConfig(data=str(path), cache_dir=tmp_path / "cache", **overrides)


def test_a_mask_file_keeps_every_pixel_that_is_not_0_whatever_its_value(tmp_path):
    """As nerfstudio reads masks. One saved as 0/1 weighted its kept pixels by 1/255: training saw near-black
    images, and evaluation scored them at 59 dB."""
    root = tmp_path / "scene"
    cameras = ring_cameras(4, 40, 30)
    for i, camera in enumerate(cameras):
        write_rgb(root / camera.name, noise_image(i, 40, 30))
        mask = np.full((30, 40), (1, 128, 255, 1)[i], np.uint8)
        mask[:, :10] = 0
        cv2.imwrite(str(root / f"mask_{i}.png"), mask)
    write_transforms(root / "transforms.json", cameras, [c.name for c in cameras],
                     frame_extras=[{"mask_path": f"mask_{i}.png"} for i in range(4)])
    scene = load_scene(config(root, tmp_path, eval_split="every-n", eval_every=2))
    expected = torch.ones(30, 40)
    expected[:, :10] = 0
    for views in (scene.train, scene.eval):
        assert all(torch.equal(mask, expected) for mask in views.mask_files)


def test_a_camera_scene_is_the_scenes_training_cameras_and_masks_without_decoding_an_image(tmp_path):
    """`load_camera_scene` splits and normalises as `load_scene` does, and decodes the mask files only when asked:
    with every photo gone (and the cache emptied) it still loads, where `load_scene` cannot."""
    root = tmp_path / "scene"
    cameras = ring_cameras(6, 40, 30)
    for i, camera in enumerate(cameras):
        write_rgb(root / camera.name, noise_image(i, 40, 30))
        mask = np.full((30, 40), 255, np.uint8)
        mask[:i] = 0
        cv2.imwrite(str(root / f"mask_{i}.png"), mask)
    write_transforms(root / "transforms.json", cameras, [c.name for c in cameras],
                     frame_extras=[{"mask_path": f"mask_{i}.png"} for i in range(6)])
    cfg = config(root, tmp_path, eval_split="every-n", eval_every=3)
    scene = load_scene(cfg)
    for camera in cameras:
        (root / camera.name).unlink()
    shutil.rmtree(tmp_path / "cache")
    with pytest.raises(SplatuError, match="not found"):
        load_scene(cfg)
    loaded = load_camera_scene(cfg, masks=True)
    assert torch.equal(loaded.center, scene.center) and loaded.scale == scene.scale
    assert loaded.train.names == scene.train.names
    assert all(torch.equal(a.world_to_camera, b.world_to_camera) and torch.equal(a.K, b.K)
               for a, b in zip(loaded.train.cameras, scene.train.cameras, strict=True))
    assert torch.equal(loaded.train.mask_files, scene.train.mask_files)
    shutil.rmtree(tmp_path / "cache")
    for i in range(6):
        (root / f"mask_{i}.png").write_bytes(b"not a png")
    assert load_camera_scene(cfg).train.mask_files is None  # not asked for: not read
    with pytest.raises(SplatuError):
        load_camera_scene(cfg, masks=True)


def test_normalisation_keeps_every_pixel_of_a_pose_written_to_four_decimals(tmp_path):
    """Rotations written to 4 decimals are orthonormal to ~1e-4 only (the loader accepts 1e-3): normalising through
    the centre −Rᵀt moved each point by (R·Rᵀ − I)·t in the camera's frame: 0.01 px here at f = 140, ten times that at
    a phone's f = 1400. The loaded cameras must project the loaded points where the file's cameras put the file's."""
    root = tmp_path / "scene"
    rng = np.random.default_rng(3)
    points = rng.normal(size=(40, 3)) * 0.5
    root.mkdir()
    write_ply_points(root / "points.ply", points, np.full((40, 3), 0.5))
    frames, originals = [], []
    for i in range(6):
        c2w = np.eye(4)
        c2w[:3, :3] = np.round(cv2.Rodrigues(rng.normal(size=3))[0], 4)
        c2w[:3, 3] = c2w[:3, 2] * 4 + rng.normal(size=3) * 0.3  # OpenGL: looks along −z, at the origin
        write_rgb(root / f"{i}.png", noise_image(i, 108, 192))
        frames.append({"file_path": f"{i}.png", "transform_matrix": c2w.tolist()})
        originals.append(torch.tensor(world_to_camera_from_opengl(c2w)))
    (root / "transforms.json").write_text(json.dumps({
        "fl_x": 140.0, "fl_y": 140.0, "cx": 54.0, "cy": 96.0, "w": 108, "h": 192, "ply_file_path": "points.ply",
        "frames": frames}))
    scene = load_scene(config(root, tmp_path, eval_split="every-n", eval_every=3))
    loaded = dict(zip([*scene.train.names, *scene.eval.names], [*scene.train.cameras, *scene.eval.cameras],
                      strict=True))
    normalised = (torch.tensor(points) - scene.center.double()) * scene.scale
    for i, world_to_camera in enumerate(originals):
        camera = loaded[f"{i}.png"].to(dtype=torch.float64)
        expected, depth = dataclasses.replace(camera, world_to_camera=world_to_camera).project(torch.tensor(points))
        projected, normalised_depth = camera.project(normalised)
        assert (projected - expected).abs().max() < 1e-3, (projected - expected).abs().max()  # float32 cameras
        assert torch.allclose(normalised_depth, depth * scene.scale, rtol=1e-5)


def test_nerfstudio_round_trip_gives_identical_cameras_points_and_pixels(tmp_path):
    root = tmp_path / "scene"
    rng = np.random.default_rng(1)
    points = rng.normal(size=(50, 3)) + np.array([10.0, -3.0, 2.0])
    colors = rng.integers(0, 256, (50, 3)) / 255.0
    root.mkdir()
    write_ply_points(root / "points.ply", points, colors)
    cameras = write_nerfstudio_scene(root, ply_file_path="points.ply")

    scene = load_scene(config(root, tmp_path, eval_split="contiguous", eval_block=2))

    centers = torch.stack([c.center() for c in cameras])
    expected_center = centers.mean(dim=0)
    expected_scale = 1.0 / float((centers - expected_center).norm(dim=1).max())
    assert torch.allclose(scene.center.double(), expected_center, atol=1e-5)
    assert scene.scale == pytest.approx(expected_scale, rel=1e-9)
    loaded = {c.name: c for c in [*scene.train.cameras, *scene.eval.cameras]}
    assert len(loaded) == len(cameras) and len(scene.eval) == 2
    for original in cameras:
        camera = loaded[original.name]
        expected = normalize_camera(original, expected_center, expected_scale)
        assert torch.allclose(camera.K.double(), original.K, atol=1e-5)
        assert torch.allclose(camera.world_to_camera.double(), expected.world_to_camera, atol=1e-5)
        assert (camera.width, camera.height) == (original.width, original.height)
    assert float(torch.stack([c.center() for c in loaded.values()]).norm(dim=1).max()) == pytest.approx(1.0, abs=1e-5)
    expected_points = (torch.tensor(points) - expected_center) * expected_scale
    assert torch.allclose(scene.points.double(), expected_points, atol=1e-5)
    assert torch.allclose(scene.point_colors.double(), torch.tensor(colors), atol=1e-6)
    index = int(cameras[[c.name for c in cameras].index(scene.train.names[0])].name[-7:-4])
    assert torch.equal(scene.train.images[0], torch.from_numpy(noise_image(index, 40, 30) / np.float32(255)))
    assert scene.train.images.dtype == torch.float32


def test_a_camera_file_gives_the_cameras_the_loader_builds_at_the_runs_downscale(tmp_path):
    """render-uncertainty --views cameras: a transforms.json's cameras without their images, as a run at
    --downscale 2 trained on them (file or folder)."""
    cameras = ring_cameras(3, 40, 30)
    write_transforms(tmp_path / "transforms.json", cameras, ["no/such/a.png", "b.png", "c.png"])
    for path in (tmp_path / "transforms.json", tmp_path):
        read = read_cameras(path, downscale=2)
        assert [c.name for c in read] == ["no/such/a.png", "b.png", "c.png"]
        for got, original in zip(read, cameras, strict=True):
            want = original.scaled(0.5)
            assert (got.width, got.height) == (want.width, want.height) == (20, 15)
            torch.testing.assert_close(got.K.double(), want.K.double())
            torch.testing.assert_close(got.world_to_camera.double(), original.world_to_camera.double())


def test_file_splits_depths_and_observed_masks(tmp_path):
    root = tmp_path / "scene"
    cameras = ring_cameras(8, 40, 30)
    names = [c.name for c in cameras]
    extras = []
    for i, camera in enumerate(cameras):
        write_rgb(root / camera.name, noise_image(i, 40, 30))
        np.save(root / f"depth_{i}.npy", np.full((30, 40), 2.0 + i, np.float32))
        observed = np.zeros((30, 40), np.uint8)
        observed[:, : 5 * i] = 255
        cv2.imwrite(str(root / f"observed_{i}.png"), observed)
        valid = np.full((30, 40), 255, np.uint8)
        valid[:i] = 0
        cv2.imwrite(str(root / f"mask_{i}.png"), valid)
        extras.append({"depth_file_path": f"depth_{i}.npy", "observed_mask_path": f"observed_{i}.png",
                       "mask_path": f"mask_{i}.png"})
    write_transforms(root / "transforms.json", cameras, names, frame_extras=extras, top_extras={
        "train_filenames": names[:5], "val_filenames": names[5:7], "test_filenames": names[7:]})

    scene = load_scene(config(root, tmp_path))
    assert scene.train.names == names[:5] and scene.eval.names == names[5:7]
    assert scene.extra_eval["interp"].names == names[7:]
    assert torch.allclose(scene.eval.depths[1], torch.full((30, 40), 8.0 * scene.scale))
    assert scene.eval.observed.dtype == torch.bool
    assert int(scene.eval.observed[1].sum()) == 30 * 30  # frame 6: 30 observed columns
    masks = scene.train.object_masks
    assert masks.shape == (5, 30, 40) and float(masks[3].sum()) == 27 * 40  # 3 rows masked
    assert torch.equal(scene.train.mask_files, masks) and scene.train.alphas is None  # what training weights

    other = load_scene(config(root, tmp_path, eval_split="every-n", eval_every=4))
    assert other.eval.names == [names[0], names[4]]
    assert other.eval.observed is None and other.eval.depths is not None  # observed is relative to the file's split

    half = load_scene(config(root, tmp_path, downscale=2))  # each file shrunk with its image: none has an images_2
    assert half.train.images.shape[1:3] == half.train.object_masks.shape[1:] == (15, 20)
    assert half.eval.depths.shape[1:] == half.eval.observed.shape[1:] == (15, 20)


def _smooth_pattern(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A colour that is a smooth function of the normalised ray (x, y): the ground truth of a pinhole image."""
    return np.stack([0.5 + 0.4 * np.sin(4 * x), 0.5 + 0.4 * np.cos(5 * y), 0.5 + 0.3 * np.sin(3 * (x + y))], axis=-1)


@pytest.mark.parametrize(("model", "coeffs", "downscale"), [
    ("OPENCV", (-0.25, 0.08, 0.002, -0.001), 1),
    ("OPENCV", (-0.25, 0.08, 0.002, -0.001), 2),
    ("OPENCV_FISHEYE", (0.05, -0.02, 0.01, 0.0), 1),
    ("OPENCV_FISHEYE", (0.0, 0.0, 0.0, 0.0), 1),  # an equidistant fisheye: it was loaded as a pinhole
])
def test_undistorted_image_matches_the_pinhole_camera(tmp_path, model, coeffs, downscale):
    """Render a distorted photo analytically, undistort it, and check each pixel sees the ray our K says."""
    width, height = 160, 120
    K = np.array([[110.0, 0.0, 81.3], [0.0, 112.0, 59.1], [0.0, 0.0, 1.0]])
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    pixels = np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1)[:, None, :]  # +0.5: pixel centres
    D = np.array(coeffs)
    if model == "OPENCV_FISHEYE":
        rays = cv2.fisheye.undistortPoints(pixels, K, D.reshape(4, 1)).reshape(height, width, 2)
    else:
        rays = cv2.undistortPoints(pixels, K, D, R=np.eye(3), P=np.eye(3), criteria=
                                   (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))
        rays = rays.reshape(height, width, 2)
    distorted = _smooth_pattern(rays[..., 0], rays[..., 1])
    root = tmp_path / "scene"
    write_rgb(root / "images" / "a.png", np.round(distorted * 255).astype(np.uint8))
    write_rgb(root / "images" / "b.png", np.round(distorted * 255).astype(np.uint8))
    frame = {"transform_matrix": np.eye(4).tolist()}
    (root / "transforms.json").write_text(json.dumps({
        "camera_model": model, "fl_x": K[0, 0], "fl_y": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "w": width,
        "h": height, **dict(zip(("k1", "k2", "k3", "k4") if model == "OPENCV_FISHEYE" else ("k1", "k2", "p1", "p2"),
                                coeffs, strict=True)),
        "frames": [{"file_path": "images/a.png", **frame}, {"file_path": "images/b.png", **frame}]}))

    scene = load_scene(config(root, tmp_path, downscale=downscale, eval_split="every-n", eval_every=2))
    camera, image = scene.train.cameras[0], scene.train.images[0].numpy()
    assert (camera.width, camera.height) == (width // downscale, height // downscale)
    Kn = camera.K.double().numpy()
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    expected = _smooth_pattern((u + 0.5 - Kn[0, 2]) / Kn[0, 0], (v + 0.5 - Kn[1, 2]) / Kn[1, 1])
    error = np.abs(image - expected)[2:-2, 2:-2]
    assert np.median(error) < 0.0018, np.median(error)  # measured ~0.0011; a half-pixel error in K gives > 0.0022
    naive = cv2.resize(distorted, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    assert np.median(np.abs(naive - expected)[2:-2, 2:-2]) > 3 * np.median(error)  # distortion was really removed


def test_images_n_folder_is_used_for_downscale(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=40, height=30)
    for i, camera in enumerate(cameras):
        write_rgb(root / "images_2" / Path(camera.name).name, noise_image(100 + i, 20, 15))
    scene = load_scene(config(root, tmp_path, downscale=2, eval_split="every-n", eval_every=2))
    frame = int(scene.train.names[0][-7:-4])
    assert torch.equal(scene.train.images[0], torch.from_numpy(noise_image(100 + frame, 20, 15) / np.float32(255)))
    assert torch.allclose(scene.train.cameras[0].K.double(), cameras[frame].scaled(0.5).K, atol=1e-6)

    without = load_scene(config(root, tmp_path, downscale=4, eval_split="every-n", eval_every=2))
    assert without.train.images.shape[1:3] == (8, 10)  # round(30 / 4), round(40 / 4): resized from full size


@pytest.mark.parametrize(("size", "fix"), [
    ((21, 15), "regenerate images_2 at 20x15 (1/2 of the camera's size), or remove images_2 to have the "
               "full-size images shrunk as they load"),
    # turned on its side, but its full-size image fits the camera: the copy alone is at fault (it said to swap the
    # camera's width and height, which would refuse every image that fits it)
    ((15, 20), "regenerate images_2 at 20x15 (1/2 of the camera's size), or remove images_2 to have the "
               "full-size images shrunk as they load"),
])
def test_a_downscaled_copy_of_the_wrong_size_is_told_against_the_cameras_size_in_the_file(tmp_path, size, fix):
    """It said "image is 21x15 but its camera says 20x15, ... fix the camera size": a size the file never held, and
    a camera that fits the full-size images."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=40, height=30)
    for i, camera in enumerate(cameras):
        width, height = size if i == 2 else (20, 15)
        write_rgb(root / "images_2" / Path(camera.name).name, noise_image(100 + i, width, height))
    with pytest.raises(SplatuError) as caught:
        load_scene(config(root, tmp_path, downscale=2, eval_split="every-n", eval_every=2))
    assert caught.value.what == f"image is {size[0]}x{size[1]}, but the camera's 40x30 at 1/2 of its size is 20x15"
    assert caught.value.where == f"in {root / 'images_2' / Path(cameras[2].name).name}"
    assert caught.value.fix == fix


@pytest.mark.parametrize("full_size", ["turned", "missing"])
def test_a_downscaled_copy_turned_as_its_full_size_image_is_says_to_swap_the_camera(tmp_path, full_size):
    """When the full-size image is turned too (or not there to compare), the camera may be the one the wrong way
    round, so the copy is not blamed."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=40, height=30)
    for i, camera in enumerate(cameras):
        write_rgb(root / "images_2" / Path(camera.name).name, noise_image(100 + i, 15 if i == 2 else 20,
                                                                          20 if i == 2 else 15))
    if full_size == "turned":
        write_rgb(root / cameras[2].name, noise_image(2, 30, 40))
    else:
        (root / cameras[2].name).unlink()
    with pytest.raises(DownscaleError) as caught:
        load_scene(config(root, tmp_path, downscale=2, eval_split="every-n", eval_every=2))
    assert caught.value.what == "image is 15x20, but the camera's 40x30 at 1/2 of its size is 20x15"
    assert caught.value.fix.startswith("swap the camera's width and height") and not caught.value.copy_at_fault


def test_a_wrong_downscaled_copy_under_the_chosen_downscale_is_not_told_to_drop_the_flag(tmp_path):
    """Without --downscale, train picks the factor itself and reads images_N: "drop --downscale" would pick the same
    factor again (and the user gave none), so the way to full size is --downscale 1."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=40, height=30)
    for i, camera in enumerate(cameras):
        write_rgb(root / "images_2" / Path(camera.name).name, noise_image(100 + i, 21 if i == 2 else 20, 15))
    given = config(root, tmp_path, max_image_size=30, eval_split="every-n", eval_every=2)
    assert chosen_for(given).downscale == 2
    with pytest.raises(SplatuError) as caught:
        load_new_scene(given)
    assert "drop --downscale" not in caught.value.fix
    assert caught.value.fix.endswith("(or train at full size with --downscale 1)")


def test_a_colmap_downscaled_copy_of_the_wrong_size_names_its_folder(tmp_path):
    """The image's name may hold folders of its own (cam1/img_1.png): the copy's folder is the one named images_N."""
    root = tmp_path / "scene"
    _write_colmap_text(root, "PINHOLE", [36.0, 36.0, 20.0, 15.0], ring_cameras(5, 40, 30))
    images_txt = root / "sparse" / "0" / "images.txt"
    images_txt.write_text(images_txt.read_text().replace(" img_", " cam1/img_"))
    shutil.move(root / "images", tmp_path / "flat")
    shutil.move(tmp_path / "flat", root / "images" / "cam1")
    for i in range(5):
        write_rgb(root / "images_2" / "cam1" / f"img_{i}.png", noise_image(100 + i, 20, 16 if i == 1 else 15))
    with pytest.raises(SplatuError) as caught:
        load_scene(config(root, tmp_path, downscale=2, eval_split="every-n", eval_every=3))
    assert str(caught.value) == (
        f"image is 20x16, but the camera's 40x30 at 1/2 of its size is 20x15, in "
        f"{root / 'images_2/cam1/img_1.png'}, regenerate images_2 at 20x15 (1/2 of the camera's size), or remove "
        "images_2 to have the full-size images shrunk as they load")


def test_blender_composites_rgba_on_background_and_records_alpha(tmp_path):
    root = tmp_path / "lego"
    angle = 0.69
    for split, count in (("train", 3), ("test", 2)):
        frames = []
        for i in range(count):
            rgba = noise_image(i, 20, 16, channels=4)
            write_rgb(root / split / f"r_{i}.png", rgba)
            pose = np.eye(4)
            pose[:3, 3] = [i, 2.0, 1.0]
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": pose.tolist()})
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": angle, "frames": frames}))

    scene = load_scene(config(root, tmp_path, background=(0.0, 1.0, 0.5)))
    assert scene.train.names == ["train/r_0", "train/r_1", "train/r_2"] and len(scene.eval) == 2
    rgba = noise_image(1, 20, 16, channels=4).astype(np.float32) / 255
    expected = rgba[..., :3] * rgba[..., 3:] + np.array([0.0, 1.0, 0.5], np.float32) * (1 - rgba[..., 3:])
    assert np.abs(scene.train.images[1].numpy() - expected).max() <= 0.5 / 255 + 1e-6
    assert torch.allclose(scene.train.object_masks[1], torch.from_numpy(rgba[..., 3]))
    assert scene.train.mask_files is None  # alpha is not a mask file: training recomposites it instead of ignoring it
    assert scene.train.cameras[0].K[0, 0].item() == pytest.approx(0.5 * 20 / math.tan(angle / 2), rel=1e-6)
    assert scene.points.shape == (0, 3)


def test_the_stored_background_moves_rgba_targets_by_rounding_only(tmp_path):
    """--background is only what the decoded images are stored on: a target on any render background is the same,
    within each load's 8-bit rounding of its stored composite, whatever colour they were stored on."""
    root = tmp_path / "lego"
    for split in ("train", "test"):
        frames = []
        for i in range(2):
            write_rgb(root / split / f"r_{i}.png", noise_image(10 * i + len(split), 20, 16, channels=4))
            pose = np.eye(4)
            pose[:3, 3] = [i, 2.0, 1.0]
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": pose.tolist()})
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": 0.69, "frames": frames}))
    white = load_scene(config(root, tmp_path / "a", background=(1.0, 1.0, 1.0)))
    black = load_scene(config(root, tmp_path / "b", background=(0.0, 0.0, 0.0)))
    assert (white.train.images[0] - black.train.images[0]).abs().max() > 0.5  # stored on different colours
    for render_background in (torch.zeros(3), torch.ones(3), torch.tensor([0.2, 0.9, 0.4])):
        for views in ("train", "eval"):
            for i in range(2):
                on_white = getattr(white, views).target(i, render_background)
                on_black = getattr(black, views).target(i, render_background)
                assert (on_white - on_black).abs().max() <= 1.0 / 255 + 1e-6


def chosen_for(given: DataConfig) -> DataConfig:
    """`given` with the downscale train would choose for its scene."""
    return with_chosen_downscale(given, read_scene(given))


@pytest.mark.parametrize(("sizes", "factor"), [
    ([(1600, 1200)], 1),  # at the limit: full size
    ([(1601, 900)], 2),
    ([(1296, 1936)], 2),  # lund_door's photos, portrait
    ([(4032, 3024)], 4),  # a phone's 12 megapixels: 1008x756
    ([(6000, 4000)], 4),
    ([(1000, 800), (3300, 2200)], 4),  # mixed sizes: the largest decides
])
def test_without_downscale_train_takes_the_power_of_two_that_brings_the_longer_side_to_1600(tmp_path, sizes, factor):
    """As nerfstudio's loaders choose when --downscale is not given: at full size, lund_door's 1296x1936 photos took
    2.3-2.6 s a step on 2 cores, so `fast` would have taken about 80 min (docs/results.md)."""
    cameras = [ring_cameras(len(sizes), width, height)[i] for i, (width, height) in enumerate(sizes)]
    write_transforms(tmp_path / "transforms.json", cameras, [f"images/{i}.png" for i in range(len(cameras))])
    given = config(tmp_path, tmp_path)
    chosen = chosen_for(given)
    assert chosen == dataclasses.replace(given, downscale=factor)
    note = downscale_note(given, chosen, max(max(size) for size in sizes) // factor)
    assert (note is None) == (factor == 1)
    assert note is None or note.startswith(f"note: images loaded at 1/{factor} of their size")
    for fixed in (1, 3):  # a given --downscale is kept, and nothing is said
        kept = dataclasses.replace(given, downscale=fixed)
        assert chosen_for(kept) == kept and downscale_note(kept, kept, 1000) is None


def test_max_image_size_sets_the_limit_and_is_checked(tmp_path, capsys):
    write_transforms(tmp_path / "transforms.json", ring_cameras(3, 1296, 1936), ["a.png", "b.png", "c.png"])
    for size, factor in ((2000, 1), (1936, 1), (1935, 2), (968, 2), (500, 4), (100, 32)):
        assert chosen_for(config(tmp_path, tmp_path, max_image_size=size)).downscale == factor
    with pytest.raises(SystemExit):
        entrypoint(["train", "--data", str(tmp_path), "--max-image-size", "0"])
    assert capsys.readouterr().err.strip().splitlines() == [
        "error: --max-image-size must be at least 8 (got 0), in the options, pass --max-image-size of at least 8"]


def test_the_chosen_downscale_never_shrinks_a_side_below_the_smallest_usable(tmp_path):
    """A panorama strip 8,000 px long and 40 px high: 1/8 would bring it to 1000 px, but its short side to 5."""
    write_transforms(tmp_path / "transforms.json", ring_cameras(3, 8000, 40), ["a.png", "b.png", "c.png"])
    assert chosen_for(config(tmp_path, tmp_path)).downscale == 4  # 2000x10: still 8 px or more a side
    write_transforms(tmp_path / "transforms.json", ring_cameras(3, 8000, 64), ["a.png", "b.png", "c.png"])
    assert chosen_for(config(tmp_path, tmp_path)).downscale == 8  # 1000x8: a side of 8 px is usable


def test_a_saved_config_without_a_downscale_loads_at_full_size_as_it_trained(tmp_path):
    """Runs saved before train chose the factor record `downscale: null`, and trained at full size: their renders,
    scores and resumes must load the scene at that size, whatever --max-image-size would choose now."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4, width=40, height=30)
    saved = config(root, tmp_path, max_image_size=30, eval_split="every-n", eval_every=2)  # would choose 1/2
    assert chosen_for(saved).downscale == 2
    for scene in (load_scene(saved), load_camera_scene(saved)):
        assert {(c.width, c.height) for c in scene.train.cameras} == {(40, 30)}


def _write_colmap_text(root: Path, model: str, params: list[float], cameras) -> None:
    sparse = root / "sparse" / "0"
    sparse.mkdir(parents=True)
    width, height = cameras[0].width, cameras[0].height
    (sparse / "cameras.txt").write_text(f"1 {model} {width} {height} {' '.join(map(str, params))}\n")
    lines = []
    for i, camera in enumerate(cameras):
        rotation = camera.world_to_camera[:3, :3].numpy()
        w, x, y, z = _quaternion(rotation)
        t = camera.world_to_camera[:3, 3].numpy()
        lines += [f"{i + 1} {w} {x} {y} {z} {t[0]} {t[1]} {t[2]} 1 img_{i}.png", ""]
        write_rgb(root / "images" / f"img_{i}.png", noise_image(i, width, height))
    (sparse / "images.txt").write_text("\n".join(lines) + "\n")
    (sparse / "points3D.txt").write_text("1 10.0 -3.0 2.0 255 0 128 0.5\n2 10.5 -3.0 2.5 0 255 0 0.5\n")


def test_colmap_quaternion_that_is_not_unit_is_normalised(tmp_path):
    """pycolmap keeps a quaternion as written; a scaled one must still give the rotation, not a scaled matrix."""
    cameras = ring_cameras(5, 40, 30)
    _write_colmap_text(tmp_path / "unit", "PINHOLE", [36.0, 36.0, 20.0, 15.0], cameras)
    _write_colmap_text(tmp_path / "scaled", "PINHOLE", [36.0, 36.0, 20.0, 15.0], cameras)
    images_txt = tmp_path / "scaled" / "sparse" / "0" / "images.txt"
    lines = [line.split() for line in images_txt.read_text().splitlines()]
    images_txt.write_text("\n".join(" ".join([t[0], *(str(2 * float(q)) for q in t[1:5]), *t[5:]]) if t else ""
                                   for t in lines) + "\n")
    unit, scaled = (load_scene(config(tmp_path / name, tmp_path, eval_split="every-n", eval_every=3))
                    for name in ("unit", "scaled"))
    for a, b in zip(unit.train.cameras, scaled.train.cameras, strict=True):
        assert torch.allclose(a.world_to_camera, b.world_to_camera, atol=1e-5)


def _quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    w = math.sqrt(max(0.0, 1 + np.trace(rotation))) / 2
    return (w, (rotation[2, 1] - rotation[1, 2]) / (4 * w), (rotation[0, 2] - rotation[2, 0]) / (4 * w),
            (rotation[1, 0] - rotation[0, 1]) / (4 * w))


def test_data_pointed_at_the_model_folder_finds_the_images_of_its_scene(tmp_path):
    """--data X/colmap/sparse/0 (nerfstudio's layout, images in X/images) used to look in X/colmap/images."""
    cameras = ring_cameras(5, 40, 30)
    _write_colmap_text(tmp_path / "plain", "PINHOLE", [36.0, 36.0, 20.0, 15.0], cameras)
    nested = tmp_path / "nested"
    _write_colmap_text(nested, "PINHOLE", [36.0, 36.0, 20.0, 15.0], cameras)
    (nested / "colmap").mkdir()
    (nested / "sparse").rename(nested / "colmap" / "sparse")
    for model in (tmp_path / "plain" / "sparse" / "0", nested / "colmap" / "sparse" / "0"):
        scene = load_scene(config(model, tmp_path, eval_split="every-n", eval_every=3))
        assert scene.train.names == ["img_1.png", "img_2.png", "img_4.png"], model


def test_colmap_text_model_poses_points_and_undistorted_intrinsics(tmp_path):
    cameras = ring_cameras(5, 40, 30)
    _write_colmap_text(tmp_path / "scene", "RADIAL", [36.0, 20.0, 15.0, -0.1, 0.01], cameras)
    scene = load_scene(config(tmp_path / "scene", tmp_path, eval_split="every-n", eval_every=3))
    assert scene.train.names == ["img_1.png", "img_2.png", "img_4.png"]
    for camera, original in zip(scene.train.cameras, [cameras[1], cameras[2], cameras[4]], strict=True):
        expected = normalize_camera(original, scene.center.double(), scene.scale)
        assert torch.allclose(camera.world_to_camera.double(), expected.world_to_camera, atol=1e-5)
    K = scene.train.cameras[0].K
    assert 30 < K[0, 0] < 36  # barrel distortion undistorted with alpha=0 zooms in slightly
    expected_points = (torch.tensor([[10.0, -3.0, 2.0], [10.5, -3.0, 2.5]]) - scene.center.float()) * scene.scale
    assert torch.allclose(scene.points, expected_points, atol=1e-5)
    assert torch.allclose(scene.point_colors[0], torch.tensor([1.0, 0.0, 128 / 255]))


def test_splits_contiguous_default_every_n_and_list(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=9, width=8, height=6)
    names = [c.name for c in cameras]
    contiguous = load_scene(config(root, tmp_path, split_seed=3))
    assert len(contiguous.eval) == 2  # round(0.22 * 9)
    held = [names.index(n) for n in contiguous.eval.names]
    assert held == list(range(held[0], held[0] + 2))
    every = load_scene(config(root, tmp_path, eval_split="every-n", eval_every=4))
    assert every.eval.names == [names[0], names[4], names[8]]
    listed = tmp_path / "eval.txt"
    listed.write_text(f"{names[2]}\n./{names[5]}\n")
    by_list = load_scene(config(root, tmp_path, eval_split="list", eval_list=listed))
    assert by_list.eval.names == [names[2], names[5]] and len(by_list.train) == 7


def test_image_cache_is_faster_the_second_time_and_follows_file_changes(tmp_path):
    path = tmp_path / "photo.jpg"
    write_rgb(path, cv2.resize(noise_image(0, 96, 72), (960, 720), interpolation=cv2.INTER_LINEAR))
    K = (800.0, 0.0, 480.0, 0.0, 800.0, 360.0, 0.0, 0.0, 1.0)
    recipe = PixelRecipe(path=path, kind="color", width=960, height=720, target_width=480, target_height=360, K=K,
                         distortion=Distortion("OPENCV", (-0.2, 0.05, 0.0, 0.0)), K_undistorted=K)
    cache = ImageCache(tmp_path / "cache")
    timings = {"cold": [], "warm": []}
    for _ in range(3):
        for entry in (tmp_path / "cache").glob("pixels/*.npy"):
            entry.unlink()
        start = time.perf_counter()
        cold = load_pixels(recipe, cache)
        timings["cold"].append(time.perf_counter() - start)
        start = time.perf_counter()
        warm = load_pixels(recipe, cache)
        timings["warm"].append(time.perf_counter() - start)
        assert np.array_equal(cold, warm)
    assert np.median(timings["warm"]) < 0.5 * np.median(timings["cold"]), timings
    assert np.array_equal(as_float(compute_pixels(recipe)), cold)  # cached result equals the uncached pipeline

    write_rgb(path, noise_image(1, 960, 720))
    os.utime(path, ns=(path.stat().st_atime_ns, path.stat().st_mtime_ns + 10**9))
    assert not np.array_equal(load_pixels(recipe, cache), cold)


@pytest.mark.parametrize("damage", [b"", b"\x93NUMPY\x01\x00v\x00{'descr'"])
def test_a_cache_entry_emptied_or_torn_is_recomputed(tmp_path, damage):
    path = tmp_path / "photo.png"
    write_rgb(path, noise_image(0, 32, 24))
    K = (30.0, 0.0, 16.0, 0.0, 30.0, 12.0, 0.0, 0.0, 1.0)
    recipe = PixelRecipe(path=path, kind="color", width=32, height=24, target_width=32, target_height=24, K=K,
                         distortion=None, K_undistorted=K)
    cache = ImageCache(tmp_path / "cache")
    first = load_pixels(recipe, cache)
    [entry] = (tmp_path / "cache").glob("pixels/*.npy")
    entry.write_bytes(damage)  # a full disk or a crash left this behind
    assert np.array_equal(load_pixels(recipe, cache), first)
    assert np.array_equal(np.load(entry), cache.load(recipe))


def test_an_unwritable_image_cache_is_one_line_naming_splatu_cache(tmp_path):
    path = tmp_path / "photo.png"
    write_rgb(path, noise_image(0, 32, 24))
    K = (30.0, 0.0, 16.0, 0.0, 30.0, 12.0, 0.0, 0.0, 1.0)
    recipe = PixelRecipe(path=path, kind="color", width=32, height=24, target_width=32, target_height=24, K=K,
                         distortion=None, K_undistorted=K)
    (tmp_path / "not-a-folder").write_text("")  # the cache folder cannot be created under a file
    with pytest.raises(SplatuError, match="SPLATU_CACHE") as caught:
        load_pixels(recipe, ImageCache(tmp_path / "not-a-folder" / "cache"))
    assert "--resume" not in str(caught.value)  # loading images is not a training to resume


@pytest.mark.parametrize("stored", [np.zeros((5, 5, 3), np.uint8), np.zeros((24, 32), np.uint8),
                                    np.zeros((24, 32, 3), np.float64)])
def test_a_cache_entry_of_another_shape_or_dtype_is_recomputed(tmp_path, stored):
    """A whole .npy that is not this recipe's array (another size, no channels, a dtype `as_float` cannot read)
    used to be returned as it was, and loading the scene raised a traceback."""
    path = tmp_path / "photo.png"
    write_rgb(path, noise_image(0, 32, 24))
    recipe = PixelRecipe(path=path, kind="color", width=32, height=24, target_width=32, target_height=24)
    cache = ImageCache(tmp_path / "cache")
    first = load_pixels(recipe, cache)
    [entry] = (tmp_path / "cache").glob("pixels/*.npy")
    np.save(entry, stored)
    assert np.array_equal(load_pixels(recipe, cache), first)
    assert np.array_equal(np.load(entry), cache.load(recipe))


def test_every_kind_of_cached_array_is_reused_not_recomputed(tmp_path, monkeypatch):
    """The check that sends a foreign .npy back to be recomputed must accept what the pipeline itself stores: 8- and
    16-bit colour, RGBA, masks and depths, or every load would decode every image again."""
    cv2.imwrite(str(tmp_path / "rgb16.png"), (noise_image(1, 32, 24).astype(np.uint16) * 257))
    cv2.imwrite(str(tmp_path / "rgba.png"), np.dstack([noise_image(2, 32, 24), np.full((24, 32), 200, np.uint8)]))
    cv2.imwrite(str(tmp_path / "mask.png"), (np.arange(32)[None, :].repeat(24, 0) > 10).astype(np.uint8) * 255)
    cv2.imwrite(str(tmp_path / "depth.png"), np.full((24, 32), 1500, np.uint16))
    np.save(tmp_path / "depth.npy", np.full((24, 32), 2.5, np.float64))
    recipes = [PixelRecipe(path=tmp_path / name, kind=kind, width=32, height=24, target_width=16, target_height=12)
               for name, kind in (("rgb16.png", "color"), ("rgba.png", "color"), ("mask.png", "mask"),
                                  ("depth.png", "depth"), ("depth.npy", "depth"))]
    cache = ImageCache(tmp_path / "cache")
    first = [load_pixels(recipe, cache) for recipe in recipes]
    computed = []
    monkeypatch.setattr(images, "compute_pixels", lambda recipe: computed.append(recipe) or 1 / 0)
    again = [load_pixels(recipe, cache) for recipe in recipes]
    assert computed == []
    for a, b in zip(first, again, strict=True):
        assert np.array_equal(a, b)


def _with_exif_thumbnail(jpeg: bytes, thumbnail: bytes) -> bytes:
    """`jpeg` with an APP1 (EXIF) segment holding a whole JPEG thumbnail, end-of-image marker and all."""
    payload = b"Exif\x00\x00" + thumbnail
    return jpeg[:2] + b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload + jpeg[2:]


def test_truncation_check_accepts_whole_jpegs_of_every_kind_and_refuses_any_cut():
    image = noise_image(0, 96, 64)
    plain, progressive, restarts = (cv2.imencode(".jpg", image, flags)[1].tobytes() for flags in (
        [], [cv2.IMWRITE_JPEG_PROGRESSIVE, 1], [cv2.IMWRITE_JPEG_RST_INTERVAL, 1]))
    exif = _with_exif_thumbnail(plain, cv2.imencode(".jpg", image[:16, :16])[1].tobytes())
    assert cv2.imdecode(np.frombuffer(exif, np.uint8), cv2.IMREAD_UNCHANGED).shape == image.shape
    for whole in (plain, progressive, restarts, exif):
        assert truncated_format(whole) is None
        assert truncated_format(whole + b"phone trailer \xff\xd8 data") is None  # after EOI: ignored, as by libjpeg
        cuts = range(4, len(whole) - 1, 37)
        assert [truncated_format(whole[:cut]) for cut in cuts] == ["JPEG"] * len(cuts)
    png = cv2.imencode(".png", image)[1].tobytes()
    assert truncated_format(png) is None and truncated_format(png[:-12]) == "PNG"  # no IEND chunk


@pytest.mark.shared_data
def test_truncation_check_accepts_a_real_capture_quickly():
    files = sorted((shared_scene("fox") / "images").glob("*.jpg"))
    assert len(files) > 50, "the fox capture should hold its 67 photos"
    contents = [path.read_bytes() for path in files]
    start = time.perf_counter()
    assert [truncated_format(data) for data in contents] == [None] * len(files)
    assert time.perf_counter() - start < 0.05 * len(files)  # measured ~0.5 ms per 0.5 MB photo
    assert truncated_format(contents[0][: len(contents[0]) // 2]) == "JPEG"


def test_ply_reader_ascii_and_binary(tmp_path):
    ascii_ply = tmp_path / "a.ply"
    ascii_ply.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                         "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
                         "element face 0\nproperty list uchar int vertex_indices\nend_header\n"
                         "1 2 3 255 0 0\n-1 0.5 2 0 0 255\n")
    xyz, rgb = read_ply_points(ascii_ply)
    assert np.allclose(xyz, [[1, 2, 3], [-1, 0.5, 2]]) and np.allclose(rgb, [[1, 0, 0], [0, 0, 1]])
    binary = tmp_path / "b.ply"
    write_ply_points(binary, xyz.astype(np.float64) * 2, None)
    xyz2, rgb2 = read_ply_points(binary)
    assert np.allclose(xyz2, xyz * 2) and rgb2 is None


def test_ply_point_reader_skips_elements_before_the_vertices_and_scales_16_bit_colours(tmp_path):
    """An element declared before the vertices used to be read as vertex data, and ushort colours were divided
    by 255, so every initial colour came out saturated."""
    ascii_ply = tmp_path / "a.ply"
    ascii_ply.write_text("ply\nformat ascii 1.0\nelement camera 2\nproperty float a\nelement vertex 1\n"
                         "property float x\nproperty float y\nproperty float z\nproperty ushort red\n"
                         "property ushort green\nproperty ushort blue\nend_header\n9\n8\n1 2 3 65535 0 32768\n")
    xyz, rgb = read_ply_points(ascii_ply)
    assert np.allclose(xyz, [[1, 2, 3]]) and np.allclose(rgb, [[1, 0, 32768 / 65535]])
    binary = tmp_path / "b.ply"
    records = np.array([(1.0, 2.0, 3.0, 65535, 0, 32768)],
                       dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("r", ">u2"), ("g", ">u2"), ("b", ">u2")])
    binary.write_bytes(b"ply\nformat binary_big_endian 1.0\nelement camera 2\nproperty double a\n"
                       b"element vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
                       b"property ushort red\nproperty ushort green\nproperty ushort blue\nend_header\n"
                       + np.array([7.0, 6.0], ">f8").tobytes() + records.tobytes())
    xyz2, rgb2 = read_ply_points(binary)
    assert np.allclose(xyz2, xyz) and np.allclose(rgb2, rgb)
    binary.write_bytes(binary.read_bytes().replace(b"element vertex 1", b"element vertex one"))
    with pytest.raises(SplatuError, match="malformed PLY element line"):
        read_ply_points(binary)


def test_ply_point_reader_ignores_end_header_in_a_comment_and_reads_8_bit_values_in_wider_integers(tmp_path):
    """find(b"end_header") matched inside a comment, so the rest of the header was read as vertex data; and
    colours 0–255 stored as ushort or int (as some tools write them) must not be divided by 65535."""
    records = np.array([(1.0, 2.0, 3.0, 255, 128, 0)],
                       dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "<u2"), ("g", "<u2"), ("b", "<u2")])
    path = tmp_path / "c.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"
                     b"property float y\nproperty float z\ncomment see end_header notes\nproperty ushort red\n"
                     b"property ushort green\nproperty ushort blue\nend_header\n" + records.tobytes())
    xyz, rgb = read_ply_points(path)
    assert np.allclose(xyz, [[1, 2, 3]]) and np.allclose(rgb, [[1.0, 128 / 255, 0.0]])
    path.write_bytes(path.read_bytes().replace(b"property ushort green", b"property ushort red"))
    with pytest.raises(SplatuError, match="one name twice"):
        read_ply_points(path)


TINY_POSTER = PosterConfig(width=24, height=40, frames=20, eval_block=4, points=300, supersample=1)


def test_poster_standin_loads_back_with_identical_cameras_and_its_own_split(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no data/nerfstudio/poster here
    monkeypatch.delenv("SPLATU_DATA", raising=False)
    scene = load_scene(DataConfig(cache_dir=tmp_path / "cache", poster=TINY_POSTER))
    originals = {f"images/{c.name}.png": c for c in camera_path(TINY_POSTER)}
    assert len(scene.train) + len(scene.eval) + len(scene.extra_eval["interp"]) == 20
    eval_indices = [int(n[-9:-4]) for n in scene.eval.names]
    assert eval_indices == list(range(eval_indices[0], eval_indices[0] + 4))  # the contiguous unseen block
    for views in (scene.train, scene.eval, scene.extra_eval["interp"]):
        for camera, name in zip(views.cameras, views.names, strict=True):
            expected = normalize_camera(originals[name], scene.center.double(), scene.scale)
            assert torch.allclose(camera.K.double(), expected.K, atol=1e-5)
            assert torch.allclose(camera.world_to_camera.double(), expected.world_to_camera, atol=1e-5)
        assert views.depths is not None and views.observed is not None
    assert bool(scene.train.observed.all())  # training pixels are seen by their own camera
    assert scene.points.shape == (300, 3) and scene.point_colors is not None and scene.name == "poster"


def test_real_poster_capture_is_preferred_when_present(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("SPLATU_DATA", str(tmp_path / "datasets"))
    write_nerfstudio_scene(tmp_path / "datasets" / "poster", n=5, width=8, height=6)
    scene = load_scene(DataConfig(cache_dir=tmp_path / "cache"))
    assert scene.source == str(tmp_path / "datasets" / "poster" / "transforms.json")
    assert not list((tmp_path / "cache").glob("poster-standin-*"))
    assert not scene.stand_in


def test_the_stand_in_is_marked_however_it_is_loaded_and_loading_it_says_nothing(tmp_path, monkeypatch, capsys):
    """`train` says so once, in its scene line; render-uncertainty and eval-ause, which load it again, did too."""
    monkeypatch.chdir(tmp_path)  # no data/nerfstudio/poster here
    monkeypatch.delenv("SPLATU_DATA", raising=False)
    by_name = load_scene(DataConfig(cache_dir=tmp_path / "cache", poster=TINY_POSTER))
    (folder,) = (tmp_path / "cache").glob("poster-standin-*")
    by_path = load_scene(DataConfig(data=str(folder), cache_dir=tmp_path / "cache"))
    assert by_name.stand_in and by_path.stand_in
    assert by_name.name == by_path.name == "poster"  # by its path it was named after its cache folder
    assert capsys.readouterr() == ("", "")


def test_poster_options_are_refused_where_they_would_shape_nothing(tmp_path, monkeypatch):
    """`--poster.*` builds the stand-in; with the real capture present, or on another scene, it used to be ignored."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("SPLATU_DATA", raising=False)
    reseeded = DataConfig(poster=PosterConfig(seed=3, point_noise=0.0))
    refuse_unused_poster_options(reseeded)  # the stand-in: they shape it
    refuse_unused_poster_options(DataConfig(data=str(tmp_path)))  # defaults: nothing given
    with pytest.raises(SplatuError, match=r"--poster.seed, --poster.point-noise only shape the built-in"):
        refuse_unused_poster_options(dataclasses.replace(reseeded, data=str(tmp_path)))
    monkeypatch.setenv("SPLATU_DATA", str(tmp_path / "datasets"))
    write_nerfstudio_scene(tmp_path / "datasets" / "poster", n=5, width=8, height=6)
    with pytest.raises(SplatuError, match=r"trains on the real capture, in .*datasets/poster"):
        refuse_unused_poster_options(reseeded)
    refuse_unused_poster_options(DataConfig())
    with pytest.raises(SplatuError, match=r"^--poster.frames shapes the built-in stand-in"):
        refuse_unused_poster_options(DataConfig(poster=PosterConfig(frames=40)))


def test_downscaled_depth_and_masks_stay_centred_like_the_colour(tmp_path):
    """Nearest-neighbour resizing took each block's top-left source pixel, half a target pixel away from the
    block centre that INTER_AREA averages colour around; depth, masks and observed maps now take the centre's."""
    columns = np.tile(np.arange(16, dtype=np.float32), (8, 1))
    np.save(tmp_path / "depth.npy", columns)
    recipe = PixelRecipe(path=tmp_path / "depth.npy", kind="depth", width=16, height=8, target_width=2,
                         target_height=1)
    depth = compute_pixels(recipe)
    colour_centres = cv2.resize(columns, (2, 1), interpolation=cv2.INTER_AREA)[0]  # 3.5 and 11.5
    assert np.allclose(colour_centres, [3.5, 11.5])
    assert np.abs(depth[0] - colour_centres).max() <= 0.5  # the source pixel nearest each centre (4 and 12)


def test_a_depth_map_at_another_resolution_of_its_images_shape_is_brought_to_the_cameras_size(tmp_path):
    """nerfstudio reads depth sensors' smaller maps by nearest neighbours; splatu refused them, blaming the camera.
    A map of another shape is still refused, and a wrong-size mask is blamed on the mask, not the camera."""
    coarse = np.arange(192, dtype=np.float32).reshape(12, 16)
    np.save(tmp_path / "coarse.npy", coarse)
    recipe = PixelRecipe(path=tmp_path / "coarse.npy", kind="depth", width=32, height=24, target_width=32,
                         target_height=24)
    depth = compute_pixels(recipe)
    assert depth.shape == (24, 32) and np.array_equal(depth[::2, ::2], coarse)  # each value covers its 2x2 block
    np.save(tmp_path / "other_shape.npy", np.zeros((8, 16), np.float32))  # 2:1, the camera 4:3
    with pytest.raises(SplatuError, match="depth map is 16x8 but its camera says 32x24"):
        compute_pixels(dataclasses.replace(recipe, path=tmp_path / "other_shape.npy"))
    # a side a pixel off at the camera's own resolution, or a map too small to have a shape, is a wrong file
    for shape in ((25, 32), (23, 32), (24, 33), (1, 1), (2, 3), (6, 8)):
        np.save(tmp_path / "off.npy", np.zeros(shape, np.float32))
        with pytest.raises(SplatuError, match=f"depth map is {shape[1]}x{shape[0]} but its camera says 32x24"):
            compute_pixels(dataclasses.replace(recipe, path=tmp_path / "off.npy"))
    cv2.imwrite(str(tmp_path / "mask.png"), np.full((3, 4), 255, np.uint8))
    with pytest.raises(SplatuError, match=r"mask is 4x3 .* make the mask at its image's size, which is the camera's"):
        compute_pixels(dataclasses.replace(recipe, path=tmp_path / "mask.png", kind="mask"))


def test_a_bad_depth_unit_scale_factor_is_a_user_error(tmp_path):
    root = tmp_path / "scene"
    root.mkdir()
    write_rgb(root / "a.png", noise_image(0, 8, 6))
    for bad in (0, -1, "mm"):
        (root / "transforms.json").write_text(json.dumps({
            "fl_x": 10, "fl_y": 10, "cx": 4, "cy": 3, "w": 8, "h": 6, "depth_unit_scale_factor": bad,
            "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}]}))
        with pytest.raises(SplatuError, match="depth_unit_scale_factor must be a positive number"):
            load_nerfstudio(root, (1.0, 1.0, 1.0))


def _distorted_photo(K: np.ndarray, coeffs: tuple[float, ...], width: int, height: int) -> np.ndarray:
    """_smooth_pattern as a camera with intrinsics K and OpenCV distortion coeffs (k1, k2, p1, p2[, k3]) sees it."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    pixels = np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1)[:, None, :]  # +0.5: pixel centres
    rays = cv2.undistortPoints(pixels, K, np.array(coeffs), R=np.eye(3), P=np.eye(3), criteria=
                               (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)).reshape(height, width, 2)
    return np.round(_smooth_pattern(rays[..., 0], rays[..., 1]) * 255).astype(np.uint8)


def _pinhole_errors(camera, image: np.ndarray) -> tuple[float, float]:
    """Median and 99th percentile of |image − the pattern a pinhole camera with camera.K sees|, off the border.

    The median is ~0.001 (8-bit rounding) and a half-pixel error in K takes it past 0.0022, as in the test above; a
    coefficient that is wrong or missing shifts mostly the corners, which the 99th percentile (~0.003) shows."""
    Kn = camera.K.double().numpy()
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    expected = _smooth_pattern((u + 0.5 - Kn[0, 2]) / Kn[0, 0], (v + 0.5 - Kn[1, 2]) / Kn[1, 1])
    error = np.abs(image - expected)[2:-2, 2:-2]
    return float(np.median(error)), float(np.quantile(error, 0.99))


@pytest.mark.parametrize(("model", "distortion", "coeffs"), [
    ("SIMPLE_RADIAL", [-0.25], (-0.25, 0.0, 0.0, 0.0)),
    ("RADIAL", [-0.25, 0.08], (-0.25, 0.08, 0.0, 0.0)),
    ("OPENCV", [-0.25, 0.08, 0.01, -0.004], (-0.25, 0.08, 0.01, -0.004)),
])
def test_undistorted_colmap_image_matches_the_pinhole_camera(tmp_path, model, distortion, coeffs):
    """COLMAP's SIMPLE_RADIAL, RADIAL and OPENCV models are OpenCV's distortion with coefficients (k1, k2, p1, p2)
    in this order (COLMAP puts pixel centres at +0.5 like splatu): a photo through each is undistorted to its K."""
    width, height = 160, 120
    focal = [110.0, 112.0] if model == "OPENCV" else [110.0]  # fx fy, or one f
    K = np.array([[focal[0], 0.0, 81.3], [0.0, focal[-1], 59.1], [0.0, 0.0, 1.0]])
    photo = _distorted_photo(K, coeffs, width, height)
    _assert_undistorted_on_load(tmp_path, model, [*focal, 81.3, 59.1, *distortion], photo)


def _assert_undistorted_on_load(tmp_path, model: str, params: list[float], photo: np.ndarray) -> None:
    """Three COLMAP views of `photo` through camera `model` load undistorted to the pinhole K splatu gives them."""
    height, width = photo.shape[:2]
    root = tmp_path / "scene"
    _write_colmap_text(root, model, params, ring_cameras(3, width, height))
    for i in range(3):
        write_rgb(root / "images" / f"img_{i}.png", photo)
    scene = load_scene(config(root, tmp_path, eval_split="every-n", eval_every=3))
    camera, image = scene.train.cameras[0], scene.train.images[0].numpy()
    median, worst = _pinhole_errors(camera, image)
    assert median < 0.0018 and worst < 0.005, (median, worst)
    assert _pinhole_errors(camera, photo / 255.0)[0] > 3 * median  # the distortion was really there, and was removed


FISHEYE_MODELS = [
    ("SIMPLE_RADIAL_FISHEYE", [110.0], [0.05], (0.05, 0.0, 0.0, 0.0)),
    ("RADIAL_FISHEYE", [110.0], [0.05, -0.02], (0.05, -0.02, 0.0, 0.0)),
    ("OPENCV_FISHEYE", [110.0, 112.0], [0.05, -0.02, 0.01, -0.004], (0.05, -0.02, 0.01, -0.004)),
]
"""COLMAP's fisheye models: f or fx fy, the distortion parameters, and the OpenCV fisheye k1..k4 they stand for."""


@pytest.mark.parametrize(("model", "focal", "distortion", "coeffs"), FISHEYE_MODELS)
def test_colmap_fisheye_models_are_opencv_s_fisheye_as_pycolmap_projects_them(model, focal, distortion, coeffs):
    """Each fisheye model is read as OpenCV's fisheye (equidistant) model with k1..k4, as nerfstudio maps them: the
    K and coefficients splatu takes project a grid of directions up to 75° off the axis where pycolmap does."""
    camera = pycolmap.Camera(model=model, width=160, height=120, params=[*focal, 81.3, 59.1, *distortion])
    K, got = colmap.opencv_camera(camera, "in a test")
    assert got == images.Distortion("OPENCV_FISHEYE", coeffs)
    theta, phi = np.meshgrid(np.radians(np.linspace(1, 75, 20)), np.linspace(0, 2 * np.pi, 16))
    directions = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    opencv, _ = cv2.fisheye.projectPoints(directions[:, None, :], np.zeros(3), np.zeros(3), K,
                                          np.array(got.coeffs).reshape(4, 1))
    assert np.abs(opencv.reshape(-1, 2) - np.asarray(camera.img_from_cam(directions))).max() < 0.01


def test_a_colmap_fisheye_without_distortion_is_still_undistorted():
    """A fisheye with k = 0 is r = f·θ, not a pinhole: it keeps OPENCV_FISHEYE distortion with zero coefficients."""
    camera = pycolmap.Camera(model="SIMPLE_RADIAL_FISHEYE", width=160, height=120, params=[110.0, 80.0, 60.0, 0.0])
    _, distortion = colmap.opencv_camera(camera, "in a test")
    assert distortion is not None and distortion.model == "OPENCV_FISHEYE" and not distortion.is_identity()


@pytest.mark.parametrize(("model", "focal", "distortion", "coeffs"), FISHEYE_MODELS)
def test_undistorted_colmap_fisheye_image_matches_the_pinhole_camera(tmp_path, model, focal, distortion, coeffs):
    """A photo of a smooth pattern through each COLMAP fisheye camera, made with pycolmap's own unprojection
    (pixel centres at +0.5), loads undistorted to the pinhole K splatu gives its camera."""
    width, height = 160, 120
    params = [*focal, 81.3, 59.1, *distortion]
    lens = pycolmap.Camera(model=model, width=width, height=height, params=params)
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.asarray(lens.cam_from_img(np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1))).reshape(height, width, 2)
    photo = np.round(_smooth_pattern(rays[..., 0], rays[..., 1]) * 255).astype(np.uint8)
    _assert_undistorted_on_load(tmp_path, model, params, photo)


def test_undistorted_image_with_k3_matches_the_pinhole_camera(tmp_path):
    """nerfstudio's OPENCV model has a sixth-order radial term k3 (OpenCV's fifth coefficient)."""
    width, height = 160, 120
    K = np.array([[110.0, 0.0, 81.3], [0.0, 112.0, 59.1], [0.0, 0.0, 1.0]])
    coeffs = (-0.25, 0.08, 0.002, -0.001, 0.1)
    photo = _distorted_photo(K, coeffs, width, height)
    root = tmp_path / "scene"
    write_rgb(root / "images" / "a.png", photo)
    write_rgb(root / "images" / "b.png", photo)
    frame = {"transform_matrix": np.eye(4).tolist()}
    (root / "transforms.json").write_text(json.dumps({
        "camera_model": "OPENCV", "fl_x": K[0, 0], "fl_y": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "w": width,
        "h": height, **dict(zip(("k1", "k2", "p1", "p2", "k3"), coeffs, strict=True)),
        "frames": [{"file_path": "images/a.png", **frame}, {"file_path": "images/b.png", **frame}]}))

    scene = load_scene(config(root, tmp_path, eval_split="every-n", eval_every=2))
    camera, image = scene.train.cameras[0], scene.train.images[0].numpy()
    median, worst = _pinhole_errors(camera, image)
    assert median < 0.0018 and worst < 0.005, (median, worst)


def test_principal_point_defaults_to_the_image_centre(tmp_path):
    """Without cx, cy the principal point is the image centre, (w/2, h/2) with pixel centres at +0.5."""
    root = tmp_path / "scene"
    write_rgb(root / "a.png", noise_image(0, 41, 31))
    (root / "transforms.json").write_text(json.dumps({
        "camera_model": "PINHOLE", "fl_x": 40.0, "w": 41, "h": 31,
        "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}]}))
    K = load_nerfstudio(root, (1.0, 1.0, 1.0)).frames[0].camera.K
    assert (float(K[0, 2]), float(K[1, 2])) == (20.5, 15.5)
    assert float(K[1, 1]) == 40.0  # fl_y defaults to fl_x


def test_tiles_cut_from_larger_photos_load_with_one_warning_line(tmp_path, capsys):
    """Aerial grids: each photo cut into 3x3 tiles, every tile with the photo's pose and K shifted to the tile, so 8
    of 9 have the principal point off the tile. Their images check out against w and h, so the scene loads and
    trains, with one line for the whole file, not one per frame."""
    root, width, height = tmp_path / "scene", 32, 24  # a tile's size, of a 96x72 photo
    tiles, names = [], []
    for i, photo in enumerate(ring_cameras(2, 3 * width, 3 * height)):
        pixels = noise_image(i, 3 * width, 3 * height)
        for row in range(3):
            for col in range(3):
                K = photo.K.clone()
                K[0, 2] -= col * width
                K[1, 2] -= row * height
                tiles.append(dataclasses.replace(photo, K=K, width=width, height=height))
                names.append(f"tiles/{i}_{row}{col}.png")
                write_rgb(root / names[-1], pixels[row * height:(row + 1) * height, col * width:(col + 1) * width])
    write_transforms(root / "transforms.json", tiles, names)
    scene = load_scene(config(root, tmp_path, eval_split="every-n", eval_every=6))
    assert len(scene.train) + len(scene.eval) == 18
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert err.startswith(f"warning: 16 of 18 frames in {root / 'transforms.json'} have a principal point far from "
                          "the image's centre (frame 'tiles/0_00.png': principal point (48.3, 35.8) lies outside the "
                          "32x24 image, as for a K made for an image 3 times this size); the cameras are used as given")


@pytest.mark.parametrize("scene", ["fox", "lund_door"])
def test_the_real_scenes_load_without_a_word_at_every_downscale(scene, capsys):
    """Their principal points sit within 1.4% of the centre: no warning, at any --downscale."""
    path = shared_scene(scene)
    raw = read_scene_files(path, (1.0, 1.0, 1.0))
    for downscale in (1, 2, 4, 8):
        assert downscaled(raw, downscale).frames
    assert capsys.readouterr() == ("", "")


def test_downscaled_colour_is_the_mean_of_each_block(tmp_path):
    """Colour is area-averaged: a bilinear resize by 4 reads only the middle 2x2 pixels of each 4x4 block."""
    photo = noise_image(0, 40, 32)
    write_rgb(tmp_path / "photo.png", photo)
    recipe = PixelRecipe(path=tmp_path / "photo.png", kind="color", width=40, height=32, target_width=10,
                         target_height=8)
    block_means = photo.astype(np.float64).reshape(8, 4, 10, 4, 3).mean(axis=(1, 3))
    assert np.abs(compute_pixels(recipe) - block_means).max() <= 0.5 + 1e-3  # rounded to 8 bits


def test_depth_images_are_scaled_by_depth_unit_scale_factor_and_npy_depth_is_not(tmp_path):
    """nerfstudio's convention: a depth image holds integers times depth_unit_scale_factor (default 1e-3, i.e.
    millimetres); a .npy holds depth itself."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=8, height=6)
    cv2.imwrite(str(root / "depth.png"), np.full((6, 8), 2500, np.uint16))
    np.save(root / "depth.npy", np.full((6, 8), 2.5, np.float32))
    eval_list = tmp_path / "eval.txt"
    eval_list.write_text(f"{cameras[0].name}\n")
    for unit, file, metres in ((None, "depth.png", 2.5), (0.01, "depth.png", 25.0),
                               (None, "depth.npy", 2.5), (0.01, "depth.npy", 2.5)):
        content = json.loads((root / "transforms.json").read_text())
        content.pop("depth_unit_scale_factor", None)
        if unit is not None:
            content["depth_unit_scale_factor"] = unit
        for frame in content["frames"]:
            frame["depth_file_path"] = file
        (root / "transforms.json").write_text(json.dumps(content))
        scene = load_scene(config(root, tmp_path, eval_split="list", eval_list=eval_list))
        assert torch.allclose(scene.eval.depths[0], torch.full((6, 8), metres * scene.scale)), (unit, file)


@pytest.mark.parametrize(("model", "params", "K"), [
    ("PINHOLE", [36.0, 38.0, 21.0, 14.0], [[36.0, 0.0, 21.0], [0.0, 38.0, 14.0]]),
    ("SIMPLE_PINHOLE", [36.0, 21.0, 14.0], [[36.0, 0.0, 21.0], [0.0, 36.0, 14.0]]),
])
def test_colmap_pinhole_parameters_are_f_or_fx_fy_then_cx_cy(tmp_path, model, params, K):
    """COLMAP's parameter order: PINHOLE fx, fy, cx, cy; SIMPLE_PINHOLE f, cx, cy (pixel centres at +0.5 in both)."""
    _write_colmap_text(tmp_path / "scene", model, params, ring_cameras(5, 40, 30))
    scene = load_scene(config(tmp_path / "scene", tmp_path, eval_split="every-n", eval_every=3))
    for camera in (*scene.train.cameras, *scene.eval.cameras):
        assert torch.allclose(camera.K.double(), torch.tensor([*K, [0.0, 0.0, 1.0]], dtype=torch.float64))
    half = load_scene(config(tmp_path / "scene", tmp_path, downscale=2, eval_split="every-n", eval_every=3))
    assert torch.allclose(half.train.cameras[0].K.double()[:2], 0.5 * torch.tensor(K, dtype=torch.float64))


def test_colmap_images_n_folder_is_used_for_downscale(tmp_path):
    """As for nerfstudio: with --downscale 2, images_2/NAME is the image (already at half size), not images/NAME."""
    root = tmp_path / "scene"
    _write_colmap_text(root, "PINHOLE", [36.0, 36.0, 20.0, 15.0], ring_cameras(5, 40, 30))
    for i in range(5):
        write_rgb(root / "images_2" / f"img_{i}.png", noise_image(100 + i, 20, 15))
    scene = load_scene(config(root, tmp_path, downscale=2, eval_split="every-n", eval_every=3))
    assert scene.train.names[0] == "img_1.png"
    assert torch.equal(scene.train.images[0], torch.from_numpy(noise_image(101, 20, 15) / np.float32(255)))


def test_colmap_images_are_ordered_by_name_not_by_id(tmp_path):
    """The frames come sorted by image name (the capture order of numbered photos), whatever ids COLMAP gave them,
    so a split by position holds out the same views in every reconstruction of the scene."""
    root = tmp_path / "scene"
    cameras = ring_cameras(5, 40, 30)
    _write_colmap_text(root, "PINHOLE", [36.0, 36.0, 20.0, 15.0], cameras)
    images_txt = root / "sparse" / "0" / "images.txt"
    rows = [line.split() for line in images_txt.read_text().splitlines()]
    images_txt.write_text("\n".join(" ".join([str(6 - int(row[0])), *row[1:]]) if row else "" for row in rows) + "\n")
    (root / "sparse" / "0" / "points3D.txt").write_text("")  # their tracks name no image, so ids are free
    frames = colmap.load_colmap(root, root / "sparse" / "0").frames
    assert [f.name for f in frames] == [f"img_{i}.png" for i in range(5)]
    for frame, camera in zip(frames, cameras, strict=True):  # each name keeps its own pose
        assert torch.allclose(frame.camera.world_to_camera, camera.world_to_camera, atol=1e-6)


def test_a_colmap_image_the_reconstruction_did_not_register_is_left_out(tmp_path, monkeypatch):
    """COLMAP keeps images it could not register, without a pose; they are not views of the scene."""
    root = tmp_path / "scene"
    _write_colmap_text(root, "PINHOLE", [36.0, 36.0, 20.0, 15.0], ring_cameras(5, 40, 30))
    reconstruction = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    reconstruction.deregister_frame(reconstruction.images[3].frame_id)  # img_2.png
    monkeypatch.setattr(colmap, "read_reconstruction", lambda sparse_dir: reconstruction)
    frames = colmap.load_colmap(root, root / "sparse" / "0").frames
    assert [f.name for f in frames] == ["img_0.png", "img_1.png", "img_3.png", "img_4.png"]


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_write_png_is_read_back_in_rgb_order(tmp_path, dtype):
    """One writer for every PNG: its channels come back the way read_image (and any viewer) reads them."""
    rgb = np.zeros((2, 3, 3), dtype)
    rgb[..., 0] = np.iinfo(dtype).max  # pure red: a swapped writer reads back blue
    rgb[1, 2] = (1, 2, 3)
    images.write_png(tmp_path / "red.png", rgb, "fix it")
    np.testing.assert_array_equal(images.read_image(tmp_path / "red.png"), rgb)
    rgba = np.concatenate([rgb, np.full((2, 3, 1), 7, dtype)], axis=-1)
    images.write_png(tmp_path / "rgba.png", rgba, "fix it")
    np.testing.assert_array_equal(images.read_image(tmp_path / "rgba.png"), rgba)
    grey = np.arange(6, dtype=dtype).reshape(2, 3)
    images.write_png(tmp_path / "grey.png", grey, "fix it")
    np.testing.assert_array_equal(images.read_image(tmp_path / "grey.png"), grey)


def test_write_png_refusal_is_one_line_with_the_callers_fix(tmp_path):
    with pytest.raises(SplatuError, match=r"could not write a.png.*no_such_folder.*free some space"):
        images.write_png(tmp_path / "no_such_folder" / "a.png", np.zeros((2, 2, 3), np.uint8), "free some space")


def test_colmap_text_lines_are_checked_as_colmap_reads_them_indented_comments_and_crlf_too(tmp_path):
    """Every line of a text model is now checked before pycolmap reads it (pycolmap misread some bad lines without a
    word), so the check must accept all that COLMAP accepts: it trims a line before looking for a comment's #."""
    cameras = ring_cameras(5, 40, 30)
    _write_colmap_text(tmp_path / "plain", "PINHOLE", [36.0, 36.0, 20.0, 15.0], cameras)
    _write_colmap_text(tmp_path / "edited", "PINHOLE", [36.0, 36.0, 20.0, 15.0], cameras)
    for path in (tmp_path / "edited" / "sparse" / "0").iterdir():
        path.write_bytes(b"  # an indented comment\r\n" + path.read_bytes().replace(b"\n", b"\r\n"))
    plain, edited = (load_scene(config(tmp_path / name, tmp_path, eval_split="every-n", eval_every=3))
                     for name in ("plain", "edited"))
    assert edited.train.names == plain.train.names
    assert torch.equal(edited.points, plain.points) and torch.equal(edited.point_colors, plain.point_colors)


def test_colmap_text_images_with_2d_points_load_as_without(tmp_path):
    """COLMAP writes each image's 2D points on the line after its pose: a long line of numbers, not an image name
    with spaces in it."""
    cameras = ring_cameras(5, 40, 30)
    _write_colmap_text(tmp_path / "plain", "PINHOLE", [36.0, 36.0, 20.0, 15.0], cameras)
    _write_colmap_text(tmp_path / "points", "PINHOLE", [36.0, 36.0, 20.0, 15.0], cameras)
    images_txt = tmp_path / "points" / "sparse" / "0" / "images.txt"
    four_points = "1.0 2.0 -1 3.0 4.0 -1 5.0 6.0 -1 7.0 8.0 -1"
    images_txt.write_text(images_txt.read_text().replace(".png\n\n", f".png\n{four_points}\n"))
    plain, points = (load_scene(config(tmp_path / name, tmp_path, eval_split="every-n", eval_every=3))
                     for name in ("plain", "points"))
    assert points.train.names == plain.train.names and points.eval.names == plain.eval.names


def test_colmap_text_point_ids_may_pass_32_bits(tmp_path):
    """Camera and image ids are 32-bit in COLMAP, 3D point ids 64-bit: a large model's point ids pass 2³²."""
    _write_colmap_text(tmp_path / "scene", "PINHOLE", [36.0, 36.0, 20.0, 15.0], ring_cameras(5, 40, 30))
    points_txt = tmp_path / "scene" / "sparse" / "0" / "points3D.txt"
    points_txt.write_text(f"{2**32} 10.0 -3.0 2.0 255 0 128 0.5\n{2**40} 10.5 -3.0 2.5 0 255 0 0.5\n")
    scene = load_scene(config(tmp_path / "scene", tmp_path, eval_split="every-n", eval_every=3))
    assert scene.points.shape[0] == 2


@pytest.mark.parametrize("given", ["in the frame and the file", "as fl_x and camera_angle_x"])
def test_a_frames_own_focal_length_wins_and_fl_x_wins_over_camera_angle_x(tmp_path, given):
    """As in instant-ngp: a frame's own value overrides the file's, and in one place fl_x overrides camera_angle_x."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=3)  # fl_x = 36 in every frame
    content = json.loads((root / "transforms.json").read_text())
    wide = 2 * math.atan(20 / 10)  # a focal length of 10 px across the 40 px
    if given == "in the frame and the file":
        content["camera_angle_x"] = wide
    else:
        for frame in content["frames"]:
            frame["camera_angle_x"] = wide
    (root / "transforms.json").write_text(json.dumps(content))
    assert {float(frame.camera.K[0, 0]) for frame in load_nerfstudio(root, (1.0, 1.0, 1.0)).frames} == {36.0}


@pytest.mark.parametrize("where", ["per frame, x and y", "top level, x only"])
def test_instant_ngp_camera_angles_give_the_cameras_fl_x_and_fl_y_give(tmp_path, where):
    """instant-ngp's transforms.json may give the field of view in radians, camera_angle_x (and _y), instead of fl_x
    (and fl_y): it was refused as "missing intrinsics fl_x". fl = ½w / tan(½angle); without camera_angle_y, fl_y is
    fl_x; cx, cy stay as given."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=3)
    content = json.loads((root / "transforms.json").read_text())
    if where == "top level, x only":
        for frame in content["frames"]:
            frame["fl_y"] = frame["fl_x"]
    (root / "transforms.json").write_text(json.dumps(content))
    given = load_nerfstudio(root, (1.0, 1.0, 1.0))
    for frame in content["frames"]:
        fl_x, fl_y = frame.pop("fl_x"), frame.pop("fl_y")
        if where == "top level, x only":
            content["camera_angle_x"] = 2 * math.atan(frame["w"] / 2 / fl_x)
        else:
            frame.update(camera_angle_x=2 * math.atan(frame["w"] / 2 / fl_x),
                         camera_angle_y=2 * math.atan(frame["h"] / 2 / fl_y))
    (root / "transforms.json").write_text(json.dumps(content))
    angled = load_nerfstudio(root, (1.0, 1.0, 1.0))
    assert [f.name for f in angled.frames] == [f.name for f in given.frames]
    for a, b in zip(angled.frames, given.frames, strict=True):
        torch.testing.assert_close(a.camera.K, b.camera.K, rtol=1e-12, atol=0)
        assert torch.equal(a.camera.world_to_camera, b.camera.world_to_camera)
        assert (a.camera.width, a.camera.height) == (b.camera.width, b.camera.height)


def _rewrite_frames(root: Path, edit) -> None:
    content = json.loads((root / "transforms.json").read_text())
    for frame in content["frames"]:
        edit(frame)
    (root / "transforms.json").write_text(json.dumps(content))


def test_instant_ngp_fields_of_view_in_degrees_give_the_cameras_fl_x_and_fl_y_give(tmp_path):
    """instant-ngp's x_fov and y_fov (degrees) were refused as "missing intrinsics fl_x"; fl = ½w / tan(½fov). Given
    beside a matching fl_x they change nothing."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=3)
    given = load_nerfstudio(root, (1.0, 1.0, 1.0))

    def to_degrees(frame: dict) -> None:
        fl_x, fl_y = frame.pop("fl_x"), frame.pop("fl_y")
        frame.update(x_fov=math.degrees(2 * math.atan(frame["w"] / 2 / fl_x)),
                     y_fov=math.degrees(2 * math.atan(frame["h"] / 2 / fl_y)))
    _rewrite_frames(root, to_degrees)
    for a, b in zip(load_nerfstudio(root, (1.0, 1.0, 1.0)).frames, given.frames, strict=True):
        torch.testing.assert_close(a.camera.K, b.camera.K, rtol=1e-12, atol=0)
    _rewrite_frames(root, lambda frame: frame.update(fl_x=float(given.frames[0].camera.K[0, 0])))
    assert float(load_nerfstudio(root, (1.0, 1.0, 1.0)).frames[0].camera.K[0, 0]) == pytest.approx(36.0, rel=1e-12)


@pytest.mark.parametrize(("fields", "message"), [
    ({"x_fov": 90.0}, "fl_x 36 px and x_fov 90 degrees (fl_x 20 px) disagree, and instant-ngp reads x_fov first "
                      "where nerfstudio reads fl_x"),
    ({"x_fov": 180.0}, "x_fov must be an angle in (0, 180) degrees (got 180.0)"),
    ({"y_fov": 0.0}, "y_fov must be an angle in (0, 180) degrees (got 0.0)"),
])
def test_an_instant_ngp_field_of_view_that_is_out_of_range_or_disagrees_with_fl_is_refused(tmp_path, fields, message):
    """instant-ngp reads x_fov before fl_x and nerfstudio after it, so a file giving two focal lengths trains with
    one or the other depending on the reader: refused, as is an angle no lens has."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=3)  # fl_x = 36 across 40 px
    _rewrite_frames(root, lambda frame: frame.update(fields))
    with pytest.raises(SplatuError) as caught:
        load_nerfstudio(root, (1.0, 1.0, 1.0))
    assert caught.value.what == message and "of " in caught.value.where


def test_an_instant_ngp_still_camera_given_as_transform_matrix_start_loads_and_a_moving_one_is_refused(tmp_path):
    """instant-ngp's rolling-shutter frames give transform_matrix_start and _end instead of transform_matrix. A camera
    that did not move (no _end, or the same) loads with that pose; one that moved during the exposure is refused,
    since splatu would train it as still."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=3)
    given = load_nerfstudio(root, (1.0, 1.0, 1.0))
    _rewrite_frames(root, lambda frame: frame.update(transform_matrix_start=frame.pop("transform_matrix")))
    started = load_nerfstudio(root, (1.0, 1.0, 1.0))
    _rewrite_frames(root, lambda frame: frame.update(transform_matrix_end=frame["transform_matrix_start"]))
    still = load_nerfstudio(root, (1.0, 1.0, 1.0))
    for loaded in (started, still):
        for a, b in zip(loaded.frames, given.frames, strict=True):
            assert torch.equal(a.camera.world_to_camera, b.camera.world_to_camera)

    def move(frame: dict) -> None:
        frame["transform_matrix_end"] = [[*row[:3], row[3] + 0.01] for row in frame["transform_matrix_start"][:3]]
    _rewrite_frames(root, move)
    with pytest.raises(SplatuError) as caught:
        load_nerfstudio(root, (1.0, 1.0, 1.0))
    assert "the camera moved during the exposure" in caught.value.what and "transform_matrix" in caught.value.fix


def test_nerfstudio_s_other_keys_and_unused_zero_coefficients_load_as_without_them(tmp_path):
    """Only misspelt keys and dropped distortion coefficients are refused: nerfstudio's and instant-ngp's other keys
    (whatever their spelling resembles), a zero (or null) coefficient the camera model does not use, and keys that
    merely contain a k or p still load."""
    cameras = ring_cameras(3, 40, 30)
    names = ["a.png", "b.png", "c.png"]
    write_transforms(tmp_path / "plain.json", cameras, names, top_extras={"camera_model": "PINHOLE"})
    extras = [{"sharpness": 41.5, "mask_path": "masks/a.png", "depth_file_path": "depth/a.png", "k4": 0.0,
               "colmap_im_id": 3, "depth_path": "depth/a.png"}, {"camera_model": "OPENCV", "k3": 0.0, "k4": None}, {}]
    write_transforms(tmp_path / "transforms.json", cameras, names, frame_extras=extras, top_extras={
        "camera_model": "PINHOLE", "k1": 0.0, "p2": 0.0, "aabb_scale": 4, "applied_transform": np.eye(4)[:3].tolist(),
        "ply_file_path": "sparse_pc.ply", "depth_unit_scale_factor": 1e-3, "orientation_override": "none",
        "keep1": 1, "kp1": 2, "k11": 3, "integer_depth_scale": 1e-3, "is_fisheye": False, "sharpen": 0.0,
        "scale": 0.33, "offset": [0.5, 0.5, 0.5], "up": [0, 0, 1], "n_extra_learnable_dims": 16, "sk_x": 0.0,
        "white_transparent": False, "applied_scale": 1.0})
    for got, want in zip(read_cameras(tmp_path), read_cameras(tmp_path / "plain.json"), strict=True):
        torch.testing.assert_close(got.K, want.K)
        torch.testing.assert_close(got.world_to_camera, want.world_to_camera)


def write_shared_camera_file(path: Path, frame_edit=lambda frame: None, **top) -> None:
    """Three frames sharing the file's camera (OPENCV, k1 = 0.05, cx off the centre); `frame_edit` edits the second."""
    write_transforms(path, ring_cameras(3, 40, 30), ["a.png", "b.png", "c.png"])
    content = json.loads(path.read_text())
    for frame in content["frames"]:
        for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            del frame[key]
    frame_edit(content["frames"][1])
    content.update({"fl_x": 36.0, "cx": 19.0, "cy": 14.5, "w": 40, "h": 30, "k1": 0.05, **top})
    path.write_text(json.dumps(content))


def assert_same_cameras(got: list, want: list) -> None:
    for a, b in zip(got, want, strict=True):
        assert (a.name, a.width, a.height) == (b.name, b.width, b.height)
        torch.testing.assert_close(a.K, b.K, rtol=0, atol=0)
        torch.testing.assert_close(a.world_to_camera, b.world_to_camera, rtol=0, atol=0)


@pytest.mark.parametrize("key", ["k1", "cx", "fl_x", "w", "camera_model", "is_fisheye"])
def test_a_frame_s_null_is_not_given_so_the_file_s_value_stands(tmp_path, key):
    """A frame's "k1": null dropped the file's k1 for that frame (its images undistorted without it) and a "cx": null
    put its principal point at the image centre, while a null fl_x fell back to the file's and a null camera_model
    was an unknown model "None". null now means not given, for every camera key, as for mask_path."""
    write_shared_camera_file(tmp_path / "plain.json")
    write_shared_camera_file(tmp_path / "null.json", lambda frame: frame.update({key: None}))
    assert_same_cameras(read_cameras(tmp_path / "null.json"), read_cameras(tmp_path / "plain.json"))


def test_a_file_s_null_is_not_given_so_the_default_stands(tmp_path):
    """A top-level "camera_model": null was an unknown model "None"; a null k1 was already no k1."""
    write_shared_camera_file(tmp_path / "plain.json", k1=0.0)
    write_shared_camera_file(tmp_path / "null.json", lambda frame: frame.update(k2=None), camera_model=None, k1=None)
    assert_same_cameras(read_cameras(tmp_path / "null.json"), read_cameras(tmp_path / "plain.json"))


def edit_json(path: Path, edit) -> None:
    content = json.loads(path.read_text())
    edit(content)
    path.write_text(json.dumps(content))


FISHEYE_COEFFICIENTS = {"k1": 0.05, "k2": 0.01, "k3": 0.002}
"""Coefficients both OPENCV and OPENCV_FISHEYE use, so a frame read with either loads."""


@pytest.mark.parametrize("place", ["top", "frame"])
def test_instant_ngp_s_is_fisheye_reads_the_coefficients_as_opencv_fisheye_s(tmp_path, place):
    """instant-ngp reads k1..k4 as OpenCV's fisheye (equidistant) model's when is_fisheye is true, nerfstudio's
    OPENCV_FISHEYE; the flag was ignored and the images undistorted with OpenCV's radial k1, k2, k3. A frame's flag
    is for that frame, as its other camera keys."""
    for name, model in (("fisheye.json", "OPENCV_FISHEYE"), ("opencv.json", "OPENCV")):
        write_shared_camera_file(tmp_path / name, camera_model=model, **FISHEYE_COEFFICIENTS)
    write_shared_camera_file(tmp_path / "flag.json", **FISHEYE_COEFFICIENTS)
    if place == "top":
        edit_json(tmp_path / "flag.json", lambda c: (c.pop("camera_model"), c.update(is_fisheye=True)))
    else:
        edit_json(tmp_path / "flag.json", lambda c: (c.pop("camera_model"), c["frames"][1].update(is_fisheye=True)))
    fisheye, opencv, flag = (read_cameras(tmp_path / name) for name in ("fisheye.json", "opencv.json", "flag.json"))
    assert not torch.equal(fisheye[1].K, opencv[1].K)
    assert_same_cameras(flag, fisheye if place == "top" else [opencv[0], fisheye[1], opencv[2]])


@pytest.mark.parametrize(("model", "flag"), [(None, False), ("OPENCV", False), ("OPENCV_FISHEYE", True),
                                             ("PINHOLE", True)])
def test_an_is_fisheye_that_agrees_with_the_camera_model_or_changes_nothing_loads(tmp_path, model, flag):
    """is_fisheye false is OPENCV, as colmap2nerf writes it for every lens that is no fisheye; with no coefficient
    to read, a flag the camera_model contradicts changes nothing."""
    coefficients = {"k1": 0.0} if model == "PINHOLE" else FISHEYE_COEFFICIENTS
    write_shared_camera_file(tmp_path / "plain.json", camera_model=model or "OPENCV", **coefficients)
    write_shared_camera_file(tmp_path / "flag.json", is_fisheye=flag, **coefficients)

    def set_model(content: dict) -> None:
        content.pop("camera_model")
        if model is not None:
            content["camera_model"] = model

    edit_json(tmp_path / "flag.json", set_model)
    assert_same_cameras(read_cameras(tmp_path / "flag.json"), read_cameras(tmp_path / "plain.json"))


def test_the_real_fox_transforms_json_passes_the_camera_file_checks():
    """fox's file (fl_x, fl_y, k1, k2, p1, p2, cx, cy, w, h, camera_angle_x/y, aabb_scale; per frame file_path,
    sharpness, transform_matrix) keeps loading: its principal point is 1.4% off the centre."""
    cameras = read_cameras(shared_scene("fox"))
    assert len(cameras) == 67 and (cameras[0].width, cameras[0].height) == (1080, 1920)
