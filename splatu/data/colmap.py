"""COLMAP models (sparse/0, binary or text) through pycolmap.

COLMAP already uses OpenCV axes and world-to-camera poses, and puts pixel centres at +0.5
like splatu, so poses and K carry over unchanged; distorted models are undistorted with
OpenCV using the exactly equivalent OpenCV coefficients. COLMAP's three equidistant fisheye models
(SIMPLE_RADIAL_FISHEYE, RADIAL_FISHEYE, OPENCV_FISHEYE) are OpenCV's fisheye model with k1..k4, the missing
ones 0, as nerfstudio maps them (pycolmap's projection and cv2.fisheye.projectPoints agree to 1e-12 px).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from splatu.camera import Camera
from splatu.data.frames import FLOAT32_MAX, MAX_IMAGE_SIDE, Frame, RawScene, refuse_implausible_focal
from splatu.data.images import Distortion, PixelRecipe, undistorted_intrinsics
from splatu.data.principal_point import Misplaced, PrincipalPointFault, misplaced_principal_point, warn_misplaced
from splatu.data.pycolmap_quiet import pycolmap
from splatu.errors import SplatuError

PARAMETER_COUNTS = {"PINHOLE": 4, "SIMPLE_PINHOLE": 3, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8,
                    "SIMPLE_RADIAL_FISHEYE": 4, "RADIAL_FISHEYE": 5, "OPENCV_FISHEYE": 8}
"""The camera models we read, and how many parameters each takes (f or fx fy, cx cy, then distortion): a
cameras.txt line with another count fails pycolmap's VerifyParams check, whose message names no file or line."""
SUPPORTED_MODELS = tuple(PARAMETER_COUNTS)
SPARSE_CANDIDATES = ("sparse/0", "sparse", "colmap/sparse/0")
"""Where a scene folder may keep its model, relative to the folder (images/ beside sparse/)."""


MODEL_FILES = ("cameras", "images", "points3D")
"""A COLMAP model: these three files, all .bin or all .txt."""


def find_sparse_dir(root: Path) -> Path | None:
    """The folder holding a COLMAP model (or any of its files, so a missing one can be named) under a scene folder."""
    for candidate in SPARSE_CANDIDATES:
        folder = root / candidate
        if any((folder / f"{name}.{ext}").is_file() for name in MODEL_FILES for ext in ("bin", "txt")):
            return folder
    return None


def empty_sparse_dir(root: Path) -> Path | None:
    """The first model folder (sparse/0, ...) that exists under a scene folder where `find_sparse_dir` found no
    model file, as a failed COLMAP run leaves it: such a scene was "unknown format: no COLMAP sparse/0", with
    sparse/0 right there."""
    return next((root / c for c in SPARSE_CANDIDATES if (root / c).is_dir()), None)


def scene_root_of(sparse_dir: Path) -> Path | None:
    """The scene folder whose model `sparse_dir` is (for `--data` pointed at the model itself), or None.

    X/colmap/sparse/0 is both X/colmap's "sparse/0" and X's "colmap/sparse/0"; the root that has images/ wins,
    since that is where the images are read from.
    """
    roots = []
    for candidate in SPARSE_CANDIDATES:
        depth = len(Path(candidate).parts)
        root = sparse_dir.parents[depth - 1] if len(sparse_dir.parents) >= depth else None
        if root is not None and find_sparse_dir(root) == sparse_dir:
            roots.append(root)
    return next((root for root in roots if (root / "images").is_dir()), roots[0] if roots else None)


def model_files(sparse_dir: Path) -> dict[str, Path]:
    """The model's cameras, images and points3D files in one format, or a one-line error naming the missing ones."""
    found = {ext: [name for name in MODEL_FILES if (sparse_dir / f"{name}.{ext}").is_file()] for ext in ("bin", "txt")}
    ext = max(("bin", "txt"), key=lambda e: len(found[e]))  # the format most files are in; bin on a tie
    missing = [f"{name}.{ext}" for name in MODEL_FILES if name not in found[ext]]
    if missing:
        raise SplatuError(f"the COLMAP model has no {' or '.join(missing)}", f"in {sparse_dir}",
                          "export the whole model (cameras, images and points3D, all .bin or all .txt) from COLMAP")
    return {name: sparse_dir / f"{name}.{ext}" for name in MODEL_FILES}


