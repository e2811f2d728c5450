"""nerfstudio / instant-ngp `transforms.json`: parse it into frames, and write it.

Intrinsics (fl_x, fl_y, cx, cy, w, h) and distortion may be global or per frame, the focal lengths also as
instant-ngp's x_fov / y_fov (degrees) or camera_angle_x / camera_angle_y (radians); poses are OpenGL
camera-to-world (instant-ngp's transform_matrix_start for a camera that did not move). Images with distortion are
undistorted to OpenCV's alpha=0 pinhole K (see splatu/data/images.py); instant-ngp's is_fisheye stands for
nerfstudio's OPENCV_FISHEYE. Frames are sorted by file path, as nerfstudio does, so contiguous eval blocks follow the
capture order of numbered video frames.

`applied_transform` is accepted and not applied: nerfstudio writes `ply_file_path` points in
the same frame as the poses, and the transform only maps both back to the original COLMAP
frame.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
import torch

from splatu.camera import Camera
from splatu.data.frames import (
    FLOAT32_MAX,
    MAX_IMAGE_SIDE,
    STANDIN_KEY,
    Frame,
    RawScene,
    checked_matrix,
    focal_from_angle,
    refuse_implausible_focal,
    world_to_camera_from_opengl,
)
from splatu.data.images import Distortion, PixelKind, PixelRecipe, undistorted_intrinsics
from splatu.data.ply import read_ply_points
from splatu.data.principal_point import Misplaced, PrincipalPointFault, misplaced_principal_point, warn_misplaced
from splatu.data.transforms_keys import (
    COEFFICIENT_KEYS,
    FRAME_KEYS,
    POSE_KEYS,
    RATIONAL_KEYS,
    SPLIT_KEYS,
    TOP_KEYS,
    refuse_misspelt_keys,
)
from splatu.errors import SplatuError
from splatu.json_files import read_json

DISTORTION_KEYS = {"OPENCV": ("k1", "k2", "p1", "p2", "k3"), "OPENCV_FISHEYE": ("k1", "k2", "k3", "k4")}
PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "PERSPECTIVE")
RADIAL_MODELS = ("SIMPLE_RADIAL", "RADIAL")
"""Radial-only models: their k1, k2 are OpenCV's with p1 = p2 = 0."""

DEFAULT_DEPTH_UNIT = 1e-3
"""nerfstudio's depth_unit_scale_factor when a transforms.json gives none: depth images in millimetres."""


def frame_name(file_path: str) -> str:
    """How a frame is named in splits and lists: its file path, normalised (no leading ./)."""
    return PurePosixPath(file_path).as_posix().removeprefix("./")


def frame_entry(frame: object, index: int, json_path: Path,
                read: tuple[str, ...] = POSE_KEYS) -> tuple[str, str, np.ndarray]:
    """A transforms.json frame's (name, where-text for errors, camera-to-world), validated in one place
    for both nerfstudio and NeRF-synthetic files, with its keys (`read`) spelt as the loader reads them."""
    if isinstance(frame, dict):
        file_path = frame.get("file_path")
        refuse_misspelt_keys(frame, read, f"in frame {frame_name(file_path)!r} of {json_path}"
                             if isinstance(file_path, str) else f"in frames[{index}] of {json_path}")
    if not isinstance(frame, dict) or frame.get("file_path") is None:
        raise SplatuError(f"frames[{index}] has no file_path", f"in {json_path}", "give every frame a file_path")
    if not isinstance(frame["file_path"], str):  # a number was read as "has no file_path" though the frame has one
        raise SplatuError(f"frames[{index}]'s file_path is {frame['file_path']!r}, not a string", f"in {json_path}",
                          "write the file_path in quotes, as a path or a name")
    name = frame_name(frame["file_path"])
    where = f"in frame {name!r} of {json_path}"
    if "transform_matrix" in frame:
        fix = "fix or remove the frame's transform_matrix"
        return name, where, checked_matrix(frame["transform_matrix"], where, fix)
    if "transform_matrix_start" not in frame:
        raise SplatuError("frame has no transform_matrix", where, "give every frame its 4x4 camera-to-world matrix")
    return name, where, _still_pose(frame, where)


