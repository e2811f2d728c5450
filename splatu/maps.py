"""The maps directory: one layout in which any method's uncertainty can be scored the same way.

    DIR/rgb/NAME.png           the method's render
    DIR/gt/NAME.png            the ground-truth image
    DIR/uncertainty/NAME.npy   float (H, W) uncertainty, finite
    DIR/mask/NAME.png          optional: non-zero = pixel is scored
    DIR/unobserved/NAME.png    optional: non-zero = no training camera saw this pixel (AUROC)

`render-uncertainty` writes it; `eval-ause --maps DIR` reads it. PNGs are written 16-bit so
the stored render is faithful to 1/65535; 8-bit PNGs from other tools read just as well.
"""

from __future__ import annotations

import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from splatu.atomic import swap_in_folder, temporary_sibling
from splatu.data.images import read_image, write_png
from splatu.errors import (
    SplatuError,
    a_few,
    load_number_array,
    no_empty_folders_left,
    os_error_behind,
    require_file,
    unwritable_folder,
)

FOLDERS = ("rgb", "gt", "uncertainty", "mask", "unobserved")


@dataclass(frozen=True)
class MapEntry:
    """One scored view: render, ground truth and uncertainty of the same size."""

    name: str
    rgb: np.ndarray  # (H, W, 3) float in [0, 1]
    gt: np.ndarray  # (H, W, 3) float in [0, 1]
    uncertainty: np.ndarray  # (H, W) float
    mask: np.ndarray | None = None  # (H, W) bool, True = scored
    unobserved: np.ndarray | None = None  # (H, W) bool, True = never seen in training


def safe_name(name: str) -> str:
    """A view name usable as a file stem: the last component's extension removed, path separators made `_`; "." and
    ".." dropped and a leading dot made `_`, so that no file is hidden (`../../x` was written as `.._.._x_*.npy`,
    which `ls` leaves out). "" when no component is left."""
    parts = [part for part in name.replace("\\", "/").split("/") if part not in ("", ".", "..")]
    parts = ["_" * (len(part) - len(part.lstrip("."))) + part.lstrip(".") for part in parts]
    return "_".join([*parts[:-1], PurePosixPath(parts[-1]).stem]) if parts else ""


LONGEST_SUFFIX = len("_uncertainty.npy")
"""The longest ending render-uncertainty adds to a view's stem (npy/NAME_uncertainty.npy)."""
NAME_MAX = 255
"""Bytes in one file name on Linux, macOS and Windows file systems."""


def _unwritable(name: str) -> str | None:
    """What keeps a view name from naming files, if anything: a --cameras file_path of "", ".", ".." or "/" (no stem:
    a ValueError deep in pathlib), one holding a NUL byte (a ValueError from open) or one too long for the file system
    (an OSError whose advice was to free disk space)."""
    if not safe_name(name):
        return "has no file name"
    if "\0" in name:
        return "holds a NUL character"
    if len(safe_name(name).encode("utf-8", "surrogateescape")) > NAME_MAX - LONGEST_SUFFIX:
        return f"is longer than the {NAME_MAX - LONGEST_SUFFIX} bytes a file name leaves for it"
    return None


def file_stems(names: list[str], where: str = "in the scene's image names") -> list[str]:
    """`safe_name` of each view, refusing a name no file can take and two views that would share files (one would
    overwrite the other)."""
    for name in names:
        if (problem := _unwritable(name)) is not None:
            raise SplatuError(f"view name {name[:60]!r}{'…' if len(name) > 60 else ''} {problem}, so its maps "
                              "cannot be written", where, "name the view by a short file name (for --cameras, each "
                              "frame's file_path, e.g. \"candidate_0\")")
    stems = [safe_name(name) for name in names]
    first_of: dict[str, str] = {}
    for name, stem in zip(names, stems, strict=True):
        if stem in first_of:
            raise SplatuError(f"views {first_of[stem]!r} and {name!r} would both be written as {stem!r}",
                              where, "rename one of the two")
        first_of[stem] = name
    return stems


def _read_png(path: Path) -> np.ndarray:
    """An 8- or 16-bit PNG as float64 in [0, 1], RGB(A)."""
    fix = "remove the view from every folder"
    image = read_image(require_file(path, "image", f"write it or {fix}"), or_else=fix)
    return image.astype(np.float64) / (65535.0 if image.dtype == np.uint16 else 255.0)