def _signed(size: int) -> int:
    """A size pycolmap read as an unsigned 64-bit integer, as the signed number the file holds."""
    return size - (1 << 64) if size >= 1 << 63 else size


def opencv_camera(camera: pycolmap.Camera, where: str) -> tuple[np.ndarray, Distortion | None]:
    """K and OpenCV distortion equivalent to a COLMAP camera; unsupported models are a one-line error."""
    model = camera.model.name
    p = [float(v) for v in camera.params]
    fisheye = model.endswith("_FISHEYE")
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
    elif model == "SIMPLE_RADIAL_FISHEYE":  # COLMAP: r = f·θ(1 + k·θ²), OpenCV fisheye's with k1 = k
        f, cx, cy, k = p
        fx = fy = f
        coeffs = (k, 0.0, 0.0, 0.0)
    elif model == "RADIAL_FISHEYE":  # r = f·θ(1 + k1·θ² + k2·θ⁴)
        f, cx, cy, k1, k2 = p
        fx = fy = f
        coeffs = (k1, k2, 0.0, 0.0)
    elif model == "OPENCV_FISHEYE":  # r = f·θ(1 + k1·θ² + k2·θ⁴ + k3·θ⁶ + k4·θ⁸)
        fx, fy, cx, cy, k1, k2, k3, k4 = p
        coeffs = (k1, k2, k3, k4)
    else:
        raise SplatuError(f"unsupported COLMAP camera model {model}", where,
                          f"use one of {', '.join(SUPPORTED_MODELS)} (or run colmap image_undistorter first)")
    if not (np.isfinite(p).all() and fx > 0 and fy > 0):
        raise SplatuError(f"camera parameters {p} need a positive, finite focal length", where,
                          "fix the camera's parameters in the model, or re-run the reconstruction")
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    refuse_implausible_focal(K, camera.width, camera.height, where,
                             "give the camera's focal length in pixels (not mm), or re-run the reconstruction")
    if fisheye:  # without coefficients still a fisheye (r = f·θ), not a pinhole
        return K, Distortion("OPENCV_FISHEYE", coeffs)
    distortion = Distortion("OPENCV", coeffs) if any(coeffs) else None
    return K, distortion


def _principal_point_fix(kind: PrincipalPointFault) -> str:
    """How to mend a camera whose principal point `misplaced_principal_point` reads as mistake `kind`."""
    if kind == "swapped":
        return "swap the camera's WIDTH and HEIGHT, or its cx and cy, whichever pair is the wrong way round"
    return "give the camera's parameters in pixels of its WIDTH x HEIGHT, or re-run the reconstruction"


def _ascii_numeral(token: str) -> bool:
    """Whether `token` has none of what Python's int() and float() read but COLMAP's C++ reader does not: digits of
    other scripts, and _ between digits (the reader took CAMERA_ID 1_0 as 1 followed by a photo named "_0")."""
    return token.isascii() and "_" not in token


def _is_number(token: str, kind: type = float) -> bool:
    """Whether COLMAP's C++ reader would parse `token` as a finite `kind` (it rejects nan and inf)."""
    if not _ascii_numeral(token):
        return False
    try:
        return math.isfinite(kind(token))
    except (ValueError, OverflowError):
        return False


ID_LIMIT = (1 << 32) - 1
"""COLMAP keeps camera and image ids (and a 2D point's index) as 32-bit unsigned integers whose largest value
means "invalid"; 3D point ids are 64-bit."""


def _is_id(token: str, limit: int = ID_LIMIT) -> bool:
    """Whether `token` is an id COLMAP's reader can hold: an integer from 0 below `limit`. A larger one fails its
    reader, which names no line (and numpy could not even test an integer that large for finiteness)."""
    if not _ascii_numeral(token):
        return False
    try:
        return 0 <= int(token) < limit
    except ValueError:
        return False


