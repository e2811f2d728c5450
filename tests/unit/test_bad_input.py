
"""Every kind of bad scene input fails with one SplatuError line: what, which file, how to fix."""

from __future__ import annotations

import dataclasses
import fcntl
import json
import math
import os
import re
import shlex
import signal
import socket
import subprocess
import time
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest
import torch

from splatu.cli import entrypoint
from splatu.data.assemble import assemble, refuse_split_flags_the_scene_overrides, scene_normalization
from splatu.data.config import DataConfig
from splatu.data.frames import refuse_implausible_focal
from splatu.data.images import ImageCache
from splatu.data.nerfstudio import read_cameras
from splatu.data.process_images import ProcessImagesConfig, process_images
from splatu.data.resolve import load_scene, read_scene_files
from splatu.errors import SplatuError
from tests.synthetic_scenes import noise_image, write_nerfstudio_scene, write_rgb


def load_error(path: Path, tmp_path: Path, **overrides) -> SplatuError:
    with pytest.raises(SplatuError) as caught:
        load_scene(DataConfig(data=str(path), cache_dir=tmp_path / "cache", **overrides))
    message = str(caught.value)
    assert "\n" not in message and caught.value.what and caught.value.where and caught.value.fix
    return caught.value


def edit_transforms(root: Path, edit) -> None:
    content = json.loads((root / "transforms.json").read_text())
    edit(content)
    (root / "transforms.json").write_text(json.dumps(content))


def test_missing_path(tmp_path):
    error = load_error(tmp_path / "nonexistent", tmp_path)
    assert "not found" in error.what and "nonexistent" in error.where


def test_train_style_resolution_of_a_nonexistent_data_path(tmp_path):
    error = load_error(Path("/nonexistent"), tmp_path)
    assert error.where == "in /nonexistent"


def test_unknown_format(tmp_path):
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "a.txt").write_text("no scene here")
    error = load_error(tmp_path / "notes", tmp_path)
    assert "unknown scene format" in error.what and "notes" in error.where and "--data" in error.fix


def test_a_folder_of_photos_without_poses_names_process_images(tmp_path):
    """Photos straight off a camera have no poses yet: the fix is the command that makes them, not a format list,
    quoted so that a folder name with a space pastes as one argument."""
    photos = tmp_path / "my photos"
    photos.mkdir()
    for i in range(3):
        write_rgb(photos / f"{i}.JPG", noise_image(i, 8, 6))
    error = load_error(photos, tmp_path)
    assert "unknown scene format" in error.what and "3 photos but no camera poses" in error.what
    assert f"splatu process-images '{photos}'" in error.fix


def test_a_folder_it_may_not_list_is_the_plain_unknown_format(tmp_path, monkeypatch):
    """Counting the photos lists the folder, which a permission error stops: that is no reason for a traceback."""
    (tmp_path / "locked").mkdir()

    def refused(self):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "iterdir", refused)
    error = load_error(tmp_path / "locked", tmp_path)
    assert error.what.startswith("unknown scene format") and "--data" in error.fix


def test_a_scenes_images_folder_names_the_scene_folder(tmp_path):
    """--data scene/images (or scene/sparse) is a slip for --data scene: the fix names the folder to pass."""
    cameras = write_nerfstudio_scene(tmp_path / "scene", n=3)
    images = (tmp_path / "scene" / cameras[0].name).parent
    error = load_error(images, tmp_path)
    assert "unknown scene format" in error.what
    assert error.fix == f"pass the scene folder it is in: --data {tmp_path}/scene"


def test_an_empty_colmap_model_folder_says_so(tmp_path):
    """A failed COLMAP run leaves sparse/0 empty; the error said the scene had no sparse/0."""
    (tmp_path / "scene" / "sparse" / "0").mkdir(parents=True)
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what.startswith("the COLMAP model folder is empty") and error.where == f"in {tmp_path}/scene/sparse/0"


def test_corrupt_image_names_the_file(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    (root / cameras[2].name).write_bytes(b"\x89PNG\r\n\x1a\nthis is not an image")
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert "cannot decode" in error.what and error.where.endswith(cameras[2].name)


def test_missing_image_names_the_file(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    (root / cameras[1].name).unlink()
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert "not found" in error.what and error.where.endswith(cameras[1].name)


def test_unknown_nerfstudio_camera_model(tmp_path):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: c.update(camera_model="EQUIRECTANGULAR"))
    error = load_error(root, tmp_path)
    assert "EQUIRECTANGULAR" in error.what and "transforms.json" in error.where


def write_colmap(root: Path, camera: str = "1 PINHOLE 8 6 5 5 4 3",
                 poses: tuple[str, ...] = ("1 0 0 0", "1 0 0 0"), points: str = "") -> Path:
    """A two-image COLMAP text model (no image files: these errors come before decoding); returns sparse/0."""
    sparse = root / "sparse" / "0"
    sparse.mkdir(parents=True)
    (sparse / "cameras.txt").write_text(f"# a comment\n{camera}\n")
    lines = [f"{i + 1} {quat} {i} 0 0 1 {'abc'[i]}.png\n\n" for i, quat in enumerate(poses)]
    (sparse / "images.txt").write_text("".join(lines))
    (sparse / "points3D.txt").write_text(points)
    return sparse


@pytest.mark.parametrize(("model", "params"), [("FULL_OPENCV", "0.1 0 0 0 0 0 0 0"),
                                               ("THIN_PRISM_FISHEYE", "0.1 0 0 0 0 0 0 0")])
def test_unknown_colmap_camera_model(tmp_path, model, params):
    """nerfstudio refuses these too: FULL_OPENCV's k5, k6 and the thin-prism terms have no OpenCV model here."""
    write_colmap(tmp_path / "scene", camera=f"1 {model} 8 6 5 5 4 3 {params}")
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what == f"unsupported COLMAP camera model {model}" and "cameras.txt" in error.where
    assert "OPENCV_FISHEYE" in error.fix and error.fix.endswith("(or run colmap image_undistorter first)")


@pytest.mark.parametrize(("edits", "message", "file", "line"), [
    ({"camera": "1 FOOBAR 8 6 5 5 4 3"}, "unknown camera model 'FOOBAR' (camera 1)", "cameras.txt", 2),
    ({"camera": "7 PINHOLE 8 6 5 5 4 3"}, "image a.png uses camera 1, which cameras.txt does not define",
     "images.txt", 1),
    ({"camera": "# no camera left"}, "image a.png uses camera 1, which cameras.txt does not define", "images.txt", 1),
    ({"points": "1 0.5 0.5 2 255 0 0 0.1\n2 0.5 0.5 2 255 0 0 0.1 8 0\n"},
     "point 2's track names image 8, which images.txt does not define", "points3D.txt", 2),
    ({"points": "1 0.5 0.5 2 255 0 0 0.1 1 0\n"},  # pycolmap: "vector::_M_range_check: __n (which is 0) >= ..."
     "point 1's track names 2D point 0 of image 1, which has 0 in images.txt", "points3D.txt", 1),
])
def test_colmap_unknown_model_or_dangling_id_names_the_file_and_line(tmp_path, edits, message, file, line):
    """pycolmap refuses these in its own terms ("Camera model does not exist", "Rig with ID 7 does not exist")
    and names no file."""
    sparse = write_colmap(tmp_path / "scene", **edits)
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what == message and error.where == f"in {sparse / file} line {line}"


def test_colmap_pose_beyond_float32_names_the_image(tmp_path):
    sparse = write_colmap(tmp_path / "scene")
    images = sparse / "images.txt"
    images.write_text(images.read_text().replace("2 1 0 0 0 1 0 0", "2 1 0 0 0 1e39 0 0"))
    error = load_error(tmp_path / "scene", tmp_path)
    assert "b.png has a pose value beyond float32's range (1e+39)" in error.what and error.where == f"in {images}"


def test_colmap_image_name_that_is_not_utf8_names_the_image_and_file(tmp_path):
    """pycolmap reads the name's bytes, but handing them to Python raised a UnicodeDecodeError (a traceback)."""
    images = write_colmap(tmp_path / "scene") / "images.txt"
    images.write_bytes(images.read_bytes().replace(b"b.png", b"\xffb.png"))
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what == "the name of image 2 is not UTF-8 text" and error.where == f"in {images}"


def test_colmap_text_image_name_with_a_space_names_the_line(tmp_path):
    """pycolmap read `my b.png` as `my`, so the error was "image not found" for a file named images/my."""
    images = write_colmap(tmp_path / "scene") / "images.txt"
    images.write_text(images.read_text().replace("b.png", "my b.png"))
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what == ("images.txt line 3 names image 'my b.png', but COLMAP's text format reads a name only up "
                          "to its first space")
    assert error.where == f"in {images}" and ".bin" in error.fix


def test_colmap_images_with_one_name_are_refused(tmp_path):
    """They were both loaded, from the one file, each with its own pose."""
    images = write_colmap(tmp_path / "scene", poses=("1 0 0 0",) * 3) / "images.txt"
    images.write_text(images.read_text().replace("c.png", "a.png"))
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what == "images 1 and 3 both have the name 'a.png'" and error.where == f"in {images}"


@pytest.mark.parametrize(("camera", "message"), [
    ("1 PINHOLE 0 6 5 5 4 3", "camera size 0x6 is not a plausible image size"),
    ("1 PINHOLE 8 0 5 5 4 3", "camera size 8x0 is not a plausible image size"),
    ("1 PINHOLE -8 6 5 5 4 3", "camera size -8x6 is not a plausible image size"),  # pycolmap reads it unsigned
    ("1 PINHOLE 8 6 0 5 4 3", "need a positive, finite focal length"),
    ("1 PINHOLE 8 6 5 0 4 3", "need a positive, finite focal length"),  # fy: a camera with zero height in rays
    ("1 PINHOLE 8 6 5 -5 4 3", "need a positive, finite focal length"),  # fy < 0: the image upside down
    ("1 SIMPLE_PINHOLE 8 6 -5 4 3", "need a positive, finite focal length"),
])
def test_colmap_camera_of_impossible_size_or_focal_names_the_camera(tmp_path, camera, message):
    write_colmap(tmp_path / "scene", camera=camera)
    error = load_error(tmp_path / "scene", tmp_path)
    assert message in error.what and error.where.endswith("cameras.txt (camera 1)")


@pytest.mark.parametrize(("fmt", "value"), [("txt", 1e39), ("bin", float("nan"))])
def test_colmap_point_that_is_not_finite_in_float32_names_the_point(tmp_path, fmt, value):
    """It seeded a Gaussian at infinity: training ran, and only the export said the model had NaN or Inf."""
    sparse = write_colmap(tmp_path / "scene", points="7 0.5 0.5 2 255 0 0 0.1\n8 1 1 2 0 255 0 0.1\n")
    reconstruction = pycolmap.Reconstruction(str(sparse))
    reconstruction.points3D[8].xyz = np.array([value, 1.0, 2.0])
    for name in ("cameras", "images", "points3D"):
        (sparse / f"{name}.txt").unlink()
    (reconstruction.write_text if fmt == "txt" else reconstruction.write_binary)(str(sparse))
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what.startswith("point 8 has a non-finite position or one beyond float32's range")
    assert error.where == f"in {sparse / f'points3D.{fmt}'}"


def test_colmap_zero_quaternion_is_refused_not_read_as_identity(tmp_path):
    write_colmap(tmp_path / "scene", poses=("1 0 0 0", "0 0 0 0"))
    error = load_error(tmp_path / "scene", tmp_path)
    assert "b.png has a zero" in error.what and error.where.endswith("images.txt")


@pytest.mark.parametrize("missing", ["cameras.txt", "images.txt", "points3D.txt"])
def test_colmap_model_missing_a_file_names_it(tmp_path, missing):
    (write_colmap(tmp_path / "scene") / missing).unlink()
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what == f"the COLMAP model has no {missing}" and error.where.endswith("sparse/0")


@pytest.mark.parametrize(("file", "edit", "line"), [
    ("images.txt", lambda text: text.replace("2 1 0 0 0", "2 nan 0 0 0"), 3),
    ("images.txt", lambda text: "garbage line here\n" + text, 1),
    ("points3D.txt", lambda text: "1 0.5 0.5 2 255 0 0 0.1\n1 x y z\n", 2),
    ("cameras.txt", lambda text: text.replace("5 5 4 3", "inf 5 4 3"), 2),
    ("cameras.txt", lambda text: text.replace("5 5 4 3", "5 5 4"), 2),  # PINHOLE takes 4 parameters
    ("cameras.txt", lambda text: text.replace("8 6", "8.5 6"), 2),  # sizes are integers
    ("points3D.txt", lambda text: "1 0.5 0.5 2 0.5 0 0 0.1\n", 1),  # so are colours
    # ids too large for COLMAP's integers: numpy's finiteness test raised a TypeError on them
    ("cameras.txt", lambda text: text.replace("1 PINHOLE", f"{10 ** 30} PINHOLE"), 2),
    ("images.txt", lambda text: text.replace("2 1 0 0 0", f"{10 ** 30} 1 0 0 0"), 3),
    ("cameras.txt", lambda text: text.replace("1 PINHOLE", f"{2 ** 32 - 1} PINHOLE"), 2),  # COLMAP's "invalid" id
    ("cameras.txt", lambda text: text.replace("5 5 4 3", "5 5 4 3 0"), 2),  # one parameter too many
    ("points3D.txt", lambda text: "1 0.5 0.5 2 255 0 0 0.1 1 0.5\n", 1),  # a track's 2D point index is an id
    # Python's int() and float() read these, COLMAP's reader does not: it took CAMERA_ID 1_0 as 1 and the photo "_0"
    ("images.txt", lambda text: text.replace("0 0 1 a.png", "0 0 1_0 a.png"), 1),
    ("points3D.txt", lambda text: "7 0.5 0.5 2 \u0662\u0665\u0665 0 0 0.1\n", 1),  # 255 in Arabic-Indic digits
    ("cameras.txt", lambda text: text.replace("1 PINHOLE", "\uff11 PINHOLE"), 2),  # a fullwidth 1
])
def test_colmap_text_that_cannot_be_parsed_names_the_file_and_line(tmp_path, file, edit, line):
    path = write_colmap(tmp_path / "scene") / file
    path.write_text(edit(path.read_text()))
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what.startswith(f"cannot parse {file} line {line} (") and error.where == f"in {path}"


def test_colmap_text_with_lines_ended_by_a_lone_cr_is_refused_not_misread(tmp_path):
    """COLMAP's reader ends a line at LF alone (CRLF works as it trims the CR), so a file saved with classic Mac
    line endings is one line to it: here pycolmap reads no image at all, without a word."""
    sparse = write_colmap(tmp_path / "scene")
    images = sparse / "images.txt"
    images.write_bytes(images.read_bytes().replace(b"\n", b"\r"))
    assert len(pycolmap.Reconstruction(str(sparse)).images) == 0
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what.startswith("images.txt line 1 ends in a lone carriage return (CR)")
    assert error.where == f"in {images}"


def test_colmap_images_txt_without_its_empty_points_lines_is_refused_not_half_read(tmp_path):
    """pycolmap takes the line after each pose as its 2D points, so with the empty lines removed it read the
    model as every other image, silently (checked here: it reads 1 of these 2 images)."""
    sparse = write_colmap(tmp_path / "scene")
    images = sparse / "images.txt"
    images.write_text("# a comment\n" + "".join(line + "\n" for line in images.read_text().splitlines() if line))
    assert len(pycolmap.Reconstruction(str(sparse)).images) == 1
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what.startswith("images.txt line 3 is an image's pose where COLMAP reads the 2D points")
    assert error.where == f"in {images}"


def test_a_missing_image_folder_says_so(tmp_path):
    """A scene copied without its images/ folder named only the first image and "the scene description", which a
    COLMAP model has none of: the message says the folder is missing and where the images go."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    folder = (root / cameras[0].name).parent
    for image in folder.iterdir():
        image.unlink()
    folder.rmdir()
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert error.what == f"image not found: its folder {folder.name}/ does not exist"
    assert error.fix.startswith(f"put the scene's images in {folder}, ")


@pytest.mark.parametrize("file_path", ["images", ""])
def test_an_image_path_that_is_a_folder_says_so(tmp_path, file_path):
    """It said "image not found" for a path that exists; an empty file_path is the scene folder itself."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: c["frames"][0].update(file_path=file_path))
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert error.what == "image path is a folder, not an image file"
    assert error.where == f"in {root / file_path}"


@pytest.mark.parametrize(("ext", "kind"), [(".jpg", "JPEG"), (".png", "PNG")])
def test_truncated_image_names_the_file(tmp_path, ext, kind):
    """libjpeg decodes a cut JPEG with only a warning (the rest grey); both formats are refused by content."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    encoded = cv2.imencode(ext, noise_image(2, 40, 30))[1].tobytes()
    (root / cameras[2].name).write_bytes(encoded[: len(encoded) * 2 // 3])
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert error.what.startswith(f"cannot decode image (truncated {kind}")
    assert error.where.endswith(cameras[2].name)


@pytest.mark.parametrize(("model", "k1", "expected"), [
    ("OPENCV_FISHEYE", -1.0, "distortion (-1.0, 0.0, 0.0, 0.0) has no usable undistorted camera (OpenCV's has "
     "focal length 8e-05 for the lens's 36 and principal point (80.5, 75.5) in a 40x30 image)"),
    ("OPENCV", 1e30, "distortion (1e+30, 0.0, 0.0, 0.0, 0.0) has no usable undistorted camera (OpenCV's has "
     "focal length 1.6e+31 for the lens's 36 and principal point (19.9, 14.9) in a 40x30 image)"),
])
def test_distortion_without_a_usable_undistorted_camera_names_the_frame(tmp_path, model, k1, expected):
    """OpenCV's undistorted camera for these had a focal length 2e-6 or 4e29 times the lens's, and trained."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: c.update(camera_model=model, k1=k1))
    error = load_error(root, tmp_path)
    assert error.what == expected and error.where == f"in frame {cameras[0].name!r} of {root / 'transforms.json'}"


def test_colmap_distortion_without_a_usable_undistorted_camera_names_the_camera(tmp_path):
    write_colmap(tmp_path / "scene", camera="1 OPENCV 8 6 5 5 4 3 1e30 0 0 0")
    error = load_error(tmp_path / "scene", tmp_path)
    assert "has no usable undistorted camera" in error.what and error.where.endswith("cameras.txt (camera 1)")


def test_image_size_that_disagrees_with_the_intrinsics(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=40, height=30)
    write_rgb(root / cameras[3].name, noise_image(3, 36, 30))
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert "36x30" in error.what and error.where.endswith(cameras[3].name)


def test_a_frame_of_another_size_within_a_split_loads_at_its_own_size(tmp_path):
    """Once refused ("image size 20x30 differs from 40x30 ... in the same split"): a frame's own w, h are nerfstudio's
    per-frame intrinsics, and a split may mix sizes (tests/unit/test_mixed_sizes.py goes on to train and score one)."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=40, height=30)
    write_rgb(root / cameras[3].name, noise_image(3, 20, 30))

    def shrink_last_frame(content):
        last = next(f for f in content["frames"] if f["file_path"] == cameras[3].name)
        last.update(w=20, cx=10.0)

    edit_transforms(root, shrink_last_frame)
    scene = load_scene(DataConfig(data=str(root), cache_dir=tmp_path / "cache", eval_split="every-n", eval_every=2))
    assert scene.train.names == [cameras[1].name, cameras[3].name]
    assert [tuple(image.shape) for image in scene.train.images] == [(30, 40, 3), (30, 20, 3)]


@pytest.mark.parametrize("bad_value", [float("nan"), float("inf")])
def test_non_finite_pose_names_the_frame(tmp_path, bad_value):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)

    def poison(content):
        frame = next(f for f in content["frames"] if f["file_path"] == cameras[1].name)
        frame["transform_matrix"][0][3] = bad_value

    edit_transforms(root, poison)
    error = load_error(root, tmp_path)
    assert "non-finite" in error.what and cameras[1].name in error.where


@pytest.mark.parametrize(("entry", "shown"), [(True, "True"), ("1", "'1'"), (None, "None")])
def test_a_pose_entry_that_is_not_a_number_names_the_frame(tmp_path, entry, shown):
    """numpy read true as 1.0 and "1" as 1.0, so such a pose loaded as if it were numbers; null read as NaN, "pose
    has non-finite values"."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)

    def replace_one_with(content):
        matrix = next(f for f in content["frames"] if f["file_path"] == cameras[1].name)["transform_matrix"]
        matrix[3][3] = entry

    edit_transforms(root, replace_one_with)
    error = load_error(root, tmp_path)
    assert error.what == f"pose holds {shown}, which is not a number" and cameras[1].name in error.where


