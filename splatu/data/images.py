"""Turn one file on disk into the pixels a view needs: decode, undistort, resize, cache.

Every image goes through the same steps in float32: decode -> composite RGBA on the
background (before any resampling, because compositing does not commute with averaging) ->
undistort to the pinhole K the loader chose -> resize to the target size (area averaging for
colour, nearest for masks and depths, which must not blend across edges) -> quantise back to
the source's bit depth. The result is cached on disk as .npy, keyed by everything that
changes it, so a second run skips decoding and remapping.

K matrices here use splatu's (and COLMAP's) pixel convention, pixel centres at +0.5; OpenCV
puts them at integers, so K is shifted by 0.5 px on the way into and out of OpenCV.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from splatu.atomic import atomic_write
from splatu.errors import DownscaleError, SplatuError, load_number_array, unwritable

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff"}
"""What COLMAP 4 reads and training decodes alike (pycolmap cannot read WebP): the photos `process-images` takes."""

PixelKind = Literal["color", "mask", "depth"]
CACHE_VERSION = 2
"""Bump when the pipeline changes, so stale cache entries are never read."""


@dataclass(frozen=True)
class Distortion:
    """Lens distortion as OpenCV parameterises it."""

    model: Literal["OPENCV", "OPENCV_FISHEYE"]
    coeffs: tuple[float, ...]
    """OPENCV: (k1, k2, p1, p2[, k3]); OPENCV_FISHEYE: (k1, k2, k3, k4)."""

    def is_identity(self) -> bool:
        """Whether undistorting changes nothing: OPENCV without coefficients is a pinhole, but OPENCV_FISHEYE
        without them is still an equidistant fisheye (r = f·θ, not f·tan θ), which was loaded as a pinhole."""
        return self.model == "OPENCV" and not any(self.coeffs)


@dataclass(frozen=True)
class PixelRecipe:
    """How to make one per-view array from one file; also the cache key."""

    path: Path
    kind: PixelKind
    width: int
    """Width of the camera the file's intrinsics describe (full resolution)."""
    height: int
    """Height of the camera the file's intrinsics describe."""
    target_width: int
    target_height: int
    K: tuple[float, ...] = ()
    """Distorted intrinsics at full resolution, row-major 3x3; empty when there is no distortion."""
    distortion: Distortion | None = None
    K_undistorted: tuple[float, ...] = ()
    """Pinhole intrinsics after undistortion at full resolution, row-major 3x3."""
    source_downscale: int = 1
    """The file is a pre-downscaled copy (images_N) at 1/N of (width, height)."""
    full_size: Path | None = None
    """The full-size image that a pre-downscaled copy stands for (not part of the cache key: the copy's pixels are
    what load)."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Colour that RGBA images are composited on."""
    depth_scale: float = 1.0
    """Depth images (not .npy): stored integers times this give depth in scene units."""


