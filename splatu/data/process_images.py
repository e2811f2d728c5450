"""`splatu process-images`: a folder of photos to a COLMAP model the loader reads.

Runs pycolmap's SIFT extraction, matching and incremental mapping on the CPU, then writes
the largest model to <output>/sparse/0 and links <output>/images to the photos, which is the
layout `--data <output>` detects as COLMAP.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import os
import re
import shlex
import shutil
import socket
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, TypeVar

import tyro
from rich.console import Console

from splatu.atomic import swap_in_folder
from splatu.data.images import IMAGE_SUFFIXES, read_image
from splatu.data.pycolmap_quiet import pycolmap
from splatu.data.resolve import colmap_data_path
from splatu.errors import SplatuError, creatable_dir
from splatu.interrupts import finish_first

T = TypeVar("T")


@dataclass
class ProcessImagesConfig:
    images: tyro.conf.Positional[Path]
    """Folder of photos of one static scene."""
    output: Path | None = None
    """Scene folder to write (sparse/0, images link, database.db); None: the parent of a folder named images, else
    <folder>-colmap beside the photos' folder."""
    matcher: Literal["exhaustive", "sequential"] = "exhaustive"
    """exhaustive: all pairs (best for < ~200 photos); sequential: neighbours in file order (video frames)."""
    camera_model: Literal["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"] = "SIMPLE_RADIAL"
    """COLMAP camera model to estimate; all of these are ones the COLMAP loader undistorts."""
    single_camera: bool | None = None
    """None: one camera shared by all photos when they are all of one size (one phone or video), else one per photo;
    True: always one (refused for photos of several sizes, which COLMAP cannot share one camera between); False:
    intrinsics estimated per photo."""
    max_image_size: int = 1600
    """Photos are downscaled to at most this many pixels on their longer side for feature extraction (at least 1;
    one at least their longer side keeps them at full size)."""
    overwrite: bool = False
    """Replace an existing database.db and sparse/0 in the output folder (only once the new model is complete)."""
    colmap_log: bool = False
    """Also show COLMAP's own (verbose) log lines: its progress, warnings and errors, such as why a photo was
    unreadable (without it splatu says in its own lines which photos it skipped and what failed)."""

    def validate(self) -> None:
        """Refuse an option COLMAP would not take as given, before any work: it reads a max_image_size of 0 or
        below as its own default, 3200 px, so such a value silently extracted at another size than asked."""
        if self.max_image_size < 1:
            raise SplatuError(f"--max-image-size must be a positive number of pixels (got {self.max_image_size})",
                              "in the options", "pass e.g. --max-image-size 1600 (the default), or one at least the "
                              "photos' longer side to extract features at full size")


def default_output(images: Path) -> Path:
    """scene/images -> scene; any other folder -> <folder>-colmap beside it."""
    return images.parent if images.name == "images" else images.with_name(f"{images.name}-colmap")


def _photo_name(path: Path) -> str:
    """The name COLMAP gets for a photo, once it is known to be a file with a UTF-8 name: a symlink loop aborted
    pycolmap's reader (killing the process), and pycolmap refused a name in another encoding with a TypeError."""
    if not path.is_file():
        raise SplatuError("not a photo file (a folder, a broken link or a link loop)", f"in {path}",
                          "remove it, or make it the photo it names")
    try:
        path.name.encode("utf-8")
    except UnicodeEncodeError:
        raise SplatuError("the photo's name is not UTF-8 text", f"in {path}", "rename it to a UTF-8 name") from None
    return path.name


PHOTO_KINDS = "/".join(sorted(suffix[1:] for suffix in IMAGE_SUFFIXES))


def _photos(images: Path) -> tuple[list[str], list[str]]:
    """The photos' names, in file order, and the other files' (hidden ones aside); too few photos is one line that
    names what was skipped, since a folder of HEIC photos, or of subfolders, otherwise reads as an empty one."""
    if images.is_file():  # one photo, as a file picker or a shell's completion gives it
        raise SplatuError("this is a file; process-images takes the folder of photos", f"in {images}",
                          f"pass its folder, {images.parent}")
    if not images.is_dir():
        raise SplatuError("photo folder not found", f"in {images}", "pass a folder of JPEG/PNG photos")
    entries = sorted(images.iterdir())
    names = [_photo_name(p) for p in entries if p.suffix.lower() in IMAGE_SUFFIXES]
    if len(names) < 2:
        others = [p.name for p in entries if p.suffix.lower() not in IMAGE_SUFFIXES]
        skipped = f" ({len(others)} other entries skipped, e.g. {others[0]!r})" if others else ""
        raise SplatuError(f"too few photos ({len(names)}): structure from motion needs at least 2{skipped}",
                          f"in {images}", f"add overlapping photos of the scene, directly in the folder, as "
                          f"{PHOTO_KINDS} files")
    others = [p.name for p in entries if p.suffix.lower() not in IMAGE_SUFFIXES and p.is_file()
              and not p.name.startswith(".")]
    return names, others