def _still_pose(frame: Mapping[str, Any], where: str) -> np.ndarray:
    """The pose of a frame that gives instant-ngp's transform_matrix_start (and _end: where a rolling shutter or a
    motion blur starts and ends) instead of a transform_matrix. A static camera's start is its pose, as instant-ngp's
    own scripts read it; one that moved would train as if it had not, so a move is refused."""
    start = checked_matrix(frame["transform_matrix_start"], where, "fix or remove the frame's transform_matrix_start")
    if frame.get("transform_matrix_end") is None:
        return start
    end = checked_matrix(frame["transform_matrix_end"], where, "fix or remove the frame's transform_matrix_end")
    moved = float(np.abs(end - start).max())
    if moved > 1e-6 * max(1.0, float(np.abs(start[:3, 3]).max())):
        raise SplatuError(f"transform_matrix_start and transform_matrix_end differ by up to {moved:.3g}: the camera "
                          "moved during the exposure (a rolling shutter or a motion blur), which splatu does not model",
                          where, "give the frame a transform_matrix, such as the pose at the middle of the exposure")
    return start


def _given(frame: Mapping[str, Any], top: Mapping[str, Any], key: str) -> Any:
    """The frame's value of a camera key, else the file's, else None. null counts as not given, in a frame and in the
    file (as for mask_path): a frame's "k1": null keeps the file's k1, where it dropped it for that frame alone.
    nerfstudio and instant-ngp fail on a null, so no file written for them means anything else by one."""
    value = frame.get(key)
    return top.get(key) if value is None else value


def _number(frame: Mapping[str, Any], top: Mapping[str, Any], key: str, where: str) -> float | None:
    value = _given(frame, top, key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not abs(value) <= FLOAT32_MAX:
        raise SplatuError(f"intrinsic {key} must be a finite number within float32's range (got {value!r})", where,
                          "fix the value")
    return float(value)


def _focal(frame: Mapping[str, Any], top: Mapping[str, Any], axis: str, side: int, where: str) -> float | None:
    """The focal length along `axis` in pixels: fl_x (fl_y), or instant-ngp's x_fov (y_fov) in degrees or
    camera_angle_x (camera_angle_y) in radians, each the field of view across the image's `side` pixels. As in
    instant-ngp, a frame's own values override the file's, and fl_ wins over camera_angle_ where one place gives
    both. instant-ngp reads x_fov before fl_x and nerfstudio after it, so where one place gives both they must agree."""
    for source in (frame, top):
        focal = _number(source, {}, f"fl_{axis}", where)
        degrees = _number(source, {}, f"{axis}_fov", where)
        if degrees is not None:
            if not 0 < degrees < 180:
                raise SplatuError(f"{axis}_fov must be an angle in (0, 180) degrees (got {degrees!r})", where,
                                  f"fix {axis}_fov, or give fl_{axis} in pixels instead")
            from_fov = focal_from_angle(math.radians(degrees), side)
            if focal is not None and not math.isclose(focal, from_fov, rel_tol=1e-3):
                raise SplatuError(f"fl_{axis} {focal:.6g} px and {axis}_fov {degrees:.6g} degrees (fl_{axis} "
                                  f"{from_fov:.6g} px) disagree, and instant-ngp reads {axis}_fov first where "
                                  f"nerfstudio reads fl_{axis}", where,
                                  f"remove the wrong one of fl_{axis} and {axis}_fov")
            focal = from_fov if focal is None else focal
        if focal is not None:
            return focal
        angle = _number(source, {}, f"camera_angle_{axis}", where)
        if angle is not None:
            if not 0 < angle < math.pi:  # tan(angle / 2) must be positive and finite
                raise SplatuError(f"camera_angle_{axis} must be an angle in (0, pi) radians (got {angle!r})", where,
                                  f"fix camera_angle_{axis}, or give fl_{axis} in pixels instead")
            return focal_from_angle(angle, side)
    return None


def _intrinsics(frame: Mapping[str, Any], top: Mapping[str, Any], where: str) -> tuple[np.ndarray, int, int]:
    values = {key: _number(frame, top, key, where) for key in ("cx", "cy", "w", "h")}
    missing = [key for key in ("w", "h") if values[key] is None]
    if missing:
        raise SplatuError(f"missing intrinsics {', '.join(missing)}", where,
                          "give w and h (and fl_x or camera_angle_x) at the top level or per frame")
    fractional = [f"{key} = {values[key]!r}" for key in ("w", "h") if values[key] != int(values[key])]
    if fractional:  # a size is counted in pixels; rounding 1080.5 would pick a size the file never gave
        raise SplatuError(f"image size {', '.join(fractional)} is not a whole number of pixels", where,
                          "give w and h in whole pixels")
    width, height = int(values["w"]), int(values["h"])
    if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE):
        raise SplatuError(f"image size {width}x{height} is not a plausible image size", where,
                          "give w and h in pixels")
    fx = _focal(frame, top, "x", width, where)
    if fx is None:
        raise SplatuError("missing intrinsics fl_x (or x_fov or camera_angle_x)", where,
                          "give fl_x in pixels, or instant-ngp's x_fov in degrees or camera_angle_x in radians, at "
                          "the top level or per frame")
    fy = _focal(frame, top, "y", height, where)
    fy = fx if fy is None else fy
    cx = values["cx"] if values["cx"] is not None else width / 2
    cy = values["cy"] if values["cy"] is not None else height / 2
    if fx <= 0 or fy <= 0:
        raise SplatuError("focal lengths must be positive", where, "fix fl_x and fl_y")
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    refuse_implausible_focal(K, width, height, where,
                             "give fl_x and fl_y in pixels (not mm), or camera_angle_x and camera_angle_y in radians")
    return K, width, height