def scale_intrinsics(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """K for an image resized by (sx, sy), in the pixel-centre-at-0.5 convention (as Camera.scaled)."""
    K = np.array(K, dtype=np.float64).reshape(3, 3).copy()
    K[0] *= sx
    K[1] *= sy
    return K


def _to_opencv(K: np.ndarray) -> np.ndarray:
    K = K.copy()
    K[0, 2] -= 0.5
    K[1, 2] -= 0.5
    return K


def _from_opencv(K: np.ndarray) -> np.ndarray:
    K = K.copy()
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    return K


MAX_UNDISTORTED_ZOOM = 10.0
"""How far the undistorted camera's focal lengths may stray from the lens's, either way. alpha=0 only crops to
valid pixels, so a real lens's stay close (fox: 1.01x); absurd coefficients gave 2e-6x (a fisheye k1 of -1, with
its principal point off the image) or 4e29x (k1 = 1e30), and trained on garbage without a word."""


def undistorted_intrinsics(K: np.ndarray, distortion: Distortion | None, width: int, height: int,
                           where: str) -> np.ndarray:
    """The pinhole K to undistort to: OpenCV's optimal matrix with alpha=0 (fisheye: balance=0); one that is not a
    usable camera for the image is a one-line error naming `where`.

    alpha=0 keeps only valid pixels, so undistorted images have no black borders; the price is
    a slightly narrower field of view than the distorted image.
    """
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    if distortion is None or distortion.is_identity():
        return K.copy()
    D = np.array(distortion.coeffs, dtype=np.float64)
    if distortion.model == "OPENCV_FISHEYE":
        new_K = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
            _to_opencv(K), D.reshape(4, 1), (width, height), np.eye(3), balance=0.0)
    else:
        new_K, _ = cv2.getOptimalNewCameraMatrix(_to_opencv(K), D, (width, height), 0.0, (width, height))
    new_K = _from_opencv(np.asarray(new_K, dtype=np.float64))
    zoom = np.diag(new_K)[:2] / np.diag(K)[:2]
    centred = 0 <= new_K[0, 2] <= width and 0 <= new_K[1, 2] <= height
    if not (np.isfinite(new_K).all() and centred and (zoom >= 1 / MAX_UNDISTORTED_ZOOM).all()
            and (zoom <= MAX_UNDISTORTED_ZOOM).all()):
        raise SplatuError(f"distortion {distortion.coeffs} has no usable undistorted camera (OpenCV's has focal "
                          f"length {new_K[0, 0]:.3g} for the lens's {K[0, 0]:.3g} and principal point "
                          f"({new_K[0, 2]:.3g}, {new_K[1, 2]:.3g}) in a {width}x{height} image)", where,
                          "check the distortion coefficients and intrinsics; a lens that sees 90° or more off its "
                          "axis (a wide fisheye) has no pinhole view of the whole image: crop the images to the part "
                          "within that angle")
    return new_K


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_END = b"\x00\x00\x00\x00IEND"
"""The IEND chunk (zero length, then its type) that closes every complete PNG."""
JPEG_SOI = b"\xff\xd8"
JPEG_MARKER_IN_SCAN = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")
"""In entropy-coded data 0xFF is stuffing (FF 00), a restart (FF D0-D7) or fill (FF FF); anything else is a marker."""
JPEG_STANDALONE = {0x01, *range(0xD0, 0xD8)}
"""Markers without a length field: TEM and RST0-7."""


def jpeg_is_complete(data: bytes) -> bool:
    """Whether a JPEG reaches its end-of-image marker, walking segments by their lengths.

    Walking (rather than searching for FF D9) skips the EXIF thumbnail's own end marker inside
    APP1, and stops at the first real EOI, so phone trailers after it are accepted.
    """
    pos = len(JPEG_SOI)
    while True:
        pos = data.find(b"\xff", pos)
        while 0 <= pos < len(data) - 1 and data[pos + 1] == 0xFF:
            pos += 1  # fill bytes before a marker
        if pos < 0 or pos + 1 >= len(data):
            return False
        marker = data[pos + 1]
        if marker == 0xD9:
            return True
        if marker in JPEG_STANDALONE:
            pos += 2
            continue
        if pos + 4 > len(data):
            return False
        end = pos + 2 + int.from_bytes(data[pos + 2:pos + 4], "big")
        if end > len(data):
            return False
        if marker != 0xDA:
            pos = end
            continue
        found = JPEG_MARKER_IN_SCAN.search(data, end)  # start of scan: skip its entropy-coded data
        if found is None:
            return False
        pos = found.start()


def truncated_format(data: bytes) -> str | None:
    """"JPEG" or "PNG" when `data` is such a file cut short, else None.

    libjpeg decodes a truncated JPEG with only a warning, filling the rest grey; the check
    makes that an error. OpenCV already refuses a truncated PNG, but without saying why.
    """
    if data.startswith(JPEG_SOI) and not jpeg_is_complete(data):
        return "JPEG"
    if data.startswith(PNG_SIGNATURE) and data.rfind(PNG_END) < 0:
        return "PNG"
    return None


def read_image(path: Path, or_else: str = "remove its frame") -> np.ndarray:
    """Decode an image file as stored (no EXIF rotation), channels in RGB(A) order; `or_else` ends the fix of a
    truncated or corrupt file (what else the user may do). A folder where the image should be is said to be one:
    "not found" sent the user looking for a path that exists (an empty file_path names the scene folder itself)."""
    if not path.is_file():
        if not path.parent.is_dir():  # a COLMAP scene copied without images/ names no file to check
            raise SplatuError(f"image not found: its folder {path.parent.name}/ does not exist", f"in {path}",
                              f"put the scene's images in {path.parent}, or check the file path in the scene "
                              "description")
        what = "image path is a folder, not an image file" if path.is_dir() else "image not found"
        raise SplatuError(what, f"in {path}", "check the file path in the scene description")
    try:
        data = path.read_bytes()
    except OSError as err:
        raise SplatuError(f"cannot read image ({err.strerror})", f"in {path}", "check the file's permissions") from None
    kind = truncated_format(data)
    if kind is not None:
        raise SplatuError(f"cannot decode image (truncated {kind}: the file ends before its end marker)",
                          f"in {path}", f"copy or export the file again in full, or {or_else}")
    pixels = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    if pixels is None:
        raise SplatuError("cannot decode image (corrupt or unsupported format)", f"in {path}",
                          f"replace the file with a valid PNG/JPEG, or {or_else}")
    if pixels.ndim == 3 and pixels.shape[2] == 4:
        return cv2.cvtColor(pixels, cv2.COLOR_BGRA2RGBA)
    if pixels.ndim == 3 and pixels.shape[2] == 3:
        return cv2.cvtColor(pixels, cv2.COLOR_BGR2RGB)
    return pixels