def test_a_pose_whose_last_row_is_not_0_0_0_1_names_the_frame(tmp_path):
    """It was accepted, and its last row silently ignored: not a rigid pose, whatever the file meant by it."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)

    def projective(content):
        next(f for f in content["frames"] if f["file_path"] == cameras[2].name)["transform_matrix"][3] = [1.0] * 4

    edit_transforms(root, projective)
    error = load_error(root, tmp_path)
    assert "last row is [1.0, 1.0, 1.0, 1.0], not [0, 0, 0, 1]" in error.what and cameras[2].name in error.where


@pytest.mark.parametrize("far", [1e20, 3e38])
def test_a_camera_absurdly_far_from_the_others_names_the_frame(tmp_path, far):
    """Within float32's range it loaded, and normalisation squeezed every other camera to within 1e-17 of a point."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=6)

    def push_away(content):
        next(f for f in content["frames"] if f["file_path"] == cameras[2].name)["transform_matrix"][1][3] = far

    edit_transforms(root, push_away)
    error = load_error(root, tmp_path)
    assert f"the camera of {cameras[2].name!r} is" in error.what and error.where.endswith("transforms.json")


@pytest.mark.parametrize("place", [0.0, 3e6])
def test_cameras_turning_on_one_spot_load_at_any_coordinates(tmp_path, place):
    """At geo-referenced coordinates (3e6) float64's rounding of R^T t spread the centres of cameras on one spot by
    about 4e-10, against a median of about 1e-26: refused as one camera "1.45e+16 times farther" than the others."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=6)

    def on_one_spot(content):
        for frame in content["frames"]:
            for row, value in zip(frame["transform_matrix"][:3], (place, place / 3, 7.0), strict=True):
                row[3] = value

    edit_transforms(root, on_one_spot)
    raw = read_scene_files(root, (1.0, 1.0, 1.0))
    center, scale = scene_normalization(raw)
    assert scale == 1.0 and np.allclose(center.numpy(), [place, place / 3, 7.0], rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize(("place", "far", "refused"), [(0.0, 1e20, True), (3e6, 1e20, True), (0.0, 1.0, False),
                                                      (3e6, 1e6, False)])
def test_one_broken_pose_among_cameras_on_one_spot_names_the_frame(tmp_path, place, far, refused):
    """With every other camera on one spot there is no typical distance, so a pose at 1e20 loaded and normalisation
    scaled the scene by 1e-20; a camera at a plausible distance (1 m, or 1e6 at geo-referenced coordinates) loads."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=6)

    def one_pushed_away(content):
        for frame in content["frames"]:
            for row, value in zip(frame["transform_matrix"][:3], (place, place / 3, 7.0), strict=True):
                row[3] = value
        next(f for f in content["frames"] if f["file_path"] == cameras[2].name)["transform_matrix"][0][3] += far

    edit_transforms(root, one_pushed_away)
    if not refused:
        scene_normalization(read_scene_files(root, (1.0, 1.0, 1.0)))
        return
    error = load_error(root, tmp_path)
    assert error.what.startswith(f"the camera of {cameras[2].name!r} is 1e+20 from the position most cameras share")
    assert error.where.endswith("transforms.json")