def _valid_text_line(name: str, tokens: list[str]) -> bool:
    """Whether one data line of a COLMAP text file has the fields COLMAP's reader expects."""
    numbers = [_is_number(t) for t in tokens]
    if name == "cameras":
        count = PARAMETER_COUNTS.get(tokens[1]) if len(tokens) > 1 else None
        return (len(tokens) >= 5 and _is_id(tokens[0]) and all(numbers[2:])
                and all(_is_number(t, int) for t in tokens[2:4]) and (count is None or len(tokens) == 4 + count))
    if name == "points3D":  # POINT3D_ID, X, Y, Z, R, G, B (integers), ERROR, then (IMAGE_ID, POINT2D_IDX) pairs
        return (len(tokens) >= 8 and len(tokens) % 2 == 0 and all(numbers) and _is_id(tokens[0], (1 << 64) - 1)
                and all(_is_number(t, int) for t in tokens[4:7]) and all(_is_id(t) for t in tokens[8:]))
    return _is_pose(tokens) or (_is_points(tokens) and _bad_point3d_ref(tokens) is None)


POINT3D_REF_LIMIT = 1 << 63
"""COLMAP's reader takes a 2D point's POINT3D_ID as a signed 64-bit integer (-1 for none): a larger one failed pycolmap
naming no line, and one written 7.0 or 1e3 was read as 7 or 1 with the rest of the line shifted."""


def _bad_point3d_ref(tokens: list[str]) -> str | None:
    """Why the first POINT3D_ID of a 2D points line is none the reader can hold (`POINT3D_REF_LIMIT`), if one is not."""
    return next((f"POINT3D_ID {token} is not a whole number from {-POINT3D_REF_LIMIT} to {POINT3D_REF_LIMIT - 1} "
                 "(-1 for none)" for token in tokens[2::3]
                 if not (_is_number(token, int) and -POINT3D_REF_LIMIT <= int(token) < POINT3D_REF_LIMIT)), None)


def _is_points(tokens: list[str]) -> bool:
    """Whether an images.txt line is a line of 2D points (X, Y, POINT3D_ID triples; empty for none)."""
    return len(tokens) % 3 == 0 and all(_is_number(t) for t in tokens)


def _is_pose(tokens: list[str]) -> bool:
    """Whether an images.txt line is a pose line: IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME."""
    return (len(tokens) >= 10 and _is_id(tokens[0]) and all(_is_number(t) for t in tokens[1:8])
            and _is_id(tokens[8]) and not _is_points(tokens))


