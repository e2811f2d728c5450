"""Every kind of bad scene input fails with one SplatuError line: what, which file, how to fix."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from splatu.cli import entrypoint
from splatu.data.config import DataConfig
from splatu.data.resolve import load_scene
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
    (tmp_path / "photos").mkdir()
    write_rgb(tmp_path / "photos" / "a.png", noise_image(0, 8, 6))
    error = load_error(tmp_path / "photos", tmp_path)
    assert "unknown scene format" in error.what and "photos" in error.where


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


def test_unknown_colmap_camera_model(tmp_path):
    sparse = tmp_path / "scene" / "sparse" / "0"
    sparse.mkdir(parents=True)
    (sparse / "cameras.txt").write_text("1 FULL_OPENCV 8 6 5 5 4 3 0.1 0 0 0 0 0 0 0\n")
    (sparse / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.png\n\n2 1 0 0 0 1 0 0 1 b.png\n\n")
    (sparse / "points3D.txt").write_text("")
    error = load_error(tmp_path / "scene", tmp_path)
    assert "FULL_OPENCV" in error.what and "cameras.txt" in error.where


def test_image_size_that_disagrees_with_the_intrinsics(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=40, height=30)
    write_rgb(root / cameras[3].name, noise_image(3, 36, 30))
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert "36x30" in error.what and error.where.endswith(cameras[3].name)


def test_mismatched_image_sizes_within_a_split(tmp_path):
    root = tmp_path / "scene"
    cameras = write_nerfstudio_scene(root, n=4, width=40, height=30)
    write_rgb(root / cameras[3].name, noise_image(3, 20, 30))

    def shrink_last_frame(content):
        last = next(f for f in content["frames"] if f["file_path"] == cameras[3].name)
        last.update(w=20, cx=10.0)

    edit_transforms(root, shrink_last_frame)
    error = load_error(root, tmp_path, eval_split="every-n", eval_every=2)
    assert "differs" in error.what and error.where.endswith(cameras[3].name)


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


def test_cli_prints_one_line_and_exits_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as caught:
        entrypoint(["process-images", str(tmp_path / "nowhere")])
    assert caught.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("error: photo folder not found") and "nowhere" in err