def test_pose_beyond_float32_names_the_frame(tmp_path):
    """Finite in the file, infinite in training: it once trained on, every Gaussian collapsing to one point."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)

    def push_away(content):
        next(f for f in content["frames"] if f["file_path"] == cameras[1].name)["transform_matrix"][0][3] = 1e39

    edit_transforms(root, push_away)
    error = load_error(root, tmp_path)
    assert error.what == "pose has a value beyond float32's range (1e+39)" and cameras[1].name in error.where


@pytest.mark.parametrize(("lists", "message"), [
    ({"val_filenames": [1]}, "has val_filenames but no train_filenames"),
    ({"train_filenames": [0, 1, 2]}, "has train_filenames but no val_filenames or test_filenames"),
    ({"train_filenames": [0, 1], "test_filenames": [2, 3]}, None),
    ({"train_filenames": [0, 1, 0], "test_filenames": [2, 3, 3]}, None),  # a name listed twice is one view
    ({"train_filenames": [0, 1, 2], "test_filenames": [3, "images/nope.png"]}, "test_filenames names a frame"),
    ({"train_filenames": [0, 1, 2], "val_filenames": [2, 3]}, "'images/frame_002.png' is in both train_filenames"),
    ({"train_filenames": [0, 1], "val_filenames": [2], "test_filenames": [1, 3]}, "is in both train_filenames and "
                                                                                  "test_filenames"),
])
def test_split_lists_must_be_complete_known_and_disjoint(tmp_path, lists, message):
    root = tmp_path / "scene"
    names = [c.name for c in write_nerfstudio_scene(root, n=4)]
    edit_transforms(root, lambda c: c.update({k: [names[i] if isinstance(i, int) else i for i in v]
                                              for k, v in lists.items()}))
    if message is None:  # train + test without val: test is the eval split, as NeRF-synthetic's test split is
        scene = load_scene(DataConfig(data=str(root), cache_dir=tmp_path / "cache"))
        assert scene.train.names == names[:2] and scene.eval.names == names[2:] and not scene.extra_eval
        return
    error = load_error(root, tmp_path)
    assert message in error.what and "transforms.json" in error.where


def test_a_saved_config_with_an_unused_out_of_range_value_still_loads(tmp_path):
    """Before these checks an ignored --eval-every 1 was accepted and saved; render and eval replay it."""
    write_nerfstudio_scene(tmp_path / "scene", n=6)
    config = DataConfig(data=str(tmp_path / "scene"), cache_dir=tmp_path / "cache", eval_split="contiguous",
                        eval_every=1)
    assert len(load_scene(config).eval) > 0
    with pytest.raises(SplatuError, match="--eval-every must be at least 2"):
        dataclasses.replace(config, eval_split="every-n").validate()


@pytest.mark.parametrize(("options", "flag"), [
    ({"eval_list": Path("eval.txt")}, "--eval-list"),
    ({"eval_split": "contiguous", "eval_every": 4}, "--eval-every"),
    ({"eval_split": "every-n", "eval_block": 2}, "--eval-block"),
    ({"eval_split": "every-n", "split_seed": 3}, "--split-seed"),
])
def test_flags_the_chosen_split_would_ignore_are_refused_for_a_new_run_only(tmp_path, options, flag):
    config = DataConfig(data=str(tmp_path / "scene"), cache_dir=tmp_path / "cache", **options)
    with pytest.raises(SplatuError) as caught:
        config.refuse_unused_flags()
    assert caught.value.what.startswith(f"{flag} is not used by --eval-split") and flag in caught.value.fix
    write_nerfstudio_scene(tmp_path / "scene", n=6)
    if "eval_list" not in options:  # a saved run's config that carried the ignored flag still loads
        assert len(load_scene(config).train) > 0


@pytest.mark.parametrize(("name", "stand_in"), [("scene", False), ("poster", True)])
def test_eval_block_with_the_scene_s_own_split_is_refused(tmp_path, name, stand_in):
    root = tmp_path / "scene"
    names = [c.name for c in write_nerfstudio_scene(root, n=6)]
    edit_transforms(root, lambda c: c.update(train_filenames=names[:4], val_filenames=names[4:]))
    raw = read_scene_files(root, (1.0, 1.0, 1.0))
    raw.name = name  # load_scene names every `--data poster` scene "poster"
    scene = assemble(raw, DataConfig(eval_block=2), ImageCache(tmp_path / "cache"))  # a saved config still loads
    assert scene.own_split and scene.eval.names == names[4:]
    with pytest.raises(SplatuError) as caught:
        refuse_split_flags_the_scene_overrides(DataConfig(eval_block=2), scene)
    assert "--eval-block is not used" in caught.value.what and "--eval-split contiguous" in caught.value.fix
    assert ("--poster.eval-block" in caught.value.fix) == stand_in
    refuse_split_flags_the_scene_overrides(DataConfig(), scene)
    with pytest.raises(SplatuError) as caught:
        refuse_split_flags_the_scene_overrides(DataConfig(split_seed=4), scene)
    assert caught.value.what.startswith("--split-seed is not used")
    assert ("--poster.seed" in caught.value.fix) == stand_in


@pytest.mark.parametrize(("options", "message"), [
    ({"eval_block": -3}, "--eval-block must be at least 0 (got -3)"),
    ({"eval_split": "every-n", "eval_every": 0}, "--eval-every must be at least 2 (got 0)"),
    ({"downscale": 0}, "--downscale must be at least 1 (got 0)"),
    ({"background": (1.5, 0.0, 0.0)}, "--background must be three RGB values in [0, 1]"),
    ({"background": (float("nan"), 0.0, 0.0)}, "--background must be three RGB values in [0, 1]"),
])
def test_out_of_range_options_say_the_valid_range(tmp_path, options, message):
    write_nerfstudio_scene(tmp_path / "scene", n=4)
    error = load_error(tmp_path / "scene", tmp_path, **options)
    assert error.what.startswith(message)


def test_eval_block_too_large_says_the_valid_range(tmp_path):
    write_nerfstudio_scene(tmp_path / "scene", n=4)
    error = load_error(tmp_path / "scene", tmp_path, eval_split="contiguous", eval_block=4)
    assert "out of range" in error.what and error.fix == "pass --eval-block between 1 and 3"


def test_downscale_that_leaves_no_pixels_names_the_image_size(tmp_path):
    cameras = write_nerfstudio_scene(tmp_path / "scene", n=4, width=40, height=30)
    error = load_error(tmp_path / "scene", tmp_path, downscale=1000)
    assert error.what.startswith("--downscale 1000 shrinks the 40x30 image to 1x1 px")
    assert error.fix == "pass --downscale 3 or less" and error.where.endswith(cameras[0].name)
    assert load_scene(DataConfig(data=str(tmp_path / "scene"), downscale=3, cache_dir=tmp_path / "cache"))


def test_downscale_of_an_image_already_below_the_smallest_side_says_so(tmp_path):
    """A 6x4 image at --downscale 2 was told it "shrinks the 6x4 image to 3x2 px"; a 1x1 one "to 1x1 px"."""
    write_nerfstudio_scene(tmp_path / "scene", n=4, width=6, height=4)
    error = load_error(tmp_path / "scene", tmp_path, downscale=2)
    assert error.what == "the 6x4 image is already below 8 px a side, too small for --downscale 2"
    assert error.fix == "drop --downscale"


def test_missing_mask_says_mask_and_names_mask_path(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: c["frames"][1].update(mask_path="masks/gone.png"))
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert error.what == f"mask not found (the mask_path of frame {cameras[1].name!r})"
    assert error.where.endswith("masks/gone.png") and "mask_path" in error.fix


def test_frame_without_file_path_is_counted_as_in_the_file(tmp_path):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: c["frames"][2].pop("file_path"))  # it would sort first
    assert load_error(root, tmp_path).what == "frames[2] has no file_path"


def test_frame_whose_file_path_is_a_number_says_so_rather_than_that_it_has_none(tmp_path):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: c["frames"][2].update(file_path=5))  # it said "frames[2] has no file_path"
    error = load_error(root, tmp_path)
    assert error.what == "frames[2]'s file_path is 5, not a string" and "in quotes" in error.fix


def test_frame_without_transform_matrix_says_so(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: c["frames"][3].pop("transform_matrix"))
    error = load_error(root, tmp_path)
    assert error.what == "frame has no transform_matrix" and cameras[3].name in error.where


def test_empty_split_from_the_file_lists(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    names = [c.name for c in cameras]
    edit_transforms(root, lambda c: c.update(train_filenames=names, val_filenames=[]))
    error = load_error(root, tmp_path)
    assert "eval split is empty" in error.what and "transforms.json" in error.where


def test_empty_split_from_an_eval_list(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    listed = tmp_path / "all.txt"
    listed.write_text("\n".join(c.name for c in cameras))
    error = load_error(root, tmp_path, eval_split="list", eval_list=listed)
    assert "empty split" in error.what and "all.txt" in error.where


def test_an_eval_list_that_is_not_utf8_is_one_line(tmp_path):
    """read_text raised UnicodeDecodeError (a traceback) on a list saved in Latin-1."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    listed = tmp_path / "eval.txt"
    listed.write_bytes("images/fram\xe9_000.png\n".encode("latin-1"))
    error = load_error(root, tmp_path, eval_split="list", eval_list=listed)
    assert error.what == "eval list is not UTF-8 text (byte 11)" and error.where == f"in {listed}"
    listed.write_bytes(b"\xef\xbb\xbf" + "images/fram\xe9_000.png\n".encode("latin-1"))  # a mark, then the byte
    error = load_error(root, tmp_path, eval_split="list", eval_list=listed)
    assert error.what == "eval list is not UTF-8 text (byte 14)"  # counted from the file's start, as an editor does


def test_an_eval_list_with_a_byte_order_mark_reads_its_first_name(tmp_path):
    """Windows editors start UTF-8 files with one; the first name was '\\ufeffimages/...', an unknown frame."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    listed = tmp_path / "eval.txt"
    listed.write_text(cameras[1].name + "\n", encoding="utf-8-sig")
    scene = load_scene(DataConfig(data=str(root), cache_dir=tmp_path / "cache", eval_split="list", eval_list=listed))
    assert scene.eval.names == [cameras[1].name]


def write_blender(root: Path, train: list[str], test: list[str], angle: object = 0.69) -> None:
    """A NeRF-synthetic scene whose split files list these file paths (images r_0, r_1, r_2 in train/ and test/)."""
    for split in ("train", "test"):
        for i in range(3):
            write_rgb(root / split / f"r_{i}.png", noise_image(i, 20, 16, channels=4))
    for split, paths in (("train", train), ("test", test)):
        frames = [{"file_path": path, "transform_matrix": np.eye(4).tolist()} for path in paths]
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": angle, "frames": frames}))


@pytest.mark.parametrize(("train", "test", "listed_again", "file"), [
    (["./train/r_0", "./train/r_1"], ["./test/r_0", "./train/r_1"], "frames[1] lists image 'train/r_1'",
     "transforms_test.json"),  # scored on a view it trained on
    (["./train/r_0", "./train/r_1", "./train/r_0"], ["./test/r_0"], "frames[2] lists image 'train/r_0'",
     "transforms_train.json"),  # trained on twice as often
])
def test_a_nerf_synthetic_training_image_listed_again_is_refused(tmp_path, train, test, listed_again, file):
    """nerfstudio files refuse both; NeRF-synthetic ones were loaded as they were."""
    write_blender(tmp_path / "lego", train, test)
    error = load_error(tmp_path / "lego", tmp_path)
    assert error.what == f"{listed_again}, which transforms_train.json lists too"
    assert error.where == f"in {tmp_path / 'lego' / file}"


def test_a_nerf_synthetic_held_out_image_in_val_and_test_is_no_leak(tmp_path):
    """Only a training image listed again is refused: one held out twice was never trained on."""
    root = tmp_path / "lego"
    write_blender(root, ["./train/r_0", "./train/r_1"], ["./test/r_0"])
    (root / "transforms_val.json").write_text((root / "transforms_test.json").read_text())
    assert [frame.name for frame in read_scene_files(root, (1.0, 1.0, 1.0)).frames] == [
        "train/r_0", "train/r_1", "test/r_0", "test/r_0"]


def test_a_nerf_synthetic_camera_angle_that_is_a_bool_is_refused(tmp_path):
    """true was read as 1 radian."""
    write_blender(tmp_path / "lego", ["./train/r_0", "./train/r_1"], ["./test/r_0"], angle=True)
    error = load_error(tmp_path / "lego", tmp_path)
    assert error.what == "camera_angle_x must be an angle in (0, pi) radians (got True)"


def test_too_few_images(tmp_path):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=1)
    error = load_error(root, tmp_path)
    assert "too few images (1)" in error.what and "transforms.json" in error.where


def test_corrupt_json(tmp_path):
    root = tmp_path / "scene"
    root.mkdir()
    (root / "transforms.json").write_text("{ not json")
    error = load_error(root, tmp_path)
    assert "cannot parse JSON" in error.what and "transforms.json" in error.where


def test_bad_depth_map_names_the_file(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=8, height=6)
    np.save(root / "d.npy", np.full((6, 8), np.nan, np.float32))
    edit_transforms(root, lambda c: [f.update(depth_file_path="d.npy") for f in c["frames"]])
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert "finite" in error.what and error.where.endswith("d.npy")
    assert cameras  # the scene itself is valid; only the depth is bad


def test_corrupt_depth_npy_is_named_without_numpy_advice(tmp_path):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4, width=8, height=6)
    np.save(root / "d.npy", np.array([{"not": "depth"}], dtype=object), allow_pickle=True)
    edit_transforms(root, lambda c: [f.update(depth_file_path="d.npy") for f in c["frames"]])
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert error.what == "depth map is not a valid .npy array of numbers" and error.where.endswith("d.npy")


def write_webp_named_png(path: Path, seed: int) -> None:
    """A photo OpenCV (the training loader) decodes by its content but COLMAP 4 cannot read: WebP bytes."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(cv2.imencode(".webp", noise_image(seed, 32, 32))[1].tobytes())