def write_png(path: Path, pixels: np.ndarray, fix: str) -> None:
    """Encode uint8 or uint16 pixels, channels in RGB(A) order (grey is written as it is), as a PNG; the inverse of
    `read_image`, so every PNG splatu writes has its channels the same way round. A refused write is one line,
    ending in `fix`. Python writes the file: cv2.imwrite crashed the process (a segfault) on a path that is not
    UTF-8, such as a run folder named after a scene folder with a Latin-1 name."""
    if pixels.ndim == 3 and pixels.shape[2] in (3, 4):  # OpenCV stores BGR(A)
        pixels = np.ascontiguousarray(pixels[..., [2, 1, 0, 3][: pixels.shape[2]]])
    data = cv2.imencode(".png", pixels)[1].tobytes()
    try:
        path.write_bytes(data)
    except OSError as err:
        raise unwritable(path, err, fix) from None


def _read_depth(recipe: PixelRecipe) -> np.ndarray:
    """A depth map from .npy (float, scene units) or an integer image times depth_scale."""
    fix = "write depth as a finite float32 .npy with one value per pixel, or as a 16-bit PNG"
    if recipe.path.suffix != ".npy":
        depth = read_image(recipe.path).astype(np.float32) * recipe.depth_scale
    elif not recipe.path.is_file():
        raise SplatuError("depth map not found", f"in {recipe.path}", "fix depth_file_path or remove it")
    else:
        depth = load_number_array(recipe.path, "depth map", fix)
    if depth.ndim != 2 or not np.isfinite(depth).all():
        raise SplatuError("depth map must be a finite 2-D array (one value per pixel)", f"in {recipe.path}", fix)
    return depth.astype(np.float32)


def _read_source(recipe: PixelRecipe) -> tuple[np.ndarray, np.dtype]:
    """The file as float32 (H, W[, C]) plus the dtype to quantise back to."""
    if recipe.kind == "depth":
        return _read_depth(recipe), np.dtype(np.float32)
    pixels = read_image(recipe.path)
    if pixels.dtype not in (np.uint8, np.uint16):
        raise SplatuError(f"unsupported image bit depth {pixels.dtype}", f"in {recipe.path}",
                          "save the image as 8- or 16-bit PNG/JPEG")
    dtype = pixels.dtype
    values = pixels.astype(np.float32) / float(np.iinfo(dtype).max)
    if recipe.kind == "mask":
        return (values[..., 0] if values.ndim == 3 else values), dtype
    if values.ndim == 2:
        values = np.repeat(values[..., None], 3, axis=2)
    if values.shape[2] == 4:
        alpha = values[..., 3:]
        rgb = values[..., :3] * alpha + np.asarray(recipe.background, dtype=np.float32) * (1.0 - alpha)
        values = np.concatenate([rgb, alpha], axis=2)
    return values, dtype


def _check_size(recipe: PixelRecipe, height: int, width: int) -> None:
    expected_w = recipe.width / recipe.source_downscale
    expected_h = recipe.height / recipe.source_downscale
    if abs(width - expected_w) >= 1 or abs(height - expected_h) >= 1:
        noun = {"color": "image", "mask": "mask", "depth": "depth map"}[recipe.kind]
        expected = f"{round(expected_w)}x{round(expected_h)}"
        turned = abs(width - expected_h) < 1 and abs(height - expected_w) < 1
        if recipe.source_downscale == 1:
            raise SplatuError(f"{noun} is {width}x{height} but its camera says {expected}", f"in {recipe.path}",
                              _size_fix(recipe.kind, noun, turned))
        # a pre-downscaled copy (images_N): the size the user wrote is the camera's, which the factor divides
        copy_at_fault = not turned or _full_size_fits(recipe)
        raise DownscaleError(f"{noun} is {width}x{height}, but the camera's {recipe.width}x{recipe.height} at "
                             f"1/{recipe.source_downscale} of its size is {expected}", f"in {recipe.path}",
                             _copy_fix(recipe, expected) if copy_at_fault else _size_fix(recipe.kind, noun, turned),
                             factor=recipe.source_downscale, copy_at_fault=copy_at_fault)


