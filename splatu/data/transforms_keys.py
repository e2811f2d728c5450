"""The keys a transforms.json reader acts on, and the refusal of near misses.

nerfstudio and instant-ngp read only the exact spelling, and so does splatu's loader: a `Camera_Model`, `fl-x` or
`c_x` was ignored without a word and the scene trained with another lens, focal length or principal point. Keys
these readers do not act on (instant-ngp's aabb_scale, sharpness, nerfstudio's applied_transform, ...) pass.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from splatu.data.frames import STANDIN_KEY
from splatu.errors import SplatuError

COEFFICIENT_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
"""Every distortion coefficient a transforms.json may give (nerfstudio reads all six whatever the camera_model)."""
RATIONAL_KEYS = ("k5", "k6")
"""OpenCV's rational lens model's further coefficients (COLMAP FULL_OPENCV's), which neither nerfstudio nor splatu
models: read only to refuse a non-zero one, which was dropped without a word."""
CAMERA_KEYS = ("camera_model", "is_fisheye", "fl_x", "fl_y", "x_fov", "y_fov", "camera_angle_x", "camera_angle_y", "cx",
               "cy", "w", "h", *COEFFICIENT_KEYS, *RATIONAL_KEYS)
"""A camera's keys: at the top level for every frame, or in a frame for that frame alone."""
SPLIT_KEYS = ("train_filenames", "val_filenames", "test_filenames")
"""The file's explicit split lists (nerfstudio keys)."""
TOP_KEYS = ("frames", *CAMERA_KEYS, "depth_unit_scale_factor", "ply_file_path", *SPLIT_KEYS, STANDIN_KEY)
FRAME_KEYS = ("file_path", "transform_matrix", "transform_matrix_start", "transform_matrix_end", *CAMERA_KEYS,
              "mask_path", "depth_file_path", "observed_mask_path")
POSE_KEYS = ("file_path", "transform_matrix")
"""What every transforms.json frame has, NeRF-synthetic's too."""


def plain(key: str) -> str:
    """`key` without case, spaces, underscores or hyphens: the spelling slips that keep a key from being read."""
    return "".join(key.split()).replace("_", "").replace("-", "").lower()


def refuse_misspelt_keys(entries: Mapping[str, Any], read: Iterable[str], where: str) -> None:
    """One line for a key that is one of the `read` keys but for case, spaces, underscores or hyphens (K1, fl-x,
    Camera_Model), since it would be ignored. A second spelling next to the right one with the same value changes
    nothing and passes."""
    spelling = {plain(key): key for key in read}
    for key, value in entries.items():
        right = spelling.get(plain(key))
        if right is None or key == right or (right in entries and entries[right] == value):
            continue
        raise SplatuError(f"key {key!r} is not spelt as the key {right!r}, so it would be ignored", where,
                          f"rename it {right!r}")