def _principal_point_fix(kind: PrincipalPointFault) -> str:
    """How to mend a camera whose principal point `misplaced_principal_point` reads as mistake `kind`."""
    if kind == "swapped":
        return "swap w and h, or cx and cy, whichever pair is the wrong way round"
    return "give fl_x, fl_y, cx and cy in pixels of this w x h image (scaled by w / the width they were made for)"


def _lens_model(frame: Mapping[str, Any], top: Mapping[str, Any], distorted: bool, where: str) -> tuple[str, str]:
    """The frame's camera_model, and how errors name it.

    instant-ngp's is_fisheye reads k1..k4 as OpenCV's fisheye (equidistant) model's, nerfstudio's OPENCV_FISHEYE:
    without a camera_model it picks that model (else OPENCV, the default). With a non-zero coefficient, a
    camera_model that says otherwise is refused: nerfstudio and instant-ngp would undistort the images differently.
    """
    given = _given(frame, top, "camera_model")
    fisheye = _given(frame, top, "is_fisheye")
    if fisheye is not None and not isinstance(fisheye, bool):
        raise SplatuError(f"is_fisheye must be true or false (got {fisheye!r})", where,
                          "write is_fisheye as true or false, without quotes")
    if given is None:
        return ("OPENCV_FISHEYE", "is_fisheye true (OPENCV_FISHEYE)") if fisheye else ("OPENCV", "camera_model OPENCV")
    model = str(given)
    if model not in (*DISTORTION_KEYS, *PINHOLE_MODELS, *RADIAL_MODELS):
        raise SplatuError(f"unknown camera model {model!r} ({_owner(frame, 'camera_model')}'s camera_model)", where,
                          f"use one of {', '.join((*DISTORTION_KEYS, *PINHOLE_MODELS, *RADIAL_MODELS))}")
    if distorted and fisheye is not None and fisheye != (model == "OPENCV_FISHEYE"):
        raise SplatuError(f"is_fisheye {str(fisheye).lower()} contradicts camera_model {model}", where,
                          "give camera_model OPENCV_FISHEYE with is_fisheye true for a fisheye lens (k1 to k4 of "
                          "OpenCV's fisheye model), or another camera_model with is_fisheye false or none")
    return model, f"camera_model {model}"


def _owner(frame: Mapping[str, Any], key: str) -> str:
    """Whose value of camera key `key` a frame reads, for an error: its own, or the file's (see `_given`)."""
    return "the file" if frame.get(key) is None else "the frame"


