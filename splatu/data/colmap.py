"""COLMAP models (sparse/0, binary or text) through pycolmap.

COLMAP already uses OpenCV axes and world-to-camera poses, and puts pixel centres at +0.5
like splatu, so poses and K carry over unchanged; distorted models are undistorted with
OpenCV using the exactly equivalent OpenCV coefficients.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from splatu.camera import Camera
from splatu.data.frames import Frame, RawScene
from splatu.data.images import Distortion, PixelRecipe, undistorted_intrinsics
from splatu.data.pycolmap_quiet import pycolmap
from splatu.errors import SplatuError

SUPPORTED_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
SPARSE_CANDIDATES = ("sparse/0", "sparse", "colmap/sparse/0")
"""Where a scene folder may keep its model, relative to the folder (images/ beside sparse/)."""


def find_sparse_dir(root: Path) -> Path | None:
    """The folder holding cameras.{bin,txt}, images.*, points3D.* under a scene folder, if any."""
    for candidate in SPARSE_CANDIDATES:
        folder = root / candidate
        if any((folder / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            return folder
    return None


def opencv_camera(camera: pycolmap.Camera, where: str) -> tuple[np.ndarray, Distortion | None]:
    """K and OpenCV distortion equivalent to a COLMAP camera; unsupported models are a one-line error."""
    model = camera.model.name
    p = [float(v) for v in camera.params]
    if model == "SIMPLE_PINHOLE":
        (f, cx, cy), coeffs = p, ()
        fx = fy = f
    elif model == "PINHOLE":
        (fx, fy, cx, cy), coeffs = p, ()
    elif model == "SIMPLE_RADIAL":
        f, cx, cy, k = p
        fx = fy = f
        coeffs = (k, 0.0, 0.0, 0.0)
    elif model == "RADIAL":
        f, cx, cy, k1, k2 = p
        fx = fy = f
        coeffs = (k1, k2, 0.0, 0.0)
    elif model == "OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2 = p
        coeffs = (k1, k2, p1, p2)
    else:
        raise SplatuError(f"unsupported COLMAP camera model {model}", where,
                          f"use one of {', '.join(SUPPORTED_MODELS)} (or run colmap image_undistorter first)")
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    distortion = Distortion("OPENCV", coeffs) if any(coeffs) else None
    return K, distortion


def _source_path(images_dir: Path, name: str, downscale: int) -> tuple[Path, int]:
    copy = images_dir.parent / f"{images_dir.name}_{downscale}" / name
    if downscale > 1 and copy.is_file():
        return copy, downscale
    return images_dir / name, 1


def read_reconstruction(sparse_dir: Path) -> pycolmap.Reconstruction:
    try:
        return pycolmap.Reconstruction(str(sparse_dir))
    except Exception as err:  # pycolmap raises plain RuntimeError/ValueError on unreadable models
        raise SplatuError(f"pycolmap cannot read the COLMAP model ({str(err).splitlines()[0][:120]})",
                          f"in {sparse_dir}", "re-export cameras, images and points3D from COLMAP") from None


def load_colmap(root: Path, sparse_dir: Path, downscale: int) -> RawScene:
    """Registered images (sorted by name) with undistorted cameras, and points3D with colours."""
    reconstruction = read_reconstruction(sparse_dir)
    images_dir = root / "images"
    cameras_file = next(p for p in (sparse_dir / "cameras.bin", sparse_dir / "cameras.txt") if p.is_file())
    intrinsics: dict[int, tuple[np.ndarray, Distortion | None, np.ndarray]] = {}
    frames: list[Frame] = []
    for image in sorted(reconstruction.images.values(), key=lambda im: im.name):
        if not image.has_pose:
            continue
        colmap_camera = reconstruction.cameras[image.camera_id]
        if image.camera_id not in intrinsics:
            K, distortion = opencv_camera(colmap_camera, f"in {cameras_file} (camera {image.camera_id})")
            K_new = undistorted_intrinsics(K, distortion, colmap_camera.width, colmap_camera.height)
            intrinsics[image.camera_id] = (K, distortion, K_new)
        K, distortion, K_new = intrinsics[image.camera_id]
        world_to_camera = np.eye(4)
        world_to_camera[:3] = image.cam_from_world().matrix()
        if not np.isfinite(world_to_camera).all():
            raise SplatuError(f"image {image.name} has a non-finite pose", f"in {sparse_dir}",
                              "re-run the reconstruction or delete the image from the model")
        camera = Camera(
            K=torch.tensor(K_new, dtype=torch.float64),
            world_to_camera=torch.tensor(world_to_camera, dtype=torch.float64),
            width=colmap_camera.width, height=colmap_camera.height, name=image.name,
        ).scaled(1.0 / downscale)
        source, source_downscale = _source_path(images_dir, image.name, downscale)
        frames.append(Frame(name=image.name, camera=camera, image=PixelRecipe(
            path=source, kind="color", width=colmap_camera.width, height=colmap_camera.height,
            target_width=camera.width, target_height=camera.height,
            K=tuple(K.ravel()) if distortion else (), distortion=distortion,
            K_undistorted=tuple(K_new.ravel()) if distortion else (), source_downscale=source_downscale,
        )))
    points3d = [point for _, point in sorted(reconstruction.points3D.items())]  # by id: a stable order
    points = np.array([p.xyz for p in points3d], dtype=np.float64).reshape(-1, 3)
    colors = np.array([p.color for p in points3d], dtype=np.float32).reshape(-1, 3) / 255.0
    return RawScene(name=root.name, source=str(sparse_dir), frames=frames, points=points, point_colors=colors)