def _full_size_fits(recipe: PixelRecipe) -> bool:
    """Whether the full-size image that a copy turned on its side stands for has its camera's size: then the copy
    alone is turned (made by a tool that applied the photo's EXIF orientation, say), and swapping the camera's width
    and height, as a turned image suggests, would refuse every image that fits it. Decoded only for this error."""
    if recipe.full_size is None or not recipe.full_size.is_file():
        return False
    try:
        return read_image(recipe.full_size).shape[:2] == (recipe.height, recipe.width)
    except SplatuError:
        return False


def _copy_fix(recipe: PixelRecipe, expected: str) -> str:
    """What to do about a pre-downscaled copy (in images_N) of the wrong size: make it again, or do without it (the
    loader then shrinks the full-size image itself). The camera is not at fault when the full-size images fit it.
    Both serve every command that loads the scene, a saved run's too, whose factor its config.yml fixes; a new run
    may also train at full size (`splatu.data.resolve.new_run_error`). The factor is named as a fraction, since the
    user may not have typed it."""
    n = recipe.source_downscale
    folder = next((p.name for p in recipe.path.parents if p.name.endswith(f"_{n}")), recipe.path.parent.name)
    return (f"regenerate {folder} at {expected} (1/{n} of the camera's size), or remove {folder} to have the "
            "full-size images shrunk as they load")


def _size_fix(kind: PixelKind, noun: str, turned: bool) -> str:
    """What to do about a file whose size is not its camera's. Turned on its side, a colour image may be the camera's
    w and h given the wrong way round, or a photo stored on its side (its EXIF orientation, which is not applied); a
    mask or depth map is its own fault, since each frame's colour image is decoded, and checked, first."""
    if not turned and kind != "color":
        return f"make the {noun} at its image's size, which is the camera's"
    if not turned:
        return "make all images match the intrinsics (w, h) or fix the camera size"
    if kind != "color":
        return f"turn the {noun} a quarter turn, to lie as its image does (whose size is the camera's)"
    return ("swap the camera's width and height (and its cx and cy if they are swapped too), or, if the photo is "
            "stored on its side (an EXIF orientation, which is not applied), save it upright")


def _undistort(values: np.ndarray, recipe: PixelRecipe) -> np.ndarray:
    distortion = recipe.distortion
    if distortion is None or distortion.is_identity():
        return values
    height, width = values.shape[:2]
    sx, sy = width / recipe.width, height / recipe.height
    K_src = _to_opencv(scale_intrinsics(np.array(recipe.K), sx, sy))
    K_dst = _to_opencv(scale_intrinsics(np.array(recipe.K_undistorted), sx, sy))
    D = np.array(distortion.coeffs, dtype=np.float64)
    if distortion.model == "OPENCV_FISHEYE":
        map_x, map_y = cv2.fisheye.initUndistortRectifyMap(K_src, D.reshape(4, 1), np.eye(3), K_dst,
                                                           (width, height), cv2.CV_32FC1)
    else:
        map_x, map_y = cv2.initUndistortRectifyMap(K_src, D, None, K_dst, (width, height), cv2.CV_32FC1)
    interpolation = cv2.INTER_LINEAR if recipe.kind == "color" else cv2.INTER_NEAREST
    return cv2.remap(values, map_x, map_y, interpolation, borderMode=cv2.BORDER_REPLICATE)


def _resize(values: np.ndarray, recipe: PixelRecipe) -> np.ndarray:
    height, width = values.shape[:2]
    size = (recipe.target_width, recipe.target_height)
    if size == (width, height):
        return values
    if recipe.kind != "color":  # the source pixel nearest each target centre, as INTER_AREA centres colour
        interpolation = cv2.INTER_NEAREST_EXACT
    elif recipe.target_width < width:
        interpolation = cv2.INTER_AREA
    else:
        interpolation = cv2.INTER_LINEAR
    return cv2.resize(values, size, interpolation=interpolation)


