"""NeRF-synthetic ("blender") scenes: transforms_{train,val,test}.json with camera_angle_x.

The images are RGBA PNGs; the pipeline composites them on the configured background and
the alpha becomes the view's mask. The file's split is train -> train and test -> eval (the
benchmark's convention); val frames are used only by the non-auto splits, which pool all
frames in the order train, val, test.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from splatu.camera import Camera
from splatu.data.frames import (
    Frame,
    RawScene,
    focal_from_angle,
    refuse_implausible_focal,
    world_to_camera_from_opengl,
)
from splatu.data.images import PixelRecipe, read_image
from splatu.data.nerfstudio import frame_entry
from splatu.data.transforms_keys import refuse_misspelt_keys
from splatu.errors import SplatuError
from splatu.json_files import is_finite_number, read_json

SPLIT_FILES = ("train", "val", "test")


def is_blender(root: Path) -> bool:
    return (root / "transforms_train.json").is_file()


def _image_path(root: Path, file_path: str) -> Path:
    """NeRF-synthetic file paths usually omit the .png extension."""
    path = root / file_path
    return path if path.suffix else path.with_suffix(".png")


def load_blender(root: Path, background: tuple[float, float, float]) -> RawScene:
    """All frames of the split files, in the order train, val, test. A training image listed again is refused, as
    in a nerfstudio file: one in train and test was scored on a view the model trained on."""
    frames: list[Frame] = []
    splits: dict[str, list[int]] = {}
    trained: set[Path] = set()
    for split in SPLIT_FILES:
        json_path = root / f"transforms_{split}.json"
        if not json_path.is_file():
            continue
        content = read_json(json_path)
        refuse_misspelt_keys(content, ("camera_angle_x", "frames"), f"in {json_path}")
        angle = content.get("camera_angle_x")
        if not is_finite_number(angle) or not 0 < angle < math.pi:  # a bool is no angle
            raise SplatuError(f"camera_angle_x must be an angle in (0, pi) radians (got {angle!r})",
                              f"in {json_path}", "fix camera_angle_x")
        frame_list = content.get("frames")
        if not isinstance(frame_list, list):
            raise SplatuError("no frames listed", f"in {json_path}", "list the images under \"frames\"")
        start = len(frames)
        for index, frame in enumerate(frame_list):
            name, _where, c2w = frame_entry(frame, index, json_path)
            path = _image_path(root, frame["file_path"])
            if path in trained:
                raise SplatuError(f"frames[{index}] lists image {name!r}, which transforms_train.json lists too",
                                  f"in {json_path}", "list each training image once, and hold out only other images")
            if split == "train":
                trained.add(path)
            if index == 0:  # the format stores no image size: all frames of a file share the first one's
                height, width = read_image(path).shape[:2]
                focal = focal_from_angle(angle, width)
                K = np.array([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])
                refuse_implausible_focal(K, width, height, f"in {json_path}",
                                         "fix camera_angle_x: the field of view across the image, in radians")
            camera = Camera(
                K=torch.tensor(K, dtype=torch.float64),
                world_to_camera=torch.tensor(world_to_camera_from_opengl(c2w), dtype=torch.float64),
                width=width, height=height, name=name,
            )
            frames.append(Frame(name=name, camera=camera, image=PixelRecipe(
                path=path, kind="color", width=width, height=height,
                target_width=camera.width, target_height=camera.height, background=background,
            )))
        splits[split] = list(range(start, len(frames)))
    if "train" not in splits:
        raise SplatuError("missing transforms_train.json", f"in {root}", "a NeRF-synthetic scene needs it")
    file_splits = {"train": splits["train"]}
    if splits.get("test") or splits.get("val"):
        file_splits["eval"] = splits["test"] if splits.get("test") else splits["val"]
    return RawScene(name=root.name, source=str(root / "transforms_train.json"), frames=frames,
                    points=np.zeros((0, 3)), file_splits=file_splits)