def test_failed_process_images_leaves_nothing_so_a_retry_needs_no_overwrite(tmp_path):
    photos = tmp_path / "photos"
    for i, name in enumerate(("a.png", "b.png")):
        write_webp_named_png(photos / name, i)
    config = ProcessImagesConfig(images=photos, output=tmp_path / "out")
    for _attempt in range(2):
        with pytest.raises(SplatuError) as caught:
            process_images(config)
        assert caught.value.what == "COLMAP could read only 0 of 2 photos"
        assert caught.value.fix.startswith("replace unreadable files ('a.png', 'b.png') with JPEG/PNG photos")
        assert not (tmp_path / "out").exists()


def test_process_images_names_a_photo_colmap_could_not_read_in_one_line_of_its_own(tmp_path, capfd):
    """COLMAP's own warning, a raw log line (W20261126 14:42:53 ... feature_extraction.cc ... BITMAP_ERROR), came
    through without --colmap-log; splatu now says which photo it skipped and COLMAP's warnings stay hidden."""
    photos = tmp_path / "photos"
    for i in range(3):
        write_rgb(photos / f"{i}.png", noise_image(i, 64, 64))
    write_webp_named_png(photos / "3.png", 3)
    with pytest.raises(SplatuError, match="no model"):  # unrelated noise: nothing matches
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out"))
    err = capfd.readouterr().err.splitlines()
    assert "  skipped 1 of 4 photos COLMAP could not read: '3.png' (--colmap-log shows why)" in err
    assert not [line for line in err if re.match(r"[IWE]\d{8} ", line)]  # no glog line


def test_process_images_without_a_model_does_not_suggest_the_default_matcher(tmp_path):
    photos = tmp_path / "images"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 64, 64))  # unrelated noise: nothing matches
    (tmp_path / "database.db").write_text("an old one")
    with pytest.raises(SplatuError) as caught:
        process_images(ProcessImagesConfig(images=photos, overwrite=True))
    assert "no model" in caught.value.what and "--matcher" not in caught.value.fix
    assert sorted(p.name for p in tmp_path.iterdir()) == ["database.db", "images"]


def test_a_failed_overwrite_keeps_the_earlier_model(tmp_path):
    """--overwrite deleted database.db and sparse/0 before the new run, so a failed or interrupted one lost them."""
    photos = tmp_path / "photos"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 64, 64))  # unrelated noise: nothing matches
    out = tmp_path / "out"
    (out / "sparse" / "0").mkdir(parents=True)
    (out / "sparse" / "0" / "cameras.txt").write_text("the old model")
    (out / "database.db").write_text("the old database")
    with pytest.raises(SplatuError, match="no model"):
        process_images(ProcessImagesConfig(images=photos, output=out, overwrite=True))
    assert (out / "sparse" / "0" / "cameras.txt").read_text() == "the old model"
    assert (out / "database.db").read_text() == "the old database"
    assert sorted(p.name for p in out.iterdir()) == ["database.db", "sparse"]
    assert sorted(p.name for p in (out / "sparse").iterdir()) == ["0"]


def stop_at_the_sfm(monkeypatch, seen: list) -> None:
    """Replace the SfM by one that records where it would have written and fails."""
    from splatu.data import process_images as P

    def reconstruct(cfg, names, mode, staging, console):
        seen.append((names, mode, staging.parent, staging.name))
        raise SplatuError("stopped", "in the test", "none")

    monkeypatch.setattr(P, "_reconstruct", reconstruct)


def test_process_images_removes_the_staging_folders_killed_runs_left(tmp_path, monkeypatch, capfd):
    """A kill -9 left a hidden .process-images-* folder (with its database) in the output for good. The next run
    removes those whose process is gone, and keeps a live run's, another host's and an older splatu's (no pid)."""
    photos, out = tmp_path / "photos", tmp_path / "out"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    ended = subprocess.Popen(["true"])  # its process id no longer runs once it is waited for
    ended.wait()
    host = socket.gethostname()
    names = {"stale": f".process-images-{ended.pid}@{host}-k1lled00",
             "live": f".process-images-{os.getpid()}@{host}-running0",
             "elsewhere": f".process-images-{ended.pid}@not-{host}-another", "older": ".process-images-x1y2z3w4"}
    for name in names.values():
        (out / name).mkdir(parents=True)
        (out / name / "database.db").write_text("staged")
    # a run killed between making its folder and naming it left it empty; a live run names its own at once
    unnamed = {"killed": ".process-images-new-k1lled00", "just made": ".process-images-new-justmade",
               "not empty": ".process-images-new-notempty"}
    for key, name in unnamed.items():
        (out / name).mkdir()
        if key != "just made":
            os.utime(out / name, (time.time() - 120, time.time() - 120))
    (out / unnamed["not empty"] / "database.db").write_text("not ours to lose")
    seen: list = []
    stop_at_the_sfm(monkeypatch, seen)
    with pytest.raises(SplatuError, match="stopped"):
        process_images(ProcessImagesConfig(images=photos, output=out))
    kept = [names[k] for k in ("live", "elsewhere", "older")] + [unnamed[k] for k in ("just made", "not empty")]
    assert sorted(p.name for p in out.iterdir()) == sorted(kept)
    assert seen[0][3].startswith(f".process-images-{os.getpid()}@{host}-")  # this run's own: gone, as it failed
    assert f"removed 2 staging folders that killed runs left in {out}" in capfd.readouterr().err


def test_process_images_keeps_a_staging_folder_whose_lock_is_held(tmp_path, monkeypatch):
    """A run in another container of the same host name has a process id this one cannot see: its folder looked
    killed and was deleted under it. Its lock (on the folder, held while it runs) now keeps it; a run holds its own."""
    from splatu.data import process_images as P

    photos, out = tmp_path / "photos", tmp_path / "out"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    ended = subprocess.Popen(["true"])
    ended.wait()
    elsewhere = out / f".process-images-{ended.pid}@{socket.gethostname()}-othrpid0"
    elsewhere.mkdir(parents=True)
    held = os.open(elsewhere, os.O_RDONLY)
    fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as that run's own descriptor holds it
    own_locked = []

    def reconstruct(cfg, names, mode, staging, console):
        own_locked.append(not P._unlocked(staging))
        raise SplatuError("stopped", "in the test", "none")

    monkeypatch.setattr(P, "_reconstruct", reconstruct)
    try:
        with pytest.raises(SplatuError, match="stopped"):
            process_images(ProcessImagesConfig(images=photos, output=out))
        assert sorted(p.name for p in out.iterdir()) == [elsewhere.name]
    finally:
        os.close(held)
    assert own_locked == [True]
    assert P._unlocked(elsewhere)  # its run ended: the next one removes it


@pytest.mark.parametrize(("folder", "output"), [("shots", "shots-colmap"), ("images", ".")])
def test_process_images_of_the_current_folder_names_its_output_by_the_folder(tmp_path, monkeypatch, folder, output):
    """`splatu process-images .` raised ValueError: PosixPath('.') has an empty name."""
    photos = tmp_path / folder
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    seen: list = []
    stop_at_the_sfm(monkeypatch, seen)
    monkeypatch.chdir(photos)
    with pytest.raises(SplatuError, match="stopped"):
        process_images(ProcessImagesConfig(images=Path(".")))
    assert seen[0][2] == (tmp_path / output).resolve()


def test_photos_of_several_sizes_get_one_camera_each(tmp_path, capfd):
    """One shared camera made COLMAP drop every photo of another size than the first (CAMERA_SINGLE_DIM_ERROR),
    reported as a photo it could not read."""
    photos = tmp_path / "photos"
    for i, (width, height) in enumerate([(64, 64), (64, 48), (48, 64)]):
        write_rgb(photos / f"{i}.png", noise_image(i, width, height))
    with pytest.raises(SplatuError, match="no model"):  # unrelated noise: nothing matches
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out"))
    err = capfd.readouterr().err
    assert "could not read" not in err and "(CPU, one camera per photo)" in err


def test_photos_of_one_size_share_one_camera(tmp_path, monkeypatch):
    photos = tmp_path / "photos"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    seen: list = []
    stop_at_the_sfm(monkeypatch, seen)
    with pytest.raises(SplatuError, match="stopped"):
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out"))
    assert seen[0][1] == pycolmap.CameraMode.SINGLE


def test_a_single_camera_forced_on_photos_of_several_sizes_is_one_line(tmp_path, monkeypatch):
    photos = tmp_path / "photos"
    for i, (width, height) in enumerate([(16, 16), (16, 12), (16, 16)]):
        write_rgb(photos / f"{i}.png", noise_image(i, width, height))
    stop_at_the_sfm(monkeypatch, [])
    with pytest.raises(SplatuError) as caught:
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out", single_camera=True))
    assert caught.value.what == "--single-camera needs photos of one size, but they come in 2 sizes ('0.png' 16x16, " \
        "'1.png' 16x12)"
    assert "leave out --single-camera" in caught.value.fix and not (tmp_path / "out").exists()