def _read_rgb(path: Path) -> np.ndarray:
    """RGB of a colour PNG; one with transparent pixels is refused, as its colour there is not what a render shows."""
    image = _read_png(path)
    if image.ndim != 3 or image.shape[2] < 3:
        raise SplatuError(f"expected a colour image, got shape {image.shape}", f"in {path}", "save it as RGB")
    if image.shape[2] > 3 and image[..., 3].min() < 1.0:
        raise SplatuError("image has transparent pixels", f"in {path}",
                          "composite it on the background the render used and save it as RGB")
    return image[..., :3]


def _read_binary(path: Path, shape: tuple[int, ...]) -> np.ndarray:
    """Non-zero pixels of a mask PNG: grey or colour values, or the alpha channel of one whose colour is uniform."""
    image = _read_png(path)
    if image.ndim == 3:
        has_alpha = image.shape[2] in (2, 4)  # grey or RGB, plus alpha
        colour = image[..., : image.shape[2] - has_alpha].max(axis=-1)
        image = image[..., -1] if has_alpha and colour.min() == colour.max() else colour
    binary = image > 0
    if binary.shape != shape:
        raise SplatuError(f"mask is {binary.shape[1]}x{binary.shape[0]} but the render is {shape[1]}x{shape[0]}",
                          f"in {path}", "write masks at the render's size")
    return binary


def read_entry(root: Path, name: str) -> MapEntry:
    """Load one view of a maps directory, checking every size and value."""
    rgb = _read_rgb(root / "rgb" / f"{name}.png")
    gt_path = root / "gt" / f"{name}.png"
    gt = _read_rgb(gt_path)
    if gt.shape != rgb.shape:
        raise SplatuError(f"ground truth is {gt.shape[1]}x{gt.shape[0]} "
                          f"but the render is {rgb.shape[1]}x{rgb.shape[0]}", f"in {gt_path}",
                          "write both at the same resolution")
    u_path = root / "uncertainty" / f"{name}.npy"
    uncertainty = load_number_array(require_file(u_path, "uncertainty map", "write it with numpy.save"),
                                    "uncertainty map", "write it with numpy.save(path, float_array)")
    if uncertainty.shape != rgb.shape[:2]:
        size = "x".join(map(str, uncertainty.shape[::-1])) if uncertainty.ndim == 2 else f"shape {uncertainty.shape}"
        raise SplatuError(f"uncertainty map is {size} {uncertainty.dtype}, but the render is "
                          f"{rgb.shape[1]}x{rgb.shape[0]}", f"in {u_path}",
                          "save one float value per pixel of the render")
    uncertainty = uncertainty.astype(np.float64)
    if not np.isfinite(uncertainty).all():
        raise SplatuError("uncertainty map contains NaN or Inf", f"in {u_path}", "write finite values only")
    optional = {folder: root / folder / f"{name}.png" for folder in ("mask", "unobserved")}
    present = {folder: _read_binary(path, rgb.shape[:2]) for folder, path in optional.items() if path.is_file()}
    if "mask" in present and not present["mask"].any():
        raise SplatuError("mask selects no pixels", f"in {optional['mask']}",
                          "mark the pixels to score with non-zero values, or remove the mask")
    return MapEntry(name, rgb, gt, uncertainty, present.get("mask"), present.get("unobserved"))


def _instead_of_no_maps(root: Path, folder: str) -> str:
    """The fix for a --maps folder without `folder`: the maps of the renders beneath it (a render's folder, the run's
    uncertainty/ or the run itself: RUN/uncertainty/<label>/maps), and --load for a run."""
    found = sorted(maps for pattern in ("maps", "*/maps", "*/*/maps") for maps in root.glob(pattern)
                   if (maps / folder).is_dir())
    is_run = any((root / name).exists() for name in ("config.yml", "checkpoints", "ensemble.json"))
    load = f"--load {shlex.quote(str(root))} to render this run's eval views and score them"
    if found:
        maps = (f"pass --maps {a_few(found)}, the maps of this render" if found == [root / "maps"]
                else f"pass --maps with the maps of a render beneath it: {a_few(found)}")
        return f"{maps}, or {load}" if is_run else maps
    return f"pass {load}" if is_run else "lay it out as rgb/NAME.png, gt/NAME.png, uncertainty/NAME.npy"