def _listed(names: list[str]) -> str:
    """Up to three names, and how many more: a line that stays one line for a folder of hundreds."""
    return ", ".join(repr(name) for name in names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")


def _photo_sizes(images: Path, names: list[str]) -> dict[str, tuple[int, int]]:
    """Each photo's (width, height) as stored, from a full decode by the training loader's own reader: COLMAP reads
    a truncated JPEG (libjpeg fills the rest grey), so it passed the SfM and only `splatu train` refused it."""
    sizes: dict[str, tuple[int, int]] = {}
    bad: list[tuple[str, str]] = []
    for name in names:
        try:
            pixels = read_image(images / name)
        except SplatuError as err:
            bad.append((name, err.what))
            continue
        sizes[name] = (pixels.shape[1], pixels.shape[0])
    if bad:
        reason = bad[0][1] if len(bad) == 1 else f"{bad[0][0]!r}: {bad[0][1]}"
        raise SplatuError(f"{len(bad)} of {len(names)} photos would not load for training: "
                          f"{_listed([name for name, _ in bad])} ({reason})", f"in {images}",
                          "copy or export them again in full, or move them out of the folder")
    return sizes


def _camera_mode(single_camera: bool | None, sizes: dict[str, tuple[int, int]], images: Path) -> pycolmap.CameraMode:
    """One shared camera only for photos of one size: COLMAP refuses every photo of another size than the first
    (CAMERA_SINGLE_DIM_ERROR). Otherwise one per photo: its reader has no camera per size (its AUTO mode, tried,
    also made one per photo)."""
    by_size = {size: name for name, size in reversed(sizes.items())}  # one photo (the first) of each size
    if single_camera is False or (single_camera is None and len(by_size) > 1):
        return pycolmap.CameraMode.PER_IMAGE
    if len(by_size) > 1:
        shown = ", ".join(f"{name!r} {w}x{h}" for (w, h), name in sorted(by_size.items(), key=lambda i: i[1])[:3])
        raise SplatuError(f"--single-camera needs photos of one size, but they come in {len(by_size)} sizes "
                          f"({shown})", f"in {images}", "leave out --single-camera to estimate one camera per "
                          "photo, or resize the photos to one size")
    return pycolmap.CameraMode.SINGLE


def _stage(console: Console, label: str, work: Callable[[], T]) -> T:
    """Run one pipeline stage under a spinner and report how long it took."""
    start = time.perf_counter()
    with console.status(f"{label}..."):
        result = work()
    console.print(f"[green]done[/green] {label} ({time.perf_counter() - start:.1f} s)")
    return result


def _images_link(images: Path, output: Path) -> Path | None:
    """<output>/images, to be linked to the photos after the SfM; None when it already is. A different folder
    there is refused before any work, so a finished model is never thrown away over it."""
    link = output / "images"
    if link.exists() and link.resolve() == images.resolve():
        return None
    if link.exists() or link.is_symlink():
        raise SplatuError("the output already has a different images folder", f"in {link}",
                          "choose another --output or remove that folder")
    return link


def _remove_partial(created: list[Path]) -> None:
    """Delete what a failed run made (the images link, the sparse folder, the output folder itself), so a retry
    needs no --overwrite; anything that was there before the run stays."""
    for path in created:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def _photos_read(database: Path, names: list[str], images: Path, console: Console) -> None:
    """Name the photos COLMAP could not read (its own warning is a raw log line, hidden unless --colmap-log), and
    stop early when too few are left to match any pair."""
    db = pycolmap.Database.open(database)
    try:
        read = {image.name for image in db.read_all_images()}
    finally:
        db.close()
    unread = [name for name in names if name not in read]
    shown = _listed(unread)
    if len(read) < 2:
        raise SplatuError(f"COLMAP could read only {len(read)} of {len(names)} photos", f"in {images}",
                          f"replace unreadable files ({shown}) with JPEG/PNG photos (--colmap-log shows COLMAP's "
                          "reason)")
    if unread:
        console.print(f"  skipped {len(unread)} of {len(names)} photos COLMAP could not read: {shown} "
                      "(--colmap-log shows why)", highlight=False, soft_wrap=True)


def _reconstruct(cfg: ProcessImagesConfig, names: list[str], mode: pycolmap.CameraMode, staging: Path,
                 console: Console) -> pycolmap.Reconstruction:
    """Extract, match and map into `staging` (database.db, sparse/0), which `_swap_in` then puts in place."""
    database = staging / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = cfg.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = cfg.max_image_size
    extraction.use_gpu = False
    _stage(console, "extracting SIFT features", lambda: pycolmap.extract_features(
        database, cfg.images, image_names=names, camera_mode=mode, reader_options=reader,
        extraction_options=extraction, device=pycolmap.Device.cpu))
    _photos_read(database, names, cfg.images, console)
    match = pycolmap.match_exhaustive if cfg.matcher == "exhaustive" else pycolmap.match_sequential
    _stage(console, f"matching features ({cfg.matcher})", lambda: match(database, device=pycolmap.Device.cpu))

    registered = [0]

    def count(n_images: int) -> Callable[[], None]:
        def report() -> None:
            registered[0] += n_images
            console.print(f"  registered {registered[0]}/{len(names)} photos", highlight=False)

        return report

    models_dir = staging / "models"
    models = _stage(console, "incremental mapping", lambda: pycolmap.incremental_mapping(
        database, cfg.images, models_dir, initial_image_pair_callback=count(2), next_image_callback=count(1)))
    if not models:
        retry = "try --matcher exhaustive" if cfg.matcher == "sequential" else "check they show one static scene"
        raise SplatuError("COLMAP could not reconstruct the scene (no model)", f"from {cfg.images}",
                          f"take more overlapping photos, or {retry}")
    best = max(models.values(), key=lambda r: r.num_reg_images())  # type: ignore[union-attr]
    sparse = staging / "sparse" / "0"
    sparse.mkdir(parents=True)
    best.write(sparse)
    return best


STAGING_PREFIX = ".process-images-"
_STAGING_NAME = re.compile(re.escape(STAGING_PREFIX) + r"(\d+)@(.+)-[^-]+")
"""A staging folder's name: the prefix, the id of the process that made it @ its host, then mkdtemp's random part."""
_UNNAMED = f"{STAGING_PREFIX}new-"
"""A staging folder's name until it is locked: no process id, so never taken for a killed run's."""


def _locked_staging(output: Path) -> tuple[Path, int]:
    """A new staging folder in `output`, named for this process and host, and the descriptor that holds its lock
    (flock on the folder) until it is closed. The kernel drops the lock when the process ends, however it ends; the
    name is given only once the lock is held, so no later run sees it unlocked while this one lives."""
    unnamed = Path(tempfile.mkdtemp(prefix=_UNNAMED, dir=output))  # never a folder the user had
    held = os.open(unnamed, os.O_RDONLY)
    # a file system without locks: the run goes on, but no later run can tell its folder unlocked (`_unlocked`), so
    # one a kill leaves there stays
    with contextlib.suppress(OSError):
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
    staging = unnamed.with_name(f"{STAGING_PREFIX}{os.getpid()}@{socket.gethostname()}-"
                                f"{unnamed.name.removeprefix(_UNNAMED)}")
    os.rename(unnamed, staging)
    return staging, held


def _running(pid: int) -> bool:
    """Whether process `pid` exists on this host (another user's included): signal 0 checks without sending."""
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:
        return True
    return True


def _unlocked(folder: Path) -> bool:
    """Whether no process holds `folder`'s lock (`_locked_staging`): a process id alone does not tell, as a run in
    another container of the same host name (another process-id namespace) has an id this one cannot see. False
    where it cannot tell (no locks, an unreadable folder)."""
    try:
        probe = os.open(folder, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(probe, fcntl.LOCK_EX | fcntl.LOCK_NB)  # released as the descriptor closes
    except OSError:
        return False
    finally:
        os.close(probe)
    return True


def _stale_staging(output: Path) -> list[Path]:
    """The staging folders in `output` that a run killed outright (kill -9, a power cut) left: made on this host by
    a process that no longer runs, and unlocked. A live run's stays, and so does one made on another host sharing the
    folder, or by an older splatu whose names held no process id, which cannot be told from a live one. A reused
    process id keeps a killed run's folder until that process ends: kept, never a live run's deleted."""
    host = socket.gethostname()
    return [entry for entry in sorted(output.iterdir())
            if (found := _STAGING_NAME.fullmatch(entry.name)) is not None and found.group(2) == host
            and entry.is_dir() and not entry.is_symlink() and not _running(int(found.group(1)))
            and _unlocked(entry)]


UNNAMED_GRACE_SECONDS = 60.0
"""How old an unnamed staging folder must be to count as a killed run's: a live run names its own within a
microsecond of making it (`_locked_staging`)."""


def _removed_unnamed(output: Path) -> list[Path]:
    """Remove the empty unnamed staging folders that a run killed between making one and naming it left. rmdir
    removes only an empty folder, so nothing a run staged is lost."""
    removed = []
    for entry in sorted(output.iterdir()):
        if not entry.name.startswith(_UNNAMED) or entry.is_symlink() or not entry.is_dir():
            continue
        with contextlib.suppress(OSError):
            if time.time() - entry.stat().st_mtime > UNNAMED_GRACE_SECONDS:
                entry.rmdir()
                removed.append(entry)
    return removed


def _remove_stale_staging(output: Path, console: Console) -> None:
    """Delete the staging folders killed runs left in `output` (each may hold a database of hundreds of MB)."""
    stale = _stale_staging(output)
    for folder in stale:
        shutil.rmtree(folder, ignore_errors=True)
    stale += _removed_unnamed(output)
    if stale:
        left = "staging folder that a killed run" if len(stale) == 1 else "staging folders that killed runs"
        console.print(f"  removed {len(stale)} {left} left in {output}", highlight=False, soft_wrap=True)


def _swap_in(staging: Path, output: Path) -> None:
    """Put the complete new model, then its database, in place of any earlier ones: until here an interrupted or
    failed run left the earlier model as it was, and a stop now waits for both, so the model and the database
    that made it stay a pair."""
    with finish_first():
        (output / "sparse").mkdir(exist_ok=True)
        swap_in_folder(staging / "sparse" / "0", output / "sparse" / "0")
        os.replace(staging / "database.db", output / "database.db")


def process_images(cfg: ProcessImagesConfig) -> Path:
    """Run SfM on cfg.images and return the scene folder holding sparse/0; a failed run leaves nothing behind."""
    console = Console(stderr=True)
    cfg.validate()
    cfg = dataclasses.replace(cfg, images=Path(os.path.abspath(cfg.images)))  # "." has no name to name the output by
    names, others = _photos(cfg.images)
    output = Path(os.path.abspath(cfg.output or default_output(cfg.images)))
    database, sparse = output / "database.db", output / "sparse" / "0"
    if (database.exists() or sparse.exists()) and not cfg.overwrite:
        raise SplatuError("a COLMAP database or model already exists", f"in {output}",
                          "pass --overwrite or choose another --output")
    link = _images_link(cfg.images, output)
    creatable_dir(output, "--output")  # before decoding the photos, which takes minutes for hundreds of large ones
    if others:  # a WebP or HEIC photo among them would otherwise be left out without a word
        console.print(f"  left out, as not {PHOTO_KINDS} photos: {_listed(others)}",
                      highlight=False, soft_wrap=True)
    sizes = _stage(console, f"decoding {len(names)} photos", lambda: _photo_sizes(cfg.images, names))
    mode = _camera_mode(cfg.single_camera, sizes, cfg.images)
    created = [path for path in (output, output / "sparse") if not path.exists()] + ([link] if link else [])
    output.mkdir(parents=True, exist_ok=True)
    _remove_stale_staging(output, console)
    staging, held = _locked_staging(output)
    # COLMAP's warnings and errors are raw log lines beside splatu's own for the same thing (an unreadable photo,
    # no model); a failure COLMAP cannot go on from is its FATAL line and an exception
    pycolmap.logging.minloglevel = pycolmap.logging.INFO if cfg.colmap_log else pycolmap.logging.FATAL
    cameras = "one camera" if mode == pycolmap.CameraMode.SINGLE else "one camera per photo"
    console.print(f"structure from motion on {len(names)} photos in {cfg.images} (CPU, {cameras})", soft_wrap=True)
    try:
        best = _reconstruct(cfg, names, mode, staging, console)
        if link is not None:
            link.symlink_to(cfg.images.resolve(), target_is_directory=True)
        _swap_in(staging, output)
    except BaseException:
        _remove_partial(created)
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        os.close(held)
    console.print(f"model: {best.num_reg_images()}/{len(names)} photos registered, {best.num_points3D()} points, "
                  f"mean reprojection error {best.compute_mean_reprojection_error():.2f} px -> {sparse}",
                  soft_wrap=True)
    console.print(f"train on it with: splatu train --data {shlex.quote(str(colmap_data_path(output)))}",
                  soft_wrap=True)
    return output


def run(cfg: ProcessImagesConfig) -> None:
    """The `splatu process-images` entry point."""
    process_images(cfg)