def test_a_truncated_jpeg_is_refused_before_the_sfm(tmp_path, monkeypatch):
    """COLMAP reads a truncated JPEG, so it passed the SfM and then `splatu train` refused it."""
    photos = tmp_path / "photos"
    for i in range(3):
        write_rgb(photos / f"{i}.jpg", noise_image(i, 32, 32))
    data = (photos / "1.jpg").read_bytes()
    (photos / "1.jpg").write_bytes(data[: len(data) * 2 // 3])
    stop_at_the_sfm(monkeypatch, [])
    with pytest.raises(SplatuError) as caught:
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out"))
    assert caught.value.what.startswith("1 of 3 photos would not load for training: '1.jpg' (cannot decode image "
                                        "(truncated JPEG")
    assert "\n" not in str(caught.value) and not (tmp_path / "out").exists()


def test_webp_photos_are_left_out_and_named(tmp_path, monkeypatch, capfd):
    """WebP was listed as accepted, but COLMAP 4 cannot read it; a photo left out is named, not dropped silently."""
    photos = tmp_path / "photos"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    (photos / "2.webp").write_bytes(cv2.imencode(".webp", noise_image(2, 16, 16))[1].tobytes())
    (photos / ".DS_Store").write_bytes(b"")  # hidden files are no one's photos
    seen: list = []
    stop_at_the_sfm(monkeypatch, seen)
    with pytest.raises(SplatuError, match="stopped"):
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out"))
    assert seen[0][0] == ["0.png", "1.png"]
    assert "  left out, as not bmp/jpeg/jpg/png/tif/tiff photos: '2.webp'" in capfd.readouterr().err


def test_a_stop_while_the_new_model_replaces_the_old_one_keeps_a_whole_model_and_its_database(tmp_path, monkeypatch):
    """The old model was deleted before the new one was renamed in, and the database replaced after: a stop between
    left no sparse/0 (the old one in a hidden folder), or a new model beside the old database."""
    from splatu import atomic
    from splatu.data import process_images as P

    def reconstruct(cfg, names, mode, staging, console):
        (staging / "sparse" / "0").mkdir(parents=True)
        (staging / "sparse" / "0" / "cameras.txt").write_text("the new model")
        (staging / "database.db").write_text("the new database")
        return pycolmap.Reconstruction()

    real_rmtree = atomic.shutil.rmtree

    def stopped_while_deleting_the_old_model(path, *args, **kwargs):
        if (Path(path) / "cameras.txt").is_file():
            os.kill(os.getpid(), signal.SIGINT)
        return real_rmtree(path, *args, **kwargs)

    photos, out = tmp_path / "photos", tmp_path / "out"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    (out / "sparse" / "0").mkdir(parents=True)
    (out / "sparse" / "0" / "cameras.txt").write_text("the old model")
    (out / "database.db").write_text("the old database")
    monkeypatch.setattr(P, "_reconstruct", reconstruct)
    monkeypatch.setattr(atomic.shutil, "rmtree", stopped_while_deleting_the_old_model)
    with pytest.raises(KeyboardInterrupt):
        process_images(ProcessImagesConfig(images=photos, output=out, overwrite=True))
    assert (out / "sparse" / "0" / "cameras.txt").read_text() == "the new model"
    assert (out / "database.db").read_text() == "the new database"
    assert sorted(p.name for p in (out / "sparse").iterdir()) == ["0"]


@pytest.mark.parametrize(("scene_file", "data"), [(None, "my out"), ("transforms.json", "my out/sparse/0")])
def test_process_images_prints_the_data_path_that_loads_its_model(tmp_path, monkeypatch, capfd, scene_file, data):
    """A transforms.json in the output wins over sparse/0 when --data names the folder; the line pastes into a shell
    as printed, a space in the path included."""
    from splatu.data import process_images as P

    def reconstruct(cfg, names, mode, staging, console):
        (staging / "sparse" / "0").mkdir(parents=True)
        (staging / "database.db").write_text("new")
        return pycolmap.Reconstruction()

    photos = tmp_path / "photos"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    if scene_file:
        (tmp_path / "my out").mkdir()
        (tmp_path / "my out" / scene_file).write_text("{}")
    monkeypatch.setattr(P, "_reconstruct", reconstruct)
    process_images(ProcessImagesConfig(images=photos, output=tmp_path / "my out"))
    assert f"train on it with: splatu train --data {shlex.quote(str(tmp_path / data))}" in capfd.readouterr().err


def test_a_conflicting_images_folder_is_refused_before_the_sfm_runs(tmp_path, monkeypatch):
    """It used to be found after the whole reconstruction, whose model the cleanup then deleted."""
    from splatu.data import process_images as P

    photos = tmp_path / "photos"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    (tmp_path / "out" / "images").mkdir(parents=True)
    monkeypatch.setattr(P, "_reconstruct", lambda *args: pytest.fail("the SfM ran"))
    with pytest.raises(SplatuError, match="different images folder"):
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out"))
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["images"]


@pytest.mark.parametrize("entry", ["link loop", "broken link", "folder"])
def test_process_images_refuses_a_photo_that_is_no_file_before_the_sfm(tmp_path, monkeypatch, entry):
    """A symlink loop named a.jpg aborted pycolmap's reader (SIGABRT, the whole process); the others were skipped
    with a warning only COLMAP's log gave."""
    from splatu.data import process_images as P

    photos = tmp_path / "photos"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    odd = photos / "a.jpg"
    if entry == "folder":
        odd.mkdir()
    else:
        odd.symlink_to(odd.name if entry == "link loop" else "nowhere.jpg")
    monkeypatch.setattr(P, "_reconstruct", lambda *args: pytest.fail("the SfM ran"))
    with pytest.raises(SplatuError) as caught:
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out"))
    assert caught.value.what.startswith("not a photo file") and caught.value.where == f"in {odd}"
    assert not (tmp_path / "out").exists()


def test_process_images_refuses_a_photo_name_that_is_not_utf8(tmp_path, monkeypatch):
    """pycolmap refused the name with a TypeError (a traceback listing its whole signature)."""
    from splatu.data import process_images as P

    photos = tmp_path / "photos"
    photos.mkdir()
    for name in (b"a.png", b"\xffb.png"):
        path = Path(os.fsdecode(os.fsencode(photos) + b"/" + name))
        path.write_bytes(cv2.imencode(".png", noise_image(len(name), 16, 16))[1].tobytes())  # imwrite: a segfault
    monkeypatch.setattr(P, "_reconstruct", lambda *args: pytest.fail("the SfM ran"))
    with pytest.raises(SplatuError) as caught:
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out"))
    assert caught.value.what == "the photo's name is not UTF-8 text" and "b.png" in caught.value.where


def test_process_images_output_that_is_a_file_is_one_line(tmp_path, monkeypatch):
    """It raised FileExistsError from mkdir."""
    from splatu.data import process_images as P

    photos = tmp_path / "photos"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    (tmp_path / "out").write_text("a file")
    monkeypatch.setattr(P, "_reconstruct", lambda *args: pytest.fail("the SfM ran"))
    with pytest.raises(SplatuError) as caught:
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out"))
    assert caught.value.what.startswith("cannot write the output folder") and "--output" in caught.value.fix
    assert (tmp_path / "out").read_text() == "a file"


def test_process_images_with_no_usable_photos_names_what_it_skipped(tmp_path):
    """A folder of 30 HEIC photos read as "too few photos (0)", as if it were empty."""
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(3):
        (photos / f"IMG_{i}.HEIC").write_bytes(b"heic")
    with pytest.raises(SplatuError) as caught:
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out"))
    assert caught.value.what.endswith("(3 other entries skipped, e.g. 'IMG_0.HEIC')")
    assert "jpg/png" in caught.value.fix and "webp" not in caught.value.fix


def test_cli_prints_one_line_and_exits_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as caught:
        entrypoint(["process-images", str(tmp_path / "nowhere")])
    assert caught.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("error: photo folder not found") and "nowhere" in err


def test_a_photo_passed_for_its_folder_is_said_to_be_a_file(tmp_path, capsys):
    """`process-images images/0001.jpg` (a shell's completion) said "photo folder not found" of a file that exists."""
    photo = tmp_path / "images" / "0001.jpg"
    photo.parent.mkdir()
    photo.write_bytes(b"")
    with pytest.raises(SystemExit):
        entrypoint(["process-images", str(photo)])
    assert capsys.readouterr().err == (f"error: this is a file; process-images takes the folder of photos, in {photo}, "
                                       f"pass its folder, {photo.parent}\n")


@pytest.mark.parametrize(("key", "value"), [("w", True), ("fl_x", 1e308), ("h", "480")])
def test_an_intrinsic_that_is_a_bool_string_or_beyond_float32_names_the_key(tmp_path, key, value):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: [frame.update({key: value}) for frame in c["frames"]])
    error = load_error(root, tmp_path)
    assert f"intrinsic {key} must be a finite number" in error.what and "transforms.json" in error.where


def test_a_nerfstudio_image_width_beyond_opencv_s_sizes_names_the_frame(tmp_path):
    """With distortion, a w beyond OpenCV's 32-bit sizes was a cv2.error traceback ("Can't parse 'imageSize'")."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: [frame.update(w=3e9, k1=0.1) for frame in c["frames"]])
    error = load_error(root, tmp_path)
    assert error.what == "image size 3000000000x30 is not a plausible image size" and cameras[0].name in error.where


def test_a_nerfstudio_image_size_that_is_not_a_whole_number_is_refused_and_a_whole_float_is_read(tmp_path):
    """w = 40.5 was rounded to 40 (and 67.5 to 68, Python's rounding to even): a size the file never gave."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: [frame.update(w=40.5) for frame in c["frames"]])
    error = load_error(root, tmp_path)
    assert error.what == "image size w = 40.5 is not a whole number of pixels" and cameras[0].name in error.where
    edit_transforms(root, lambda c: [frame.update(w=40.0) for frame in c["frames"]])
    assert read_scene_files(root, (1.0, 1.0, 1.0)).frames[0].camera.width == 40


@pytest.mark.parametrize(("w", "h", "plausible"), [(2**16, 30, True), (40, 2**16 + 1, False)])
def test_a_nerfstudio_image_side_may_reach_the_limit_and_not_pass_it(tmp_path, w, h, plausible):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: [frame.update(w=w, h=h, fl_x=3e4, fl_y=3e4) for frame in c["frames"]])
    if plausible:
        assert read_scene_files(root, (1.0, 1.0, 1.0)).frames[0].camera.width == w
        return
    with pytest.raises(SplatuError) as caught:
        read_scene_files(root, (1.0, 1.0, 1.0))
    assert caught.value.what == f"image size {w}x{h} is not a plausible image size"


def test_two_frames_with_the_same_file_path_are_refused(tmp_path):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: c["frames"].append(dict(c["frames"][1])))
    error = load_error(root, tmp_path)
    assert "frames 1 and 4 both have file_path" in error.what and "transforms.json" in error.where


def test_a_mirrored_pose_names_the_frame(tmp_path):
    """A camera axis flipped (R·diag(−1, 1, 1)) is still orthonormal, but a reflection: determinant −1."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)

    def mirror(content):
        matrix = next(f for f in content["frames"] if f["file_path"] == cameras[1].name)["transform_matrix"]
        for row in matrix[:3]:
            row[0] = -row[0]

    edit_transforms(root, mirror)
    error = load_error(root, tmp_path)
    assert error.what == "pose rotation is not a rotation matrix" and cameras[1].name in error.where


@pytest.mark.parametrize("fl_y", [0.0, -36.0])
def test_a_focal_length_fl_y_that_is_not_positive_is_refused(tmp_path, fl_y):
    """fl_y is checked as fl_x is: a negative one would load the images upside down, a zero one divide by zero."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: [frame.update(fl_y=fl_y) for frame in c["frames"]])
    error = load_error(root, tmp_path)
    assert error.what == "focal lengths must be positive" and "transforms.json" in error.where