def _distortion(frame: Mapping[str, Any], top: Mapping[str, Any], where: str) -> Distortion | None:
    """The frame's lens distortion; a non-zero coefficient its camera_model does not use is refused, since it would
    be dropped: nerfstudio's OPENCV uses k1, k2, p1, p2 (and OpenCV's k3), OPENCV_FISHEYE k1 to k4, a pinhole none,
    and no model k5 or k6."""
    for key in RATIONAL_KEYS:
        if value := _number(frame, top, key, where):
            raise SplatuError(f"{_owner(frame, key)}'s {key} = {value:g} belongs to OpenCV's rational lens model "
                              "(COLMAP FULL_OPENCV), which splatu does not model", where,
                              "undistort the images first (colmap image_undistorter does) and give the pinhole camera "
                              f"they were undistorted to, or remove {key} if the images are already undistorted")
    values = {key: _number(frame, top, key, where) or 0.0 for key in COEFFICIENT_KEYS}
    model, named = _lens_model(frame, top, any(values.values()), where)
    lens = "OPENCV" if model in RADIAL_MODELS else model
    used = DISTORTION_KEYS.get(lens, ())
    dropped = [key for key in COEFFICIENT_KEYS if values[key] and key not in used]
    if dropped:
        key = dropped[0]
        users = [name for name, keys in DISTORTION_KEYS.items() if key in keys]
        raise SplatuError(f"{_owner(frame, key)}'s {key} = {values[key]:g} would be ignored: "
                          f"{named} uses {', '.join(used) or 'no distortion coefficients'}", where,
                          f"set camera_model to the lens model {key} belongs to ({' or '.join(users)}), or remove "
                          f"{key} if the images are already undistorted")
    if not used:
        return None
    distortion = Distortion(lens, tuple(values[key] for key in used))  # type: ignore[arg-type]
    return None if distortion.is_identity() else distortion


def _copies(root: Path, file_path: str) -> Path | None:
    """The folder whose sibling `<name>_N` may hold the image at 1/N (images_N/...): the image's own folder, if it
    has one under the scene's."""
    relative = PurePosixPath(frame_name(file_path))
    return root / relative.parent if len(relative.parts) >= 2 else None


def _extra(color: PixelRecipe, root: Path, frame: Mapping[str, Any], key: str, kind: PixelKind, name: str,
           depth_unit: float = DEFAULT_DEPTH_UNIT) -> PixelRecipe | None:
    """The frame's mask or depth map named by `key`, warped exactly like its image (but never pre-downscaled).

    Depth in .npy files is taken as is; depth images are integers times depth_unit_scale_factor
    (nerfstudio's convention, default 1e-3: millimetres).
    """
    if frame.get(key) is None:
        return None
    path = root / str(frame[key])
    if not path.is_file():
        noun = "depth map" if kind == "depth" else "mask"
        raise SplatuError(f"{noun} not found (the {key} of frame {name!r})", f"in {path}",
                          f"fix the frame's {key} or remove it")
    depth_scale = 1.0 if kind != "depth" or path.suffix == ".npy" else depth_unit
    return replace(color, path=path, kind=kind, depth_scale=depth_scale)


def _by_file_path(frames_json: list[Any]) -> list[tuple[int, Any]]:
    """(index in the file, frame) sorted by file path, so errors can still count frames as the file does."""
    return sorted(enumerate(frames_json),
                  key=lambda item: str(item[1].get("file_path", "")) if isinstance(item[1], dict) else "")


def _depth_unit(top: Mapping[str, Any], json_path: Path) -> float:
    """Metres per depth-image unit; a zero, negative or non-numeric factor would scale every depth wrongly."""
    value = top.get("depth_unit_scale_factor")
    if value is None:  # absent or null
        return DEFAULT_DEPTH_UNIT
    if isinstance(value, bool) or not isinstance(value, int | float) or not (np.isfinite(value) and value > 0):
        raise SplatuError(f"depth_unit_scale_factor must be a positive number (got {value!r})", f"in {json_path}",
                          f"fix it, or remove it for nerfstudio's default of {DEFAULT_DEPTH_UNIT} (millimetres)")
    return float(value)