def _quantise(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    if dtype == np.float32:
        return values.astype(np.float32)
    top = float(np.iinfo(dtype).max)
    return np.clip(np.round(values * top), 0, top).astype(dtype)


MIN_RESCALED_SIDE = 8
"""The smallest side a depth map rescaled to its camera is taken at: a 1x1 or 2x3 "map" matches any shape."""


def _is_rescaled(width: int, height: int, camera_width: int, camera_height: int) -> bool:
    """Whether a width x height map is the camera's image at another resolution: both sides scaled by one factor,
    each rounded down or up (so the two ranges of factors they allow overlap), and neither side one the camera has,
    which would make the other side a pixel or so off at the camera's own resolution."""
    if min(width, height) < MIN_RESCALED_SIDE or width == camera_width or height == camera_height:
        return False
    low = max((width - 1) / camera_width, (height - 1) / camera_height)
    high = min((width + 1) / camera_width, (height + 1) / camera_height)
    return low <= high


def _depth_at_camera_size(values: np.ndarray, recipe: PixelRecipe) -> np.ndarray:
    """A depth map stored at another resolution of its image's shape, brought to the camera's size by nearest
    neighbours, as nerfstudio reads one (depth sensors rarely match the colour camera's resolution); a map of
    another shape is left for `_check_size` to refuse."""
    height, width = values.shape[:2]
    if recipe.kind != "depth" or (width, height) == (recipe.width, recipe.height):
        return values
    if not _is_rescaled(width, height, recipe.width, recipe.height):
        return values
    return cv2.resize(values, (recipe.width, recipe.height), interpolation=cv2.INTER_NEAREST_EXACT)


def compute_pixels(recipe: PixelRecipe) -> np.ndarray:
    """Decode, composite, undistort and resize one file; returned at its storage dtype."""
    values, dtype = _read_source(recipe)
    values = _depth_at_camera_size(values, recipe)
    _check_size(recipe, *values.shape[:2])
    return _quantise(_resize(_undistort(values, recipe), recipe), dtype)


def as_float(stored: np.ndarray) -> np.ndarray:
    """A stored array as float32, integer images mapped to [0, 1]."""
    if stored.dtype == np.float32:
        return stored
    return stored.astype(np.float32) / float(np.iinfo(stored.dtype).max)


def default_cache_dir() -> Path:
    """$SPLATU_CACHE, else ~/.cache/splatu."""
    env = os.environ.get("SPLATU_CACHE", "")
    return Path(env) if env else Path.home() / ".cache" / "splatu"


@dataclass(frozen=True)
class ImageCache:
    """Processed per-view arrays on disk, one .npy each, keyed by a hash of their recipe."""

    directory: Path

    def key(self, recipe: PixelRecipe) -> str:
        """Hash of the source file's identity (path, mtime, size) and every processing setting."""
        stat = recipe.path.stat()
        parts = {
            "version": CACHE_VERSION,
            "path": str(recipe.path.resolve()),
            "mtime_ns": stat.st_mtime_ns,
            "size": stat.st_size,
            "recipe": [recipe.kind, recipe.width, recipe.height, recipe.target_width, recipe.target_height,
                       list(recipe.K), recipe.distortion and [recipe.distortion.model, list(recipe.distortion.coeffs)],
                       list(recipe.K_undistorted), recipe.source_downscale, list(recipe.background),
                       recipe.depth_scale],
        }
        return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:32]

    def load(self, recipe: PixelRecipe) -> np.ndarray:
        """The processed array (stored dtype), from the cache when present, else computed and stored."""
        if not recipe.path.is_file():
            return compute_pixels(recipe)  # raises the one-line "not found" error
        entry = self.directory / "pixels" / f"{self.key(recipe)}.npy"
        if entry.is_file():
            try:
                stored = np.load(entry)
            except (OSError, ValueError, EOFError):
                stored = None
            if stored is not None and _is_stored_form(stored, recipe):
                return stored
            entry.unlink(missing_ok=True)  # torn, emptied (a crash, a full disk) or not this array: recompute it
        pixels = compute_pixels(recipe)
        atomic_write(entry, lambda f: np.save(f, pixels),
                     fix="free space on that disk, or set SPLATU_CACHE to a writable folder with room for the images")
        return pixels


def _is_stored_form(stored: np.ndarray, recipe: PixelRecipe) -> bool:
    """Whether a cached array is what `compute_pixels` makes of `recipe`: its target size, channels (colour only)
    and a dtype `as_float` reads."""
    dtypes = (np.float32,) if recipe.kind == "depth" else (np.uint8, np.uint16)
    return (isinstance(stored, np.ndarray) and stored.dtype in dtypes
            and stored.shape[:2] == (recipe.target_height, recipe.target_width)
            and stored.ndim == (3 if recipe.kind == "color" else 2))


def load_pixels(recipe: PixelRecipe, cache: ImageCache) -> np.ndarray:
    """One processed array as float32, through the disk cache."""
    return as_float(cache.load(recipe))