@pytest.mark.parametrize("distort", ["scaled", "sheared"])
def test_a_pose_whose_rotation_is_scaled_or_sheared_names_the_frame(tmp_path, distort):
    """A rotation block 2% too long, or with a 2% shear, is no rotation (RᵀR ≠ I): it would stretch the scene."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)

    def deform(content):
        matrix = np.array(next(f for f in content["frames"] if f["file_path"] == cameras[1].name)["transform_matrix"])
        factor = np.diag([1.02, 1.02, 1.02]) if distort == "scaled" else np.array([[1, 0.02, 0], [0, 1, 0], [0, 0, 1]])
        matrix[:3, :3] = matrix[:3, :3] @ factor
        next(f for f in content["frames"] if f["file_path"] == cameras[1].name)["transform_matrix"] = matrix.tolist()

    edit_transforms(root, deform)
    error = load_error(root, tmp_path)
    assert error.what == "pose rotation is not a rotation matrix" and cameras[1].name in error.where


@pytest.mark.parametrize("size", [0, -1])
def test_process_images_max_image_size_below_1_is_refused_before_the_sfm(tmp_path, monkeypatch, size):
    """COLMAP reads 0 or below as its own default, 3200 px: neither "no limit" nor the size asked for."""
    from splatu.data import process_images as P

    photos = tmp_path / "photos"
    for i in range(2):
        write_rgb(photos / f"{i}.png", noise_image(i, 16, 16))
    monkeypatch.setattr(P, "_reconstruct", lambda *args: pytest.fail("the SfM ran"))
    with pytest.raises(SplatuError) as caught:
        process_images(ProcessImagesConfig(images=photos, output=tmp_path / "out", max_image_size=size))
    assert caught.value.what == f"--max-image-size must be a positive number of pixels (got {size})"
    assert "--max-image-size 1600" in caught.value.fix and not (tmp_path / "out").exists()


@pytest.mark.parametrize("colour", ["300 0 0", "0 -1 0", "0 0 256"])
def test_a_colmap_point_colour_outside_0_to_255_names_the_point_and_line(tmp_path, colour):
    """pycolmap wrapped it round silently (300 read as 44, -1 as 255)."""
    sparse = write_colmap(tmp_path / "scene", points=f"7 0.5 0.5 2 255 0 0 0.1\n8 1 1 2 {colour} 0.1\n")
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what == f"point 8's colour ({colour.replace(' ', ', ')}) is not RGB from 0 to 255"
    assert error.where == f"in {sparse / 'points3D.txt'} line 2"


@pytest.mark.parametrize(("file", "edit", "line", "field"), [
    ("images.txt", lambda text: text.replace("0 0 1 a.png", "0 0 1.5 a.png"), 1, "CAMERA_ID 1.5"),  # image '.5'
    ("images.txt", lambda text: text.replace("2 1 0 0 0", "2.5 1 0 0 0"), 3, "IMAGE_ID 2.5"),  # image named '2'
    ("images.txt", lambda text: text.replace("0 0 1 b.png", "0 0 -1 b.png"), 3, "CAMERA_ID -1"),
    ("points3D.txt", lambda text: "7.5 0.5 0.5 2 255 0 0 0.1\n", 1, "POINT3D_ID 7.5"),  # x read as 0.5, y as 0.5...
    ("cameras.txt", lambda text: text.replace("1 PINHOLE", "1.5 PINHOLE"), 2, "CAMERA_ID 1.5"),
])
def test_a_colmap_text_id_that_is_not_a_whole_number_names_the_field_and_line(tmp_path, file, edit, line, field):
    """pycolmap read 1.5 as id 1 followed by a field ".5", and shifted the rest of the line: an image loaded as the
    photo named ".5", silently. A quoted pose line is cut before its CAMERA_ID, so the field is named."""
    path = write_colmap(tmp_path / "scene") / file
    path.write_text(edit(path.read_text()))
    error = load_error(tmp_path / "scene", tmp_path)
    limit = 2**64 - 2 if file == "points3D.txt" else 2**32 - 2
    assert error.what == f"cannot parse {file} line {line} ({field} is not an id, a whole number from 0 to {limit})"
    assert error.where == f"in {path}"


@pytest.mark.parametrize(("file", "edit", "line", "shown"), [
    # a 2D points line: its first fields are coordinates, not the IMAGE_ID and CAMERA_ID of a pose line
    ("images.txt", lambda text: text.replace("a.png\n\n", "a.png\n1.5 2.5 -1 3.5 4.5 -1 5.5 6.5 -1 7.5\n"), 2,
     "'1.5 2.5 -1 3.5 4.5 -1 5.5 6.5 -1 7.5'"),
    ("cameras.txt", lambda text: text.replace("1 PINHOLE", "x PINHOLE"), 2, "'x PINHOLE 8 6 5 5 4 3'"),  # no number
])
def test_a_colmap_line_that_is_bad_but_not_for_an_id_is_quoted(tmp_path, file, edit, line, shown):
    """Only a number where an id belongs is named by its field; any other bad line is quoted as it is."""
    path = write_colmap(tmp_path / "scene") / file
    path.write_text(edit(path.read_text()))
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what == f"cannot parse {file} line {line} ({shown})"


@pytest.mark.parametrize("track, points2d, what", [
    # an images.txt points line holds X Y POINT3D_ID triples: one point is three fields, not three points
    ("1", "1.5 2.5 -1", "point 1's track names 2D point 1 of image 1, which has 1 in images.txt"),
    # pycolmap refused it as "Check failed: point2D.point3D_id == point3D_id (8 vs. 1)", naming no file or line
    ("0", "1.5 2.5 8", "point 1's track names 2D point 0 of image 1, which images.txt gives to point 8"),
])
def test_a_colmap_track_naming_a_2d_point_it_cannot_have_names_the_point(tmp_path, track, points2d, what):
    sparse = write_colmap(tmp_path / "scene", points=f"1 0.5 0.5 2 255 0 0 0.1 1 {track}\n")
    images = sparse / "images.txt"
    images.write_text(images.read_text().replace("a.png\n\n", f"a.png\n{points2d}\n"))
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what == what
    assert error.where == f"in {sparse / 'points3D.txt'} line 1"


def _focal_for(degrees: float, side: int) -> float:
    """The focal length that sees `degrees` across `side` pixels."""
    return 0.5 * side / math.tan(math.radians(degrees) / 2)


@pytest.mark.parametrize(("fx", "fy", "refused"), [
    (36.0, 36.0, None),
    (36.0, _focal_for(179.5, 30), "wider than any camera's"),  # fl_y alone: a camera of no height in rays
    (_focal_for(179.1, 40), 36.0, "wider than any camera's"),
    (_focal_for(178.9, 40), 36.0, None),
    (36.0, 4.1e5, "longer than any camera's"),  # fl_y alone
    (3.9e5, 3.9e5, None),  # 1e4 times the larger side is 4e5 px, whatever the smaller one
])
def test_a_focal_length_is_judged_on_both_axes_against_the_larger_side(fx, fy, refused):
    K = np.array([[fx, 0.0, 20.0], [0.0, fy, 15.0], [0.0, 0.0, 1.0]])
    if refused is None:
        refuse_implausible_focal(K, 40, 30, "here", "fix it")
        return
    with pytest.raises(SplatuError) as caught:
        refuse_implausible_focal(K, 40, 30, "here", "fix it")
    assert refused in caught.value.what


@pytest.mark.parametrize(("cx", "cy", "zoom_x", "zoom_y", "usable"), [
    (20.0, 15.0, 1.0, 1.0, True),
    (20.0, 15.0, 10.0, 0.1, True),  # the limits themselves
    (-0.5, 15.0, 1.0, 1.0, False),  # the principal point off the image, either way
    (20.0, 30.5, 1.0, 1.0, False),
    (20.0, 15.0, 0.09, 0.09, False),  # the lens's focal length cut, or stretched, over ten times
    (20.0, 15.0, 1.0, 11.0, False),  # along y alone
])
def test_an_undistorted_camera_must_keep_its_principal_point_and_focal_length_near(monkeypatch, cx, cy, zoom_x,
                                                                                     zoom_y, usable):
    """OpenCV's optimal matrix is checked, not trusted: absurd coefficients gave one 2e-6 or 4e29 times the lens."""
    from splatu.data import images

    K = np.array([[36.0, 0.0, 20.0], [0.0, 36.0, 15.0], [0.0, 0.0, 1.0]])
    found = np.array([[36.0 * zoom_x, 0.0, cx - 0.5], [0.0, 36.0 * zoom_y, cy - 0.5], [0.0, 0.0, 1.0]])  # OpenCV's

    monkeypatch.setattr(images.cv2, "getOptimalNewCameraMatrix", lambda *args: (found, None))
    distortion = images.Distortion("OPENCV", (0.1, 0.0, 0.0, 0.0))
    if usable:
        np.testing.assert_allclose(images.undistorted_intrinsics(K, distortion, 40, 30, "here")[:2, :2],
                                   found[:2, :2])
        return
    with pytest.raises(SplatuError, match="has no usable undistorted camera"):
        images.undistorted_intrinsics(K, distortion, 40, 30, "here")


@pytest.mark.parametrize(("value", "message"), [
    (0.0, "camera_angle_x must be an angle in (0, pi) radians (got 0.0)"),
    (-0.5, "camera_angle_x must be an angle in (0, pi) radians (got -0.5)"),
    (math.pi, f"camera_angle_x must be an angle in (0, pi) radians (got {math.pi})"),
    (float("nan"), "intrinsic camera_angle_x must be a finite number within float32's range (got nan)"),
])
def test_an_instant_ngp_camera_angle_outside_0_to_pi_names_the_frame(tmp_path, value, message):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: [frame.update(fl_x=None, camera_angle_x=value) for frame in c["frames"]])
    error = load_error(root, tmp_path)
    assert error.what == message and error.where == f"in frame {cameras[0].name!r} of {root / 'transforms.json'}"


def test_a_missing_focal_length_names_camera_angle_x_too(tmp_path):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: [frame.pop("fl_x") for frame in c["frames"]])
    error = load_error(root, tmp_path)
    assert error.what == "missing intrinsics fl_x (or x_fov or camera_angle_x)"
    assert "x_fov in degrees or camera_angle_x in radians" in error.fix


@pytest.mark.parametrize(("intrinsics", "message"), [
    ({"fl_x": 1e-30, "fl_y": 1e-30}, "focal length 1e-30 x 1e-30 px for a 40x30 image gives a field of view of 180 x "
     "180 degrees, wider than any camera's (below 179)"),
    ({"fl_x": 0.04, "fl_y": 0.04}, "focal length 0.04 x 0.04 px for a 40x30 image gives a field of view of 179.8 x "
     "179.7 degrees, wider than any camera's (below 179)"),  # a focal length in mm
    ({"fl_x": 1e30, "fl_y": 1e30}, "focal length 1e+30 x 1e+30 px for a 40x30 image is over 10000 times the image's "
     "larger side (a field of view of 2.3e-27 x 1.7e-27 degrees), longer than any camera's"),
    ({"fl_x": None, "fl_y": None, "camera_angle_x": 1e-30}, "focal length 4e+31 x 4e+31 px for a 40x30 image is over "
     "10000 times the image's larger side (a field of view of 5.7e-29 x 4.3e-29 degrees), longer than any camera's"),
])
def test_a_nerfstudio_focal_length_no_camera_has_names_the_frame(tmp_path, intrinsics, message):
    """A pinhole camera with a ~180 or ~0 degree field of view trained silently into garbage."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: [frame.update(intrinsics) for frame in c["frames"]])
    error = load_error(root, tmp_path)
    assert error.what == message and error.where == f"in frame {cameras[0].name!r} of {root / 'transforms.json'}"


@pytest.mark.parametrize(("camera", "message"), [
    ("1 PINHOLE 8 6 1e-30 5 4 3", "focal length 1e-30 x 5 px for a 8x6 image gives a field of view of 180 x 61.93 "
     "degrees, wider than any camera's (below 179)"),
    ("1 SIMPLE_PINHOLE 8 6 1e30 4 3", "focal length 1e+30 x 1e+30 px for a 8x6 image is over 10000 times the image's "
     "larger side (a field of view of 4.6e-28 x 3.4e-28 degrees), longer than any camera's"),
])
def test_a_colmap_focal_length_no_camera_has_names_the_camera(tmp_path, camera, message):
    sparse = write_colmap(tmp_path / "scene", camera=camera)
    error = load_error(tmp_path / "scene", tmp_path)
    assert error.what == message and error.where == f"in {sparse / 'cameras.txt'} (camera 1)"


def test_a_nerf_synthetic_camera_angle_no_camera_has_is_refused(tmp_path):
    write_blender(tmp_path / "lego", ["./train/r_0", "./train/r_1"], ["./test/r_0"], angle=1e-30)
    error = load_error(tmp_path / "lego", tmp_path)
    assert "times the image's larger side" in error.what and "camera_angle_x" in error.fix
    assert error.where == f"in {tmp_path / 'lego' / 'transforms_train.json'}"


MISSPELT_CAMERA_KEYS = [("k_1", "k1"), ("K1", "k1"), ("k1 ", "k1"), ("p_2", "p2"), ("P-1", "p1"), (" k 4", "k4"),
                        ("camera-model", "camera_model"), ("cameraModel", "camera_model"),
                        ("Camera_Model", "camera_model"), ("fl-x", "fl_x"), ("flx", "fl_x"), ("FL_X", "fl_x"),
                        ("c_x", "cx"), ("W", "w"), ("Camera Angle Y", "camera_angle_y"), ("isFisheye", "is_fisheye")]
MISSPELT_TOP_KEYS = [("Frames", "frames"), ("Depth_Unit_Scale_Factor", "depth_unit_scale_factor"),
                     ("plyFilePath", "ply_file_path"), ("Train-Filenames", "train_filenames")]
MISSPELT_FRAME_KEYS = [("Transform_Matrix", "transform_matrix"), ("filePath", "file_path"), ("mask-path", "mask_path"),
                       ("depthFilePath", "depth_file_path"), ("Observed_Mask_Path", "observed_mask_path")]
KEY_VALUES = {"camera_model": "PINHOLE", "is_fisheye": True, "camera_angle_y": 0.9, "fl_x": 30.0, "cx": 19.0, "w": 40,
              "depth_unit_scale_factor": 1e-3, "ply_file_path": "points.ply", "train_filenames": [],
              "mask_path": "masks/a.png", "depth_file_path": "depth/a.png", "observed_mask_path": "observed/a.png"}
"""A value for each misspelt key whose right spelling the scene does not have in that place already."""


def misspell(entries: dict, key: str, right: str) -> None:
    """Rename `right` to `key` where it is given, else add `key` with a plausible value."""
    entries[key] = entries.pop(right) if right in entries else KEY_VALUES.get(right, 0.05)


@pytest.mark.parametrize(("key", "right", "place"), [*[(*keys, place) for keys in MISSPELT_CAMERA_KEYS
                                                      for place in ("top", "frame")],
                                                     *[(*keys, "top") for keys in MISSPELT_TOP_KEYS],
                                                     *[(*keys, "frame") for keys in MISSPELT_FRAME_KEYS]])
def test_a_misspelt_key_names_the_key_the_file_the_frame_and_the_spelling(tmp_path, key, right, place):
    """nerfstudio, instant-ngp and the loader read only the exact names: a Camera_Model left the model at OPENCV,
    an fl-x or c_x in a frame let the file's value or the image centre stand, and a k_1 left the images
    undistorted without it, all without a word; a misspelt file_path or transform_matrix said it was missing."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: misspell(c if place == "top" else c["frames"][2], key, right))
    error = load_error(root, tmp_path)
    json_path = root / "transforms.json"
    frame = f"frames[2] of {json_path}" if right == "file_path" else f"frame {cameras[2].name!r} of {json_path}"
    assert (error.what, error.where, error.fix) == (
        f"key {key!r} is not spelt as the key {right!r}, so it would be ignored",
        f"in {json_path}" if place == "top" else f"in {frame}", f"rename it {right!r}")


def test_a_misspelt_key_in_a_cameras_file_is_refused_too(tmp_path):
    """render-uncertainty --cameras FILE reads the same keys."""
    write_nerfstudio_scene(tmp_path, n=3)
    edit_transforms(tmp_path, lambda c: c["frames"][1].update(CX=c["frames"][1].pop("cx")))
    with pytest.raises(SplatuError, match="key 'CX' is not spelt as the key 'cx'"):
        read_cameras(tmp_path / "transforms.json")