def entry_names(root: Path) -> list[str]:
    """The views of a maps directory, checking that rgb/, gt/ and uncertainty/ name the same ones."""
    if not root.is_dir():
        raise SplatuError("maps directory not found", f"in {root}", "pass a directory written by render-uncertainty")
    stems = {}
    for folder, suffix in (("rgb", ".png"), ("gt", ".png"), ("uncertainty", ".npy")):
        if not (root / folder).is_dir():
            raise SplatuError(f"maps directory has no {folder}/ folder", f"in {root}",
                              _instead_of_no_maps(root, folder))
        stems[folder] = {p.stem for p in (root / folder).glob(f"*{suffix}")}
    if not stems["uncertainty"]:
        raise SplatuError("maps directory has no uncertainty maps", f"in {root / 'uncertainty'}",
                          "write one NAME.npy per view")
    for folder in ("rgb", "gt"):
        missing = stems["uncertainty"] - stems[folder]
        if missing:
            raise SplatuError(f"{len(missing)} uncertainty maps have no {folder}/ image (e.g. {sorted(missing)[0]!r})",
                              f"in {root / folder}", f"write {folder}/NAME.png for every uncertainty/NAME.npy")
    unscored = stems["rgb"] - stems["uncertainty"]  # a view whose map was lost would silently drop out of the score
    if unscored:
        raise SplatuError(f"{len(unscored)} renders have no uncertainty map (e.g. {sorted(unscored)[0]!r})",
                          f"in {root / 'uncertainty'}", "write uncertainty/NAME.npy for every rgb/NAME.png, or "
                          "remove the view's files from every folder")
    for folder, consequence in (("mask", "would be scored on every pixel"),
                                ("unobserved", "would drop out of AUROC-unobserved's average")):
        present = {p.stem for p in (root / folder).glob("*.png")}
        lacking = stems["uncertainty"] - present if present else set()
        if lacking:  # a view missing from a folder the others use is a lost file, not a choice
            raise SplatuError(f"{len(lacking)} views have no {folder}/ map (e.g. {sorted(lacking)[0]!r}), so they "
                              f"{consequence}", f"in {root / folder}",
                              f"write {folder}/NAME.png for every view, or remove the {folder}/ folder")
    return sorted(stems["uncertainty"])


def _write_png(path: Path, image: np.ndarray) -> None:
    """[0, 1] values as 16-bit PNG, so the scored colours lose next to nothing to quantisation."""
    write_png(path, np.round(np.clip(image, 0.0, 1.0) * 65535.0).astype(np.uint16),
              "check the output directory is writable")


def write_entry(root: Path, entry: MapEntry) -> None:
    """Write one view in the maps layout, creating the folders it needs."""
    for folder in FOLDERS:
        if folder in ("rgb", "gt", "uncertainty") or getattr(entry, folder) is not None:
            (root / folder).mkdir(parents=True, exist_ok=True)
    _write_png(root / "rgb" / f"{entry.name}.png", entry.rgb)
    _write_png(root / "gt" / f"{entry.name}.png", entry.gt)
    np.save(root / "uncertainty" / f"{entry.name}.npy", entry.uncertainty.astype(np.float32))
    for folder in ("mask", "unobserved"):
        binary = getattr(entry, folder)
        if binary is not None:
            _write_png(root / folder / f"{entry.name}.png", binary.astype(np.float64))


def write_maps_dir(root: Path, entries: list[MapEntry], extra_files: dict[str, str] | None = None
                   ) -> list[MapEntry]:
    """Write a whole maps directory beside `root`, then put it in place of any earlier one: a crash mid-write
    leaves the earlier directory or none, never one with views missing or lacking their masks, which
    `eval-ause --maps` would score without complaint; a write refused (a full disk) leaves no folder made for it.
    `extra_files` (name → text) go in with the views.

    Returns the views as stored (read back before the swap), which is what `eval-ause --maps` reads: a caller
    scores those rather than `root`, which another process may replace at any time.
    """
    staging = temporary_sibling(root)
    shutil.rmtree(staging, ignore_errors=True)
    with no_empty_folders_left(root.parent):  # made for the staging folder, and empty again if it fails
        try:
            staging.mkdir(parents=True)
            for entry in entries:
                write_entry(staging, entry)
            for name, text in (extra_files or {}).items():
                (staging / name).write_text(text, encoding="utf-8")
            stored = [read_entry(staging, name) for name in entry_names(staging)]
            swap_in_folder(staging, root)
        except OSError as err:
            if os_error_behind(err) is None:
                raise
            raise unwritable_folder(root, err) from None
        finally:
            shutil.rmtree(staging, ignore_errors=True)
    return stored