def _frame_camera(frame: Mapping[str, Any], top: Mapping[str, Any], where: str, name: str, c2w: np.ndarray,
                  undistorted: dict[tuple, np.ndarray]) -> tuple[Camera, np.ndarray, Distortion | None]:
    """A frame's pinhole camera at full resolution, with the intrinsics its images are undistorted to (computed once
    per distinct camera, in `undistorted`), and the frame's own K and distortion. Its principal point is left to
    the caller (`misplaced_principal_point`): refused for a candidate camera, reported for a training scene."""
    K, width, height = _intrinsics(frame, top, where)
    distortion = _distortion(frame, top, where)
    key = (K.tobytes(), width, height, distortion)
    if key not in undistorted:
        undistorted[key] = undistorted_intrinsics(K, distortion, width, height, where)
    camera = Camera(K=torch.tensor(undistorted[key], dtype=torch.float64),
                    world_to_camera=torch.tensor(world_to_camera_from_opengl(c2w), dtype=torch.float64),
                    width=width, height=height, name=name)
    return camera, K, distortion


def transforms_file(path: Path) -> Path:
    """The transforms.json that `path` names: the file itself, or the one in the folder."""
    return path / "transforms.json" if path.is_dir() else path


def read_cameras(path: Path, downscale: int = 1, off_centre_ok: bool = False) -> list[Camera]:
    """The cameras a transforms.json-style file (or its folder) lists, poses and intrinsics as nerfstudio writes
    them, built as the loader builds a run's cameras at its --downscale: candidate views in the data's frame. No
    image need exist; file_path only names the view. A principal point that a mistake explains is refused, unless
    `off_centre_ok` (render-uncertainty's --off-centre-ok) says the file holds tiles or crops of larger photos."""
    path = transforms_file(path)
    # a COLMAP images.txt or a camera list of another tool is the likely mistake here
    top = read_json(path, "pass a nerfstudio-style transforms.json: \"frames\" with a camera-to-world "
                          "\"transform_matrix\" each, and fl_x, fl_y, cx, cy, w, h at the top or per frame")
    refuse_misspelt_keys(top, TOP_KEYS, f"in {path}")
    frames_json = top.get("frames")
    if not isinstance(frames_json, list) or not frames_json:
        raise SplatuError("no frames listed", f"in {path}", "list the cameras under \"frames\"")
    cameras: list[Camera] = []
    undistorted: dict[tuple, np.ndarray] = {}
    for index, frame in enumerate(frames_json):
        name, where, c2w = frame_entry(frame, index, path, FRAME_KEYS)
        camera, K, _ = _frame_camera(frame, top, where, name, c2w, undistorted)
        fault = None if off_centre_ok else misplaced_principal_point(float(K[0, 2]), float(K[1, 2]), camera.width,
                                                                      camera.height, candidate=True)
        if fault is not None:  # no image shows which of K and w, h is wrong, and either renders a shifted view
            raise SplatuError(fault[1], where, f"{_principal_point_fix(fault[0])}; for tiles or crops of a larger "
                              "photo (a tile scene's own cameras too), pass --off-centre-ok")
        cameras.append(camera.scaled(1.0 / downscale))
    return cameras