@pytest.mark.parametrize("content", ["# Image list with two lines of data per image:\n1 1 0 0 0 0 0 0 1 a.png\n\n",
                                     '[{"transform_matrix": [[1, 0, 0, 0]]}]'])
def test_a_cameras_file_of_another_kind_says_what_cameras_takes(tmp_path, content):
    """A COLMAP images.txt (or a bare list of frames) passed as --cameras was told only "fix or regenerate the file",
    as if it were a broken transforms.json; the fix now says what the file must hold."""
    path = tmp_path / "images.txt"
    path.write_text(content)
    with pytest.raises(SplatuError) as raised:
        read_cameras(path)
    assert raised.value.where == f"in {path}"
    assert raised.value.fix.startswith('pass a nerfstudio-style transforms.json: "frames" with a camera-to-world')


def test_a_second_spelling_with_the_same_value_passes_and_with_another_is_refused(tmp_path):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: [frame.update(W=frame["w"]) for frame in c["frames"]])
    load_scene(DataConfig(data=str(root), cache_dir=tmp_path / "cache"))
    edit_transforms(root, lambda c: c["frames"][0].update(W=c["frames"][0]["w"] + 1))
    assert load_error(root, tmp_path).what == "key 'W' is not spelt as the key 'w', so it would be ignored"


def test_a_misspelt_key_in_a_nerf_synthetic_frame_is_named(tmp_path):
    """The frame said it had no transform_matrix, without naming the key it had."""
    write_blender(tmp_path / "lego", ["./train/r_0", "./train/r_1"], ["./test/r_0"])
    path = tmp_path / "lego" / "transforms_test.json"
    content = json.loads(path.read_text())
    content["frames"][0]["transformMatrix"] = content["frames"][0].pop("transform_matrix")
    path.write_text(json.dumps(content))
    error = load_error(tmp_path / "lego", tmp_path)
    assert error.what == "key 'transformMatrix' is not spelt as the key 'transform_matrix', so it would be ignored"
    assert error.where == f"in frame 'test/r_0' of {path}"


@pytest.mark.parametrize(("model", "key", "uses", "belongs"), [
    ("PINHOLE", "k1", "no distortion coefficients", "OPENCV or OPENCV_FISHEYE"),
    ("SIMPLE_PINHOLE", "p2", "no distortion coefficients", "OPENCV"),
    ("OPENCV", "k4", "k1, k2, p1, p2, k3", "OPENCV_FISHEYE"),
    ("SIMPLE_RADIAL", "k4", "k1, k2, p1, p2, k3", "OPENCV_FISHEYE"),
    ("OPENCV_FISHEYE", "p1", "k1, k2, k3, k4", "OPENCV"),
])
def test_a_distortion_coefficient_the_camera_model_does_not_use_is_refused_not_dropped(tmp_path, model, key, uses,
                                                                                        belongs):
    """nerfstudio's OPENCV uses k1, k2, p1, p2 (and OpenCV's k3), OPENCV_FISHEYE k1-k4, a pinhole none: the
    loader dropped the others, and trained on images undistorted by another lens than the file's."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, camera_model=model)
    edit_transforms(root, lambda c: c.update({key: 0.02}))
    error = load_error(root, tmp_path)
    assert error.what == f"the file's {key} = 0.02 would be ignored: camera_model {model} uses {uses}"
    assert error.where == f"in frame {sorted(c.name for c in cameras)[0]!r} of {root / 'transforms.json'}"
    assert error.fix == (f"set camera_model to the lens model {key} belongs to ({belongs}), or remove {key} if the "
                         "images are already undistorted")


def test_a_frame_s_own_unused_coefficient_is_named_as_the_frame_s(tmp_path):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: c["frames"][1].update(camera_model="OPENCV_FISHEYE", p2=0.01))
    assert load_error(root, tmp_path).what.startswith("the frame's p2 = 0.01 would be ignored: camera_model "
                                                      "OPENCV_FISHEYE uses k1, k2, k3, k4")


FISHEYE_FIX = ("give camera_model OPENCV_FISHEYE with is_fisheye true for a fisheye lens (k1 to k4 of OpenCV's "
               "fisheye model), or another camera_model with is_fisheye false or none")


@pytest.mark.parametrize(("top", "frame", "what"), [
    ({"camera_model": "OPENCV", "is_fisheye": True}, {}, "is_fisheye true contradicts camera_model OPENCV"),
    ({"camera_model": "SIMPLE_RADIAL", "is_fisheye": True}, {},
     "is_fisheye true contradicts camera_model SIMPLE_RADIAL"),
    ({"camera_model": "OPENCV_FISHEYE", "is_fisheye": False}, {},
     "is_fisheye false contradicts camera_model OPENCV_FISHEYE"),
    ({"camera_model": "OPENCV"}, {"is_fisheye": True}, "is_fisheye true contradicts camera_model OPENCV"),
])
def test_an_is_fisheye_the_camera_model_contradicts_is_refused(tmp_path, top, frame, what):
    """instant-ngp reads the coefficients by is_fisheye, nerfstudio by camera_model: the two would undistort the
    images differently, and the loader followed camera_model without a word."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, k1=0.02, **top)
    edit_transforms(root, lambda c: c["frames"][2].update(frame))
    error = load_error(root, tmp_path)
    name = sorted(c.name for c in cameras)[2 if frame else 0]
    assert (error.what, error.where, error.fix) == (what, f"in frame {name!r} of {root / 'transforms.json'}",
                                                    FISHEYE_FIX)


@pytest.mark.parametrize("flag", ["true", 1, [True]])
def test_an_is_fisheye_that_is_not_true_or_false_is_refused(tmp_path, flag):
    """instant-ngp fails on any is_fisheye but a boolean, and Python would take a quoted "false" for true."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4)
    edit_transforms(root, lambda c: c.update(is_fisheye=flag))
    error = load_error(root, tmp_path)
    assert (error.what, error.fix) == (f"is_fisheye must be true or false (got {flag!r})",
                                       "write is_fisheye as true or false, without quotes")


def test_a_coefficient_the_fisheye_model_of_is_fisheye_does_not_use_names_is_fisheye(tmp_path):
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4, is_fisheye=True, k1=0.02, p1=0.01)
    edit_transforms(root, lambda c: c.pop("camera_model"))
    assert load_error(root, tmp_path).what == ("the file's p1 = 0.01 would be ignored: is_fisheye true "
                                               "(OPENCV_FISHEYE) uses k1, k2, k3, k4")


@pytest.mark.parametrize(("key", "place"), [("k5", "file"), ("k6", "frame")])
def test_a_rational_model_coefficient_is_refused_not_dropped(tmp_path, key, place):
    """OpenCV's rational model (COLMAP FULL_OPENCV) adds k5 and k6, which no transforms.json model reads: they were
    dropped without a word, and the images undistorted without them. A zero one changes nothing and loads."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4, k1=0.01, k5=0.0, k6=0.0)
    assert len(read_scene_files(root, (1.0, 1.0, 1.0)).frames) == 4
    edit_transforms(root, lambda c: (c if place == "file" else c["frames"][0]).update({key: 0.02}))
    error = load_error(root, tmp_path)
    assert (error.what, error.fix) == (
        f"the {place}'s {key} = 0.02 belongs to OpenCV's rational lens model (COLMAP FULL_OPENCV), which splatu does "
        "not model", "undistort the images first (colmap image_undistorter does) and give the pinhole camera they "
        f"were undistorted to, or remove {key} if the images are already undistorted")
    with pytest.raises(SplatuError, match=f"{key} = 0.02 belongs to OpenCV's rational lens model"):
        read_cameras(root)


def swap(frame: dict, first: str, second: str) -> None:
    frame[first], frame[second] = frame[second], frame[first]