def _numbered_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(line number, line with its ending) of each line of a COLMAP text file; bytes that are no UTF-8 read as U+FFFD.
    \\n, \\r\\n and a lone \\r each end a line, as in an editor; COLMAP's reader ends one at \\n alone (and trims
    the \\r of \\r\\n), so the two count alike once `_line_error` has refused a lone \\r."""
    with path.open(encoding="utf-8", errors="replace", newline="") as lines:
        yield from enumerate(lines, start=1)


_TOKEN = re.compile(r"[^ \t\n\v\f\r]+")
"""A field as COLMAP's reader (a C++ stream) finds one: between ASCII whitespace only. Python's str.split also splits
at a no-break space, U+3000 and the like, which the reader keeps inside a field: a line spaced by them passed the
check and failed pycolmap naming no line, and a name holding one was refused as a name with a space."""


def _tokens(line: str) -> list[str]:
    """The fields of one line of a COLMAP text file, as its reader splits it (`_TOKEN`)."""
    return _TOKEN.findall(line)


def _is_skipped(line: str) -> bool:
    """Whether COLMAP's reader skips a line where it expects a camera, pose or point: blank or a comment once trimmed
    of spaces, tabs, CR and LF, as its trim does (not of \\v or \\f: a line of them, or a comment indented by one, is
    read as data, and fails)."""
    trimmed = line.strip(" \t\n\r")
    return not trimmed or trimmed.startswith("#")


def _data_lines(path: Path) -> Iterator[tuple[int, list[str]]]:
    """(line number, tokens) of each line of a COLMAP text file that its reader does not skip (`_is_skipped`)."""
    for number, line in _numbered_lines(path):
        if not _is_skipped(line):
            yield number, _tokens(line)


ID_FIELDS = {"cameras": ((0, "CAMERA_ID"),), "images": ((0, "IMAGE_ID"), (8, "CAMERA_ID")),
             "points3D": ((0, "POINT3D_ID"),)}
"""The ids that lead each kind of line (an images.txt pose line's CAMERA_ID too), by field index and name."""


def _bad_id(name: str, tokens: list[str]) -> str | None:
    """Which leading id of a line that does not parse is a number but no id (1.5, -1, 1e3), said by its field's name,
    since a quoted pose line is cut before its CAMERA_ID. COLMAP's reader took 1.5 as id 1 followed by a field ".5",
    so an images.txt CAMERA_ID of 1.5 loaded the photo named ".5", and an IMAGE_ID of 1.5 one named "1"."""
    if name == "images" and (len(tokens) < 10 or _is_number(tokens[9])):  # a points line: no NAME in field 10
        return None
    limit = (1 << 64) - 1 if name == "points3D" else ID_LIMIT
    return next((f"{field} {tokens[index]} is not an id, a whole number from 0 to {limit - 1}"
                 for index, field in ID_FIELDS[name]
                 if index < len(tokens) and _is_number(tokens[index]) and not _is_id(tokens[index], limit)), None)


def _text_line_error(path: Path, name: str, number: int, tokens: list[str], line: str) -> SplatuError | None:
    """The error for one data line of a COLMAP text file that COLMAP's reader would refuse or misread, if any; a line
    without fields (of \\v or \\f alone) is quoted as it is."""
    if not _valid_text_line(name, tokens):
        points = name == "images" and _is_points(tokens)  # numbers in threes, but a POINT3D_ID the reader cannot hold
        reason = ((_bad_point3d_ref(tokens) if points else _bad_id(name, tokens))
                  or repr((" ".join(tokens) or line.rstrip("\r\n"))[:60]))
        return SplatuError(f"cannot parse {path.name} line {number} ({reason})", f"in {path}",
                           "fix that line or export the model from COLMAP again")
    if name == "points3D" and not all(0 <= int(value) <= 255 for value in tokens[4:7]):
        return SplatuError(f"point {tokens[0]}'s colour ({', '.join(tokens[4:7])}) is not RGB from 0 to 255",
                           f"in {path} line {number}", "give R, G and B as whole numbers from 0 to 255")
    return None


def _line_error(path: Path, name: str, number: int, line: str) -> tuple[list[str], SplatuError | None]:
    """The tokens of one line of a COLMAP text file, and the error if COLMAP's reader would refuse or misread it. A
    line ended by a lone \\r (as classic Mac OS saved text) is refused: COLMAP reads it and the next as one line, so
    such an images.txt read as one comment line, a model of no image, without a word. (Ending a file's last line, a
    lone \\r is harmless, but it never comes alone.)"""
    if line.endswith("\r"):
        return [], SplatuError(f"{path.name} line {number} ends in a lone carriage return (CR), which COLMAP does not "
                               "read as the end of a line", f"in {path}",
                               "save the file with LF (or CRLF) line endings")
    if _is_skipped(line):
        return [], None
    return (tokens := _tokens(line)), _text_line_error(path, name, number, tokens, line)


_FLOAT = r"-?[0-9]{1,20}+\.?[0-9]{0,30}+(?:e[-+][0-9][0-9])?+"
"""A number as COLMAP writes one (17 or 6 significant digits, an exponent of two digits), in ASCII: below 1e50
before its exponent and at most 1e99 in it, so always finite for float(). Possessive quantifiers (+) make every
field match one way only, so a line that fails does so in time linear in its length."""
_ID = "[0-9]{1,9}+"
"""An id below 10**9, so below ID_LIMIT; int() and float() read it (leading zeros too)."""
_POINT3D_ID = "[0-9]{1,18}+"
"""A 3D point's id below 10**18, so below its 64-bit limit."""
_POINT3D_REF = "-?[0-9]{1,18}+"
"""A 2D point's POINT3D_ID, -1 or an id below 10**18, so within its signed 64-bit range (`POINT3D_REF_LIMIT`)."""
_NAME = "[!-~]+"
"""An image's name in printable ASCII, so without a space or any other whitespace."""
_CHANNEL = "(?>25[0-5]|2[0-4][0-9]|1[0-9][0-9]|[1-9]?[0-9])"
"""A colour channel, 0 to 255 spelt out."""
_LINE_END = r"(?:\r?\n)?"
"""The end of a line as `_numbered_lines` hands it over, LF or CRLF (none on a last line): no other whitespace, and
no lone CR, ends a fast line."""
FAST_LINES = {
    "points3D": re.compile(rf"{_POINT3D_ID} {_FLOAT} {_FLOAT} {_FLOAT} {_CHANNEL} {_CHANNEL} {_CHANNEL} {_FLOAT}"
                           rf"(?: {_ID} {_ID})*+{_LINE_END}"),
    "pose": re.compile(rf"{_ID}{f' {_FLOAT}' * 7} {_ID} {_NAME}{_LINE_END}"),
    "points2D": re.compile(rf"{_FLOAT} {_FLOAT} {_POINT3D_REF}(?: {_FLOAT} {_FLOAT} {_POINT3D_REF})*+{_LINE_END}"),
}
"""Lines of a large model that are certainly valid, matched whole without splitting them into tokens (7 times
faster than the per-token check on a model of 1M points, docs/results.md; every other line still gets that check,
which words every error).

Each accepts only lines that `_line_error` passes, in the same line numbering (`_numbered_lines`): fields are
ASCII, one space apart, so `_tokens` finds exactly these tokens; every one is a finite number (`_FLOAT`, `_ID`,
`_CHANNEL`); ids have at most 9 digits (a POINT3D_ID 18), so they are ids below their limits; colours are 0–255.
A points3D line has 8 fields then (IMAGE_ID, POINT2D_IDX) pairs of ids; a pose line 10, IMAGE_ID, 7 numbers,
CAMERA_ID and a NAME of printable ASCII (10 fields is no multiple of 3, so no points line either: it is a pose
line with a name without a space); a 2D points line numbers in threes, each third an integer of at most 18 digits
(`_POINT3D_REF`), never a pose line, by `_is_pose`.
Both paths get the same lines (`_numbered_lines`): a CRLF file's take the fast path too, one ended by a lone CR
never. Anything else, a comment, a blank line, a tab, '+5', '.5', '1e5', a colour 007, digits of other scripts,
goes to the per-token check, which decides and words the error as it always has. cameras.txt, a line per camera,
has no fast path.
"""


def _file_error(path: Path, name: str) -> SplatuError | None:
    """The first line of a cameras.txt or points3D.txt that COLMAP's reader would refuse or misread, if any."""
    fast = FAST_LINES.get(name)
    for number, line in _numbered_lines(path):
        if fast is not None and fast.fullmatch(line):
            continue
        if (error := _line_error(path, name, number, line)[1]) is not None:
            return error
    return None


def _images_errors(path: Path) -> tuple[SplatuError | None, SplatuError | None]:
    """In one pass over an images.txt, following its reader: the first line that COLMAP's reader would refuse or
    misread (`_order_error` too), and the first fault of its layout that the reader takes without a word
    (`_layout_error`). The reader skips blank and comment lines where it expects a pose, and takes the line after
    each pose, whatever it holds, as that image's 2D points."""
    pose_after_pose = spaced_name = None
    points_next = False
    for number, line in _numbered_lines(path):
        if FAST_LINES["pose"].fullmatch(line):
            pose = True
        elif FAST_LINES["points2D"].fullmatch(line):
            pose = False
        else:
            tokens, error = _line_error(path, "images", number, line)
            if error is not None:
                return error, None
            if not points_next and _is_skipped(line):
                continue
            pose = _is_pose(tokens)
            if pose and len(tokens) > 10 and spaced_name is None:
                spaced_name = (number, " ".join(tokens[9:]))
        if points_next:
            if pose and pose_after_pose is None:
                pose_after_pose = number
            points_next = False
        elif pose:
            points_next = True
        else:
            return _order_error(path, number, pose_after_pose), None
    if points_next:
        return _order_error(path, None, pose_after_pose), None
    return None, _layout_error(path, pose_after_pose, spaced_name)


def _order_error(path: Path, number: int | None, pose_after_pose: int | None) -> SplatuError:
    """The error for an images.txt whose line `number` is no pose where the reader expects one (a comment or blank
    line between a pose and its 2D points, a second points line), which pycolmap refuses naming no line, or which
    (with 10 numbers or more) it reads as a pose; or (`number` None) whose last pose has no line after it, an image
    the reader leaves out without a word. A pose after a pose before it is the likelier cause, so it is named."""
    if pose_after_pose is not None:
        return _layout_error(path, pose_after_pose, None)
    fix = "give each image two lines, its pose then its 2D points (an empty line when it has none)"
    if number is None:
        return SplatuError(f"{path.name} ends with an image's pose without the line of its 2D points after it, so "
                           "COLMAP would leave that image out", f"in {path}", f"{fix}, the last one too")
    return SplatuError(f"{path.name} line {number} is not an image's pose (IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, "
                       "CAMERA_ID, NAME), which COLMAP reads there: it reads the line right after each pose as that "
                       "image's 2D points", f"in {path}", f"{fix}, with no comment or blank line between them")


def _layout_error(path: Path, pose_after_pose: int | None, spaced_name: tuple[int, str] | None) -> SplatuError | None:
    """The error for an images.txt whose every line parses but which COLMAP's reader misreads silently: a pose line
    right after a pose line (the reader takes the line after each pose as its 2D points, blank or not, so a file
    whose empty points lines were removed read as every other image), else a pose line whose name holds a space
    (the reader takes a name up to its first space, so `my photo.jpg` was looked for as `my`)."""
    if pose_after_pose is not None:
        return SplatuError(f"{path.name} line {pose_after_pose} is an image's pose where COLMAP reads the 2D points "
                           "of the image on the line before, so every other image would be lost", f"in {path}",
                           "give each image two lines, its pose then its 2D points (an empty line when it has none)")
    if spaced_name is not None:
        return SplatuError(f"{path.name} line {spaced_name[0]} names image {spaced_name[1]!r}, but COLMAP's text "
                           "format reads a name only up to its first space", f"in {path}",
                           "rename the photo and its entry without spaces, or export the model as .bin")
    return None


def text_model_errors(files: dict[str, Path]) -> tuple[SplatuError | None, SplatuError | None]:
    """For a text model, (the first line COLMAP's reader would refuse, naming no line, or misread without a word: an
    id written 1.5 shifts the rest of its line, a colour of 300 wrapped round to 44; the first images.txt layout it
    misreads, `_layout_error`, raised only once pycolmap has read the model). (None, None) for a .bin model."""
    if files["cameras"].suffix != ".txt":
        return None, None
    if (error := _file_error(files["cameras"], "cameras")) is not None:
        return error, None
    error, layout = _images_errors(files["images"])
    if error is None:
        error = _file_error(files["points3D"], "points3D")
    return error, layout


def read_reconstruction(sparse_dir: Path) -> pycolmap.Reconstruction:
    """The model through pycolmap; a text file it cannot parse, or would misread, is named with its line (checked
    first: pycolmap reads some bad lines without a word)."""
    files = model_files(sparse_dir)
    error, layout = text_model_errors(files)
    if error is not None:
        raise error
    try:
        reconstruction = pycolmap.Reconstruction(str(sparse_dir))
    except Exception as err:  # pycolmap raises plain RuntimeError/ValueError on unreadable models
        raise _unreadable(sparse_dir, files, err) from None
    if layout is not None:
        raise layout
    return reconstruction


def broken_reference(files: dict[str, Path]) -> SplatuError | None:
    """In a text model whose every line parses, the first camera model COLMAP does not know, the first id that
    points at nothing, or the first track that names a 2D point images.txt gives to another 3D point: pycolmap names
    these in its own terms ("Rig with ID 7 does not exist", "Check failed: point2D.point3D_id == point3D_id (8 vs.
    7)"), without file or line."""
    cameras, images = files["cameras"], files["images"]
    camera_ids = set()
    for number, tokens in _data_lines(cameras):
        if tokens[1] not in pycolmap.CameraModelId.__members__:
            return SplatuError(f"unknown camera model {tokens[1]!r} (camera {tokens[0]})",
                               f"in {cameras} line {number}", f"use one of {', '.join(SUPPORTED_MODELS)}")
        camera_ids.add(int(tokens[0]))
    point_ids: dict[int, list[str]] = {}
    for number, tokens, ids in _poses_and_point_ids(images):
        point_ids[int(tokens[0])] = ids
        if int(tokens[8]) not in camera_ids:
            return SplatuError(f"image {tokens[9]} uses camera {tokens[8]}, which {cameras.name} does not define",
                               f"in {images} line {number}", "fix its CAMERA_ID or export the model from COLMAP again")
    for number, tokens in _data_lines(files["points3D"]):
        track = [(int(image), int(index)) for image, index in zip(tokens[8::2], tokens[9::2], strict=True)]
        missing = next((image for image, _ in track if image not in point_ids), None)
        if missing is not None:
            return SplatuError(f"point {tokens[0]}'s track names image {missing}, which {images.name} does not define",
                               f"in {files['points3D']} line {number}", "export the model from COLMAP again")
        beyond = next(((image, index) for image, index in track if index >= len(point_ids[image])), None)
        if beyond is not None:
            return SplatuError(f"point {tokens[0]}'s track names 2D point {beyond[1]} of image {beyond[0]}, which has "
                               f"{len(point_ids[beyond[0]])} in {images.name}", f"in {files['points3D']} line {number}",
                               "export the model from COLMAP again")
        other = next(((image, index, point_ids[image][index]) for image, index in track
                      if _other_point(point_ids[image][index], int(tokens[0]))), None)
        if other is not None:
            return SplatuError(f"point {tokens[0]}'s track names 2D point {other[1]} of image {other[0]}, which "
                               f"{images.name} gives to point {other[2]}", f"in {files['points3D']} line {number}",
                               "export the model from COLMAP again")
    return None


def _other_point(named: str, point_id: int) -> bool:
    """Whether a 2D point's POINT3D_ID `named` is another 3D point than `point_id`; -1, no point, is none (pycolmap
    accepts a track naming such a 2D point), and one that is no whole number is left to pycolmap's own words."""
    try:
        return int(named) not in (-1, point_id)
    except ValueError:
        return False


def _poses_and_point_ids(images: Path) -> Iterator[tuple[int, list[str], list[str]]]:
    """(line number, tokens, its 2D points' POINT3D_IDs) of each pose line of an images.txt: COLMAP reads the line
    after a pose, blank or not, as that image's 2D points, X Y POINT3D_ID triples that tracks index from 0."""
    with images.open(encoding="utf-8", errors="replace") as file:
        lines = list(file)
    for number, (line, after) in enumerate(zip(lines, [*lines[1:], ""], strict=True), start=1):
        tokens = _tokens(line)
        if _is_pose(tokens):  # a comment's first token starts with #, so it is no IMAGE_ID
            yield number, tokens, _tokens(after)[2::3]


def _unreadable(sparse_dir: Path, files: dict[str, Path], err: Exception) -> SplatuError:
    """The error for a model pycolmap could not read though every text line parses: a text model's broken
    reference, else pycolmap's reason."""
    if all(path.suffix == ".txt" for path in files.values()) and (error := broken_reference(files)) is not None:
        return error
    reason = re.sub(r"^\[[^]]*\]\s*", "", (str(err).strip().splitlines() or [type(err).__name__])[0])
    return SplatuError(f"pycolmap cannot read the COLMAP model ({reason})", f"in {sparse_dir}",
                       "export cameras, images and points3D from COLMAP again")


def _world_to_camera(image: pycolmap.Image, where: str) -> np.ndarray:
    """The image's 4x4 pose; pycolmap keeps the quaternion as written, so a zero one would silently be identity."""
    pose = image.cam_from_world()
    norm = pose.rotation.norm()
    fix = "re-run the reconstruction or delete the image from the model"
    if not np.isfinite(norm) or norm < 1e-6:
        raise SplatuError(f"image {image.name} has a zero or non-finite rotation quaternion", where, fix)
    pose.rotation.normalize()
    world_to_camera = np.eye(4)
    world_to_camera[:3] = pose.matrix()
    if not np.isfinite(world_to_camera).all():
        raise SplatuError(f"image {image.name} has a non-finite pose", where, fix)
    if (largest := float(np.abs(world_to_camera).max())) > FLOAT32_MAX:
        raise SplatuError(f"image {image.name} has a pose value beyond float32's range ({largest:.3g})", where, fix)
    return world_to_camera


def _image_name(image: pycolmap.Image, images_file: Path) -> str:
    """The image's file name; pycolmap hands names to Python as UTF-8, so another encoding's bytes raised a
    UnicodeDecodeError that named neither the image nor the file."""
    try:
        return image.name
    except UnicodeDecodeError:
        raise SplatuError(f"the name of image {image.image_id} is not UTF-8 text", f"in {images_file}",
                          "rename the photo to a UTF-8 name and run the reconstruction again") from None


def registered_images(reconstruction: pycolmap.Reconstruction, images_file: Path) -> list[pycolmap.Image]:
    """The images with a pose, sorted by name; two images with one name would both read the same file, each
    with its own pose, so they are refused."""
    named: dict[str, pycolmap.Image] = {}
    for image in reconstruction.images.values():
        name = _image_name(image, images_file)
        if name in named:
            first, second = sorted((named[name].image_id, image.image_id))
            raise SplatuError(f"images {first} and {second} both have the name {name!r}", f"in {images_file}",
                              "remove the duplicate image from the model or re-run the reconstruction")
        named[name] = image
    return [named[name] for name in sorted(named) if named[name].has_pose]


def refuse_unusable_point(points: np.ndarray, ids: list[int], points_file: Path) -> None:
    """One line naming the first point that is not finite in float32 (a .bin may hold NaN, a .txt 1e39): it seeds
    a Gaussian at infinity, and training ran on until the export refused the model as non-finite."""
    bad = ~(np.abs(points) <= FLOAT32_MAX).all(axis=1)
    if bad.any():
        index = int(bad.argmax())
        raise SplatuError(f"point {ids[index]} has a non-finite position or one beyond float32's range "
                          f"({points[index].tolist()})", f"in {points_file}",
                          "delete that point from the model or re-run the reconstruction")


def load_colmap(root: Path, sparse_dir: Path, warn_off_centre: bool = True) -> RawScene:
    """Registered images (sorted by name) with undistorted cameras at full size (images_N beside images/ holds copies
    at 1/N), and points3D with colours, with one warning line for principal points far off-centre unless not
    `warn_off_centre`."""
    reconstruction = read_reconstruction(sparse_dir)
    images_dir = root / "images"
    files = model_files(sparse_dir)
    intrinsics: dict[int, tuple[np.ndarray, Distortion | None, np.ndarray]] = {}
    frames: list[Frame] = []
    misplaced: list[Misplaced] = []
    for image in registered_images(reconstruction, files["images"]):
        colmap_camera = reconstruction.cameras[image.camera_id]
        if image.camera_id not in intrinsics:
            where = f"in {files['cameras']} (camera {image.camera_id})"
            width, height = (_signed(size) for size in (colmap_camera.width, colmap_camera.height))
            if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE):
                raise SplatuError(f"camera size {width}x{height} is not a plausible image size", where,
                                  "give the camera its image width and height in pixels")
            K, distortion = opencv_camera(colmap_camera, where)
            if (fault := misplaced_principal_point(float(K[0, 2]), float(K[1, 2]), width, height)) is not None:
                misplaced.append((f"camera {image.camera_id}", *fault))
            K_new = undistorted_intrinsics(K, distortion, colmap_camera.width, colmap_camera.height, where)
            intrinsics[image.camera_id] = (K, distortion, K_new)
        K, distortion, K_new = intrinsics[image.camera_id]
        world_to_camera = _world_to_camera(image, f"in {files['images']}")
        camera = Camera(
            K=torch.tensor(K_new, dtype=torch.float64),
            world_to_camera=torch.tensor(world_to_camera, dtype=torch.float64),
            width=colmap_camera.width, height=colmap_camera.height, name=image.name,
        )
        frames.append(Frame(name=image.name, camera=camera, image=PixelRecipe(
            path=images_dir / image.name, kind="color", width=colmap_camera.width, height=colmap_camera.height,
            target_width=camera.width, target_height=camera.height,
            K=tuple(K.ravel()) if distortion else (), distortion=distortion,
            K_undistorted=tuple(K_new.ravel()) if distortion else (),
        ), copies=images_dir))
    points3d = [point for _, point in sorted(reconstruction.points3D.items())]  # by id: a stable order
    points = np.array([p.xyz for p in points3d], dtype=np.float64).reshape(-1, 3)
    refuse_unusable_point(points, sorted(reconstruction.points3D), files["points3D"])
    colors = np.array([p.color for p in points3d], dtype=np.float32).reshape(-1, 3) / 255.0
    if warn_off_centre:
        warn_misplaced(misplaced, len(intrinsics), "cameras", files["cameras"], _principal_point_fix)
    return RawScene(name=root.name, source=str(sparse_dir), frames=frames, points=points, point_colors=colors)