def load_nerfstudio(path: Path, background: tuple[float, float, float], warn_off_centre: bool = True) -> RawScene:
    """Parse a transforms.json (or the folder holding it) into frames at full size, with one warning line for
    principal points far off-centre unless not `warn_off_centre`."""
    json_path = transforms_file(path)
    root = json_path.parent
    top = read_json(json_path)
    refuse_misspelt_keys(top, TOP_KEYS, f"in {json_path}")
    frames_json = top.get("frames")
    if not isinstance(frames_json, list) or not frames_json:
        raise SplatuError("no frames listed", f"in {json_path}", "list the images under \"frames\"")
    depth_unit = _depth_unit(top, json_path)
    frames: list[Frame] = []
    undistorted_cache: dict[tuple, np.ndarray] = {}
    seen: dict[str, int] = {}
    misplaced: list[Misplaced] = []
    for index, frame in _by_file_path(frames_json):
        name, where, c2w = frame_entry(frame, index, json_path, FRAME_KEYS)
        if name in seen:  # two poses for one image, and split lists could name only one of them
            raise SplatuError(f"frames {seen[name]} and {index} both have file_path {name!r}", f"in {json_path}",
                              "remove the duplicate frame")
        seen[name] = index
        camera, K, distortion = _frame_camera(frame, top, where, name, c2w, undistorted_cache)
        fault = misplaced_principal_point(float(K[0, 2]), float(K[1, 2]), camera.width, camera.height)
        if fault is not None:
            misplaced.append((f"frame {name!r}", *fault))
        color = PixelRecipe(
            path=root / frame["file_path"], kind="color", width=camera.width, height=camera.height,
            target_width=camera.width, target_height=camera.height,
            K=tuple(K.ravel()) if distortion else (), distortion=distortion,
            K_undistorted=tuple(camera.K.numpy().ravel()) if distortion else (), background=background,
        )
        frames.append(Frame(
            name=name,
            camera=camera,
            image=color,
            mask=_extra(color, root, frame, "mask_path", "mask", name),
            depth=_extra(color, root, frame, "depth_file_path", "depth", name, depth_unit),
            observed=_extra(color, root, frame, "observed_mask_path", "mask", name),
            copies=_copies(root, frame["file_path"]),
        ))
    points, colors = np.zeros((0, 3), np.float32), None
    if top.get("ply_file_path"):
        points, colors = read_ply_points(root / str(top["ply_file_path"]))
    splits = _file_splits(top, [f.name for f in frames], json_path)
    if warn_off_centre:  # once the file has loaded
        warn_misplaced(misplaced, len(frames), "frames", json_path, _principal_point_fix)
    return RawScene(name=root.name, source=str(json_path), frames=frames, points=points, point_colors=colors,
                    file_splits=splits, stand_in=STANDIN_KEY in top)


def _listed_frames(value: object, key: str, index: Mapping[str, int], json_path: Path) -> list[int]:
    """A split list's frames as indices; a name that is not a frame is an error, as in nerfstudio."""
    if not isinstance(value, list) or not all(isinstance(n, str) for n in value):
        raise SplatuError(f"{key} must be a list of file paths", f"in {json_path}", f"fix or remove {key}")
    listed = [frame_name(n) for n in value]
    unknown = [n for n in listed if n not in index]
    if unknown:
        raise SplatuError(f"{key} names a frame that is not in frames ({unknown[0]!r})", f"in {json_path}",
                          "list file paths exactly as the frames give them")
    return [index[n] for n in dict.fromkeys(listed)]  # a name listed twice is one view, as in nerfstudio


def _file_splits(top: Mapping[str, Any], names: list[str], json_path: Path) -> dict[str, list[int]]:
    """The file's own split lists as frame indices ("train", "eval" and the extra "interp"); empty without lists.

    As in nerfstudio, a file with any split list must have the lists it needs: train_filenames, and
    val_filenames as the eval split. Where nerfstudio stops for want of val_filenames, a file with
    test_filenames uses them as the eval split (they name the views it holds out, as NeRF-synthetic's
    test split does); with both, test_filenames is the extra "interp" set. A frame in the train list
    and an eval list is refused: its scores would measure a view the model trained on.
    """
    present = [key for key in SPLIT_KEYS if key in top]
    if not present:
        return {}
    index = {name: i for i, name in enumerate(names)}
    lists = {key: _listed_frames(top[key], key, index, json_path) for key in present}
    if "train_filenames" not in lists or len(lists) == 1:
        missing = "train_filenames" if "train_filenames" not in lists else "val_filenames or test_filenames"
        raise SplatuError(f"the file has {' and '.join(present)} but no {missing}", f"in {json_path}",
                          f"add {missing.split()[0]} (or remove the split lists to split by --eval-split)")
    eval_key = "val_filenames" if "val_filenames" in lists else "test_filenames"
    splits = {"train": lists["train_filenames"], "eval": lists[eval_key]}
    if eval_key == "val_filenames" and lists.get("test_filenames"):
        splits["interp"] = lists["test_filenames"]
    trained = set(splits["train"])
    for split, key in (("eval", eval_key), ("interp", "test_filenames")):
        both = [names[i] for i in splits.get(split, []) if i in trained]
        if both:
            raise SplatuError(f"frame {both[0]!r} is in both train_filenames and {key}", f"in {json_path}",
                              "remove it from one list: a model must not be scored on a view it trained on")
    return splits