@pytest.mark.parametrize(("edit", "what", "fix"), [
    (lambda f: swap(f, "w", "h"),
     "principal point (32.3, 17.8) is 40% of the width off the centre of the 36x64 image, but at the centre of a "
     "64x36 one", "swap w and h, or cx and cy, whichever pair is the wrong way round"),
    (lambda f: swap(f, "cx", "cy"),
     "principal point (17.8, 32.3) is 40% of the height off the centre of the 64x36 image, but at the centre of a "
     "36x64 one", "swap w and h, or cx and cy, whichever pair is the wrong way round"),
    (lambda f: f.update(fl_x=f["fl_x"] / 2, fl_y=f["fl_y"] / 2, cx=f["cx"] / 2, cy=f["cy"] / 2),  # a K at 1/2 size
     "principal point (16.15, 8.9) is at 25% x 25% of the 64x36 image, as for a K made for an image 0.5 times this "
     "size", "give fl_x, fl_y, cx and cy in pixels of this w x h image (scaled by w / the width they were made for)"),
    (lambda f: f.update(cx=f["cx"] * 3),
     "principal point (96.9, 17.8) lies outside the 64x36 image",
     "give fl_x, fl_y, cx and cy in pixels of this w x h image (scaled by w / the width they were made for)"),
])
def test_a_transforms_json_k_that_does_not_fit_its_size_is_one_warning_line_and_refused_as_a_candidate(
        tmp_path, capsys, edit, what, fix):
    """A size and K that do not belong together trained (or, from a --cameras file, rendered) a shifted, zoomed
    view without a word. A training scene's images are there, and a tile of a larger photo has such a K, so loading
    it says so in one line for the whole file and goes on; a --cameras file has no image to tell, so it is refused."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=64, height=36)
    edit_transforms(root, lambda c: [edit(frame) for frame in c["frames"]])
    first = sorted(c.name for c in cameras)[0]
    assert len(read_scene_files(root, (1.0, 1.0, 1.0)).frames) == 4
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith(
        f"warning: 4 of 4 frames in {root / 'transforms.json'} have a principal point far from the image's centre "
        f"(frame {first!r}: {what}); the cameras are used as given")
    assert err.rstrip().endswith(f"if the camera is wrong, {fix}")
    with pytest.raises(SplatuError) as caught:
        read_cameras(root)
    assert caught.value.what == what and caught.value.fix.startswith(fix)
    assert caught.value.where == f"in frame {first!r} of {root / 'transforms.json'}"


@pytest.mark.parametrize(("camera", "what", "fix"), [
    ("1 PINHOLE 64 36 50 50 18 32", "principal point (18, 32) is 39% of the height off the centre of the 64x36 image, "
     "but at the centre of a 36x64 one", "swap the camera's WIDTH and HEIGHT, or its cx and cy, whichever pair is "
     "the wrong way round"),
    ("1 SIMPLE_PINHOLE 64 36 25 16 9", "principal point (16, 9) is at 25% x 25% of the 64x36 image, as for a K made "
     "for an image 0.5 times this size", "give the camera's parameters in pixels of its WIDTH x HEIGHT, or re-run the "
     "reconstruction"),
    ("1 PINHOLE 64 36 50 50 70 18", "principal point (70, 18) lies outside the 64x36 image",
     "give the camera's parameters in pixels of its WIDTH x HEIGHT, or re-run the reconstruction"),
])
def test_a_colmap_camera_whose_k_does_not_fit_its_size_is_one_warning_line(tmp_path, capsys, camera, what, fix):
    """As for a transforms.json: counted by camera, the first named, and the model loads."""
    write_colmap(tmp_path / "scene", camera=camera)
    assert len(read_scene_files(tmp_path / "scene", (1.0, 1.0, 1.0)).frames) == 2
    out, err = capsys.readouterr()
    cameras_file = tmp_path / "scene" / "sparse" / "0" / "cameras.txt"
    assert out == "" and err == (f"warning: 1 of 1 cameras in {cameras_file} has a principal point far from the "
                                 f"image's centre (camera 1: {what}); the cameras are used as given, "
                                 "which is right for tiles or crops cut from a larger photo, but if the camera is "
                                 f"wrong, {fix}\n")


def _off_centre_nerfstudio(root: Path) -> None:
    write_nerfstudio_scene(root, n=4, width=64, height=36)
    edit_transforms(root, lambda c: [f.update(cx=f["cx"] * 3) for f in c["frames"]])


@pytest.mark.parametrize("write", [_off_centre_nerfstudio,
                                   lambda root: write_colmap(root, camera="1 PINHOLE 64 36 50 50 70 18")])
def test_querying_a_scene_s_cameras_in_a_loop_prints_nothing(tmp_path, capfd, write):
    """`RunQuery.scene_cameras` and `training_cameras` read the scene's files through the loaders, which printed
    their principal-point warning on every call: a planner asking in a loop filled stderr with it. The run warned
    as it trained; the query reads quietly (and loading the scene to train still warns, once)."""
    from splatu.query import scene_cameras
    from splatu.world_frame import WorldTransform

    write(tmp_path / "scene")
    raw = read_scene_files(tmp_path / "scene", (1.0, 1.0, 1.0))
    out, err = capfd.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("warning: ")
    frame = WorldTransform.from_normalization(*scene_normalization(raw))
    config = DataConfig(data=str(tmp_path / "scene"), eval_split="every-n", eval_every=2)
    for _ in range(3):
        assert len(scene_cameras(config, frame)) == len(raw.frames)
        assert 0 < len(scene_cameras(config, frame, training_only=True)) < len(raw.frames)
    assert capfd.readouterr() == ("", "")


def test_an_image_of_the_camera_s_size_turned_on_its_side_says_to_swap_width_and_height(tmp_path):
    """A 4:3 swap moves the principal point too little to refuse from a training scene's file alone; the image's
    size shows it."""
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=40, height=30)
    write_rgb(root / cameras[3].name, noise_image(3, 30, 40))
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert error.what == "image is 30x40 but its camera says 40x30" and error.where.endswith(cameras[3].name)
    assert error.fix == ("swap the camera's width and height (and its cx and cy if they are swapped too), or, if the "
                         "photo is stored on its side (an EXIF orientation, which is not applied), save it upright")


@pytest.mark.parametrize(("key", "name", "noun"), [("mask_path", "mask.png", "mask"),
                                                   ("depth_file_path", "depth.npy", "depth map")])
def test_a_mask_or_depth_map_turned_on_its_side_says_to_turn_it_not_to_swap_the_camera(tmp_path, key, name, noun):
    """Each frame's image is decoded and checked before its mask and depth map, so one of those turned on its side is
    the file's fault: swapping the camera's width and height, as a turned image suggests, would refuse the image."""
    root = tmp_path / "scene"
    write_nerfstudio_scene(root, n=4, width=40, height=30)
    if noun == "mask":
        cv2.imwrite(str(root / name), np.full((40, 30), 255, np.uint8))
    else:
        np.save(root / name, np.ones((40, 30), np.float32))
    edit_transforms(root, lambda c: c["frames"][1].update({key: name}))
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert error.what == f"{noun} is 30x40 but its camera says 40x30" and error.where.endswith(name)
    assert error.fix == f"turn the {noun} a quarter turn, to lie as its image does (whose size is the camera's)"


@pytest.mark.parametrize(("edit", "what"), [
    (lambda c: c.update(K1=0.05), "key 'K1' is not spelt as the key 'k1', so it would be ignored"),
    (lambda c: c.update(camera_model="PINHOLE", k1=0.05),
     "the file's k1 = 0.05 would be ignored: camera_model PINHOLE uses no distortion coefficients"),
    (lambda c: c.update(w=80, h=48), "principal point (24, 40) is 33% of the height off the centre of the 80x48 "
     "image, but at the centre of a 48x80 one"),
    (lambda c: c.update(w=96, h=160), "principal point (24, 40) is at 25% x 25% of the 96x160 image, as for a K made "
     "for an image 0.5 times this size"),
    (lambda c: c.update(w=24, h=40), "principal point (24, 40) lies on the edge of the 24x40 image, as for a K made "
     "for an image 2 times this size"),  # a 2x2 grid's top-left tile: refused as its three neighbours are
    (lambda c: c.update(cx=0.0, cy=0.0, w=24, h=40), "principal point (0, 0) lies on the edge of the 24x40 image"),
    # a 60x80 camera's K with w and h swapped: 4:3 moves the point too little for a training scene to flag it
    (lambda c: c.update(cx=30.0, cy=40.0, w=80, h=60), "principal point (30, 40) is 17% of the height off the centre "
     "of the 80x60 image, but at the centre of a 60x80 one"),
    (lambda c: c.update(k5=0.01), "the file's k5 = 0.01 belongs to OpenCV's rational lens model (COLMAP FULL_OPENCV), "
     "which splatu does not model"),
    # named as the frame's alone, a model the file gives was looked for in that frame, which has none
    (lambda c: c.update(camera_model="OPENCV_FISHEY"), "unknown camera model 'OPENCV_FISHEY' (the file's "
     "camera_model)"),
    (lambda c: c["frames"][0].update(camera_model="FISHEYE"), "unknown camera model 'FISHEYE' (the frame's "
     "camera_model)"),
])
def test_a_render_uncertainty_camera_file_s_bad_camera_names_the_file(tmp_path, edit, what):
    """--views cameras reads its --cameras file as the loader reads a scene's, no image needed: a candidate's K for
    another size or orientation, or a coefficient it would drop, is one line naming the file."""
    from splatu.data.nerfstudio import read_cameras

    content = {"w": 48, "h": 80, "fl_x": 40.0, "cx": 24.0, "cy": 40.0,
               "frames": [{"file_path": "a", "transform_matrix": np.eye(4).tolist()}]}
    edit(content)
    (tmp_path / "transforms.json").write_text(json.dumps(content))
    with pytest.raises(SplatuError) as caught:
        read_cameras(tmp_path)
    assert caught.value.what == what and str(tmp_path / "transforms.json") in caught.value.where


def test_a_candidate_tile_camera_is_told_how_to_render_it(tmp_path):
    """A tile's camera cannot be told from a K of another size without its image: the refusal names the flag that
    renders it (the fix said only to cut it out of the whole photo's render, and a tile scene's own cameras, which
    trained, had no way through --cameras), and with it the tile reads as given."""
    (tmp_path / "transforms.json").write_text(json.dumps({
        "w": 24, "h": 40, "fl_x": 40.0, "cx": 0.0, "cy": 40.0,
        "frames": [{"file_path": "a", "transform_matrix": np.eye(4).tolist()}]}))
    with pytest.raises(SplatuError) as caught:
        read_cameras(tmp_path)
    assert caught.value.fix == ("give fl_x, fl_y, cx and cy in pixels of this w x h image (scaled by w / the width "
                                "they were made for); for tiles or crops of a larger photo (a tile scene's own "
                                "cameras too), pass --off-centre-ok")
    (camera,) = read_cameras(tmp_path, off_centre_ok=True)
    assert (camera.width, camera.height) == (24, 40) and camera.K[:2, 2].tolist() == [0.0, 40.0]


def test_a_pose_being_optimised_names_its_nearest_training_view_as_render_takes_it():
    """A planner refining a candidate pose by gradient passes a tensor that requires grad: `RunQuery.render` took it
    (it runs without gradients), while `nearest_training_view` raised torch's RuntimeError with a traceback; and any
    tensor went through torch's `__array__`, which numpy 2 warns is deprecated (a CUDA one, which numpy cannot read,
    was "not a 3x4 or 4x4 matrix")."""
    import warnings

    from splatu.query import SceneCamera, nearest_training_view

    K = np.array([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]])
    moved = np.eye(4)  # looking along +x rather than +z
    moved[:3, :3] = [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
    training = {"a.png": SceneCamera(np.eye(4), K, 64, 48), "b.png": SceneCamera(moved, K, 64, 48)}
    for pose in (torch.tensor(moved, requires_grad=True), torch.tensor(moved, dtype=torch.float32)):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            name, angle, distance = nearest_training_view(pose, training)
        assert name == "b.png" and angle == pytest.approx(0.0, abs=1e-3) and distance == pytest.approx(0.0, abs=1e-6)


def test_an_image_size_given_as_an_integer_tensor_is_taken_and_a_fractional_one_refused():
    """A nerfstudio `Cameras`' width and height are integer tensors: they were refused as not positive integers (a
    0-d one printed as its value, "got 48×80"). An integral float tensor is a size too; a fraction or a bool is not."""
    from splatu.query import _checked_camera

    K = np.array([[40.0, 0.0, 24.0], [0.0, 40.0, 40.0], [0.0, 0.0, 1.0]])
    for given in ((torch.tensor([48]), torch.tensor(80)), (torch.tensor(48.0), torch.tensor([80.0])),
                  (np.array(48.0), np.array([80])), (np.float32(48.0), np.int64(80))):
        *_, width, height = _checked_camera(np.eye(4), K, *given, False)
        assert (width, height) == (48, 80) and type(width) is int and type(height) is int
    for size, shown in (((torch.tensor(48.5), 80), "width 48.5 is not a whole number"),
                        ((torch.tensor(True), 80), "width is a bool (True)"),
                        ((np.bool_(True), 80), "width is a bool (True)"),
                        ((torch.tensor([True, False]), 80), "width is an array of shape (2,), not a number"),
                        ((np.array([48, 80]), 80), "width is an array of shape (2,), not a number")):
        with pytest.raises(SplatuError, match=re.escape(shown)):
            _checked_camera(np.eye(4), K, *size, False)


def test_the_memory_a_render_may_use_is_the_tightest_cgroup_limit_on_the_process_path(tmp_path, monkeypatch):
    """A container's limit, not the host's memory, is where the kernel kills a render: the limit of the process's
    cgroup or any ancestor counts (v1 and v2), and "max" or v1's ~2⁶³ mean none."""
    from splatu.data import frames

    proc = tmp_path / "cgroup"
    v1 = tmp_path / "v1"
    (v1 / "memory" / "docker" / "abc").mkdir(parents=True)
    (v1 / "memory" / "memory.limit_in_bytes").write_text("9223372036854771712\n")
    (v1 / "memory" / "docker" / "memory.limit_in_bytes").write_text(f"{6 * 2**30}\n")
    (v1 / "memory" / "docker" / "abc" / "memory.limit_in_bytes").write_text(f"{8 * 2**30}\n")
    proc.write_text("12:cpu,cpuacct:/docker/abc\n4:memory:/docker/abc\n0::/\n")
    assert frames.cgroup_memory_limit(proc, v1) == 6 * 2**30
    (v1 / "memory" / "docker" / "memory.limit_in_bytes").write_text("9223372036854771712\n")
    assert frames.cgroup_memory_limit(proc, v1) == 8 * 2**30

    v2 = tmp_path / "v2"
    (v2 / "user.slice" / "app").mkdir(parents=True)
    (v2 / "cgroup.controllers").write_text("memory\n")
    (v2 / "user.slice" / "memory.max").write_text("max\n")
    (v2 / "user.slice" / "app" / "memory.max").write_text(f"{3 * 2**30}\n")
    proc.write_text("0::/user.slice/app\n")
    assert frames.cgroup_memory_limit(proc, v2) == 3 * 2**30
    (v2 / "user.slice" / "app" / "memory.max").write_text("max\n")
    assert frames.cgroup_memory_limit(proc, v2) is None
    assert frames.cgroup_memory_limit(tmp_path / "absent", v2) is None

    monkeypatch.setattr(frames, "physical_memory", lambda: 64 * 2**30)
    monkeypatch.setattr(frames, "cgroup_memory_limit", lambda: 8 * 2**30)
    with pytest.raises(SplatuError, match=re.escape("more than the 8.6 GB of memory this process may use")):
        frames.refuse_unaffordable_render([(7680, 4320)], 1, "in cams.json", "give smaller w and h")  # ~9.0 GB
    monkeypatch.setattr(frames, "cgroup_memory_limit", lambda: None)
    frames.refuse_unaffordable_render([(7680, 4320)], 1, "in cams.json", "give smaller w and h")


def test_a_render_is_refused_by_its_memory_estimate_with_members_and_kept_views_counted(monkeypatch):
    """The estimate grows with the largest view's pixels, with each ensemble member, and with what render-uncertainty
    keeps of every other view; a machine that does not say its memory refuses nothing."""
    from splatu.data import frames

    gigabyte = 10**9
    monkeypatch.setattr(frames, "usable_memory", lambda: 4 * gigabyte)
    fits = [(3840, 2160)]  # 1 GiB + 240 B × 8.3 Mpx ≈ 3.1 GB
    frames.refuse_unaffordable_render(fits, 1, "in cams.json", "give smaller w and h")
    with pytest.raises(SplatuError, match=re.escape("a 3840×2160 render needs about 6.0 GB (~590 bytes per pixel)")):
        frames.refuse_unaffordable_render(fits, 15, "in cams.json", "give smaller w and h")  # 14 more members
    with pytest.raises(SplatuError, match=re.escape("(and 4 more views kept until written) needs about 4.7 GB")):
        frames.refuse_unaffordable_render(fits * 5, 1, "in cams.json", "give smaller w and h")
    monkeypatch.setattr(frames, "usable_memory", lambda: None)
    frames.refuse_unaffordable_render([(65536, 65536)], 1, "in cams.json", "give smaller w and h")
