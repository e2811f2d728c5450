"""Scenes whose images differ in size (nerfstudio's per-frame w, h; a COLMAP model with several cameras): every view
loads, trains, is scored and renders at its own camera's size, while views of one size stay stacked."""

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from splatu import train_command
from splatu.camera import Camera
from splatu.cli import entrypoint
from splatu.data.config import DataConfig
from splatu.data.resolve import load_scene
from splatu.data.scene import ViewList
from splatu.degree_choice import DegreeChoiceConfig
from splatu.model import ModelConfig
from splatu.train_progress import scene_line
from splatu.training_step import TrainImages
from tests.synthetic_scenes import noise_image, ring_cameras, write_nerfstudio_scene, write_rgb, write_transforms
from tests.unit.test_loaders import _quaternion
from tests.unit.test_trainer import tiny_config

SIZES = ((40, 30), (30, 40), (20, 15))
"""(w, h): landscape, portrait, and a plain half-resolution camera, in turn frame by frame."""
MASKED_ROWS = 2


def write_mixed_scene(root: Path, n: int = 12) -> list[Camera]:
    """A nerfstudio scene of `n` frames cycling through SIZES (per-frame w, h), each with a depth map and an observed
    mask, every 4th from frame 1 with a mask file hiding its top MASKED_ROWS rows; its own split lists hold the last
    3 frames out, one of each size."""
    rings = {size: ring_cameras(n, *size) for size in SIZES}
    cameras = [rings[SIZES[i % len(SIZES)]][i] for i in range(n)]
    extras = []
    for i, camera in enumerate(cameras):
        shape = (camera.height, camera.width)
        write_rgb(root / camera.name, noise_image(i, camera.width, camera.height))
        np.save(root / f"depth_{i}.npy", np.full(shape, 2.0 + i, np.float32))
        observed = np.zeros(shape, np.uint8)
        observed[:, : camera.width // 2] = 255
        cv2.imwrite(str(root / f"observed_{i}.png"), observed)
        extra = {"depth_file_path": f"depth_{i}.npy", "observed_mask_path": f"observed_{i}.png"}
        if i % 4 == 1:
            mask = np.full(shape, 255, np.uint8)
            mask[:MASKED_ROWS] = 0
            cv2.imwrite(str(root / f"mask_{i}.png"), mask)
            extra["mask_path"] = f"mask_{i}.png"
        extras.append(extra)
    names = [c.name for c in cameras]
    write_transforms(root / "transforms.json", cameras, names, frame_extras=extras,
                     top_extras={"train_filenames": names[: n - 3], "val_filenames": names[n - 3:]})
    return cameras


def test_each_view_of_a_split_of_mixed_sizes_loads_at_its_own_size_and_one_size_stays_stacked(tmp_path):
    write_mixed_scene(tmp_path / "scene")
    scene = load_scene(DataConfig(data=str(tmp_path / "scene"), cache_dir=tmp_path / "cache"))
    assert "9 training and 3 eval views at 40x30, 30x40 and 20x15," in scene_line(scene)
    for views, first in ((scene.train, 0), (scene.eval, 9)):
        assert isinstance(views.images, ViewList) and len(views.images) == len(views)
        for i, camera in enumerate(views.cameras):
            frame = first + i
            assert (camera.width, camera.height) == SIZES[frame % 3]
            shape = (camera.height, camera.width)
            expected = torch.from_numpy(noise_image(frame, camera.width, camera.height)).float() / 255
            assert torch.allclose(views.target(i, torch.zeros(3)), expected, atol=1e-6)
            for per_view in (views.mask_files, views.object_masks, views.depths, views.observed):
                assert per_view[i].shape == shape
            assert float(views.depths[i][0, 0]) == pytest.approx((2.0 + frame) * scene.scale)
            kept = camera.width * (camera.height - MASKED_ROWS) if frame % 4 == 1 else camera.width * camera.height
            assert float(views.mask_files[i].sum()) == kept
    landscape = scene.train.subset([0, 3, 6])  # one size again: stacked, every per-view tensor alike
    assert isinstance(landscape.images, torch.Tensor) and landscape.images.shape == (3, 30, 40, 3)
    assert landscape.depths.shape == landscape.observed.shape == landscape.mask_files.shape == (3, 30, 40)
    mixed = scene.train.subset([2, 1])
    assert [tuple(t.shape) for t in mixed.images] == [(15, 20, 3), (40, 30, 3)]
    assert [tuple(t.shape) for t in mixed.mask_files] == [(15, 20), (40, 30)]

    write_nerfstudio_scene(tmp_path / "uniform", n=6)
    uniform = load_scene(DataConfig(data=str(tmp_path / "uniform"), cache_dir=tmp_path / "cache"))
    assert isinstance(uniform.train.images, torch.Tensor) and uniform.train.images.shape[1:] == (30, 40, 3)


def test_a_colmap_model_with_two_cameras_of_different_sizes_loads_each_image_at_its_cameras_size(tmp_path):
    root = tmp_path / "scene"
    sparse = root / "sparse" / "0"
    sparse.mkdir(parents=True)
    sizes = {1: (40, 30), 2: (20, 15)}
    (sparse / "cameras.txt").write_text("".join(f"{cid} PINHOLE {w} {h} {0.9 * w} {0.9 * w} {w / 2} {h / 2}\n"
                                                for cid, (w, h) in sizes.items()))
    lines = []
    for i, camera in enumerate(ring_cameras(6, 40, 30)):
        cid = 1 + i % 2
        qw, qx, qy, qz = _quaternion(camera.world_to_camera[:3, :3].numpy())
        t = camera.world_to_camera[:3, 3].numpy()
        lines += [f"{i + 1} {qw} {qx} {qy} {qz} {t[0]} {t[1]} {t[2]} {cid} img_{i}.png", ""]
        write_rgb(root / "images" / f"img_{i}.png", noise_image(i, *sizes[cid]))
    (sparse / "images.txt").write_text("\n".join(lines) + "\n")
    (sparse / "points3D.txt").write_text("1 10.0 -3.0 2.0 255 0 128 0.5\n2 10.5 -3.0 2.5 0 255 0 0.5\n")

    scene = load_scene(DataConfig(data=str(root), cache_dir=tmp_path / "cache", eval_split="every-n", eval_every=3))
    seen = set()
    for views in (scene.train, scene.eval):
        assert isinstance(views.images, ViewList)
        for i, (camera, name) in enumerate(zip(views.cameras, views.names, strict=True)):
            frame = int(Path(name).stem.removeprefix("img_"))
            width, height = sizes[1 + frame % 2]
            assert (camera.width, camera.height) == (width, height)
            assert float(camera.K[0, 0]) == pytest.approx(0.9 * width)
            expected = torch.from_numpy(noise_image(frame, width, height)).float() / 255
            assert torch.allclose(views.images[i], expected, atol=1e-6)
            seen.add(frame)
    assert seen == set(range(6))


def test_training_images_of_mixed_sizes_downsample_each_view_as_a_split_of_its_size_alone(tmp_path):
    write_mixed_scene(tmp_path / "scene")
    train = load_scene(DataConfig(data=str(tmp_path / "scene"), cache_dir=tmp_path / "cache")).train
    images, background = TrainImages(train), torch.tensor([0.2, 0.5, 0.9])
    sizes = set()
    for i in range(len(train)):
        alone = TrainImages(train.subset([i]))  # stacked: the path a scene of one size takes
        for level in (0, 1):
            camera, target = images.get(i, level, background)
            assert target.shape == (camera.height, camera.width, 3)
            sizes.add((level, camera.width, camera.height))
            assert torch.equal(target, alone.get(0, level, background)[1])
            assert torch.equal(images.weight(i, level), alone.weight(0, level))
    assert sizes == {(0, 40, 30), (0, 30, 40), (0, 20, 15), (1, 20, 15), (1, 15, 20), (1, 10, 8)}
    assert float(images.weight(1, 1).min()) == 0.0 and float(images.weight(0, 1).min()) == 1.0


@pytest.fixture(scope="module")
def mixed_run(tmp_path_factory) -> Path:
    """A few steps on the mixed-size scene, with a resolution level and a degree choice on a held-out block."""
    root = tmp_path_factory.mktemp("mixed")
    write_mixed_scene(root / "scene")
    config = tiny_config(root, steps=16, checkpoint_every=0, resolution_levels=1, resolution_interval=6,
                         model=ModelConfig(sh_degree=2, u_sh_degree=2, sh_degree_interval=3),
                         degree_choice=DegreeChoiceConfig(on=True, held_out=0.25, at=0.55),
                         data=DataConfig(data=str(root / "scene"), cache_dir=root / "cache"))
    return train_command.train(dataclasses.replace(config, compile_kernels=False))


def test_a_scene_of_mixed_sizes_trains_chooses_degrees_and_evaluates_every_view(mixed_run):
    events = [json.loads(line) for line in (mixed_run / "metrics.jsonl").read_text().splitlines()]
    steps = [e for e in events if e["event"] == "train"]
    assert len(steps) == 16 and all(np.isfinite(e["loss"]) for e in steps)
    summary = json.loads((mixed_run / "summary.json").read_text())
    final = summary["eval"]["eval"]
    assert final["num_images"] == 3 and all(np.isfinite(final[k]) for k in ("psnr", "ssim", "psnr_observed"))
    assert len(summary["degree_choice"]["held_out_views"]) == 2  # scored on views of two sizes


def test_render_uncertainty_and_eval_ause_score_each_view_of_mixed_sizes_at_its_own_size(mixed_run, tmp_path):
    out = tmp_path / "eval"
    entrypoint(["render-uncertainty", "--load", str(mixed_run), "--views", "eval", "--output", str(out)])
    shapes = [np.load(path).shape for path in (out / "npy").glob("*_uncertainty.npy")]
    assert sorted(shapes) == sorted((h, w) for w, h in SIZES)
    for method in ("ours", "visibility", "residual"):
        scores = tmp_path / f"{method}.json"
        entrypoint(["eval-ause", "--load", str(mixed_run), "--method", method, "--output", str(scores)])
        result = json.loads(scores.read_text())
        assert result["images"] == 3 and np.isfinite(result["mean"]["ause_mae"]), method
