"""User-facing errors: one line saying what is wrong, where, and how to fix it.

Anything the user can fix (a bad path, a corrupt file, a bad option) raises `SplatuError`;
the CLI prints it on one line and exits 2. Everything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import contextlib
import io
import shlex
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np


class SplatuError(Exception):
    """A problem with the user's input, reported without a traceback."""

    def __init__(self, what: str, where: str | Path, fix: str) -> None:
        self.what = what
        self.where = str(where)
        self.fix = fix
        super().__init__(f"{what}, {self.where}, {fix}")


class OptionError(SplatuError):
    """An option's value out of its range, told as the flag's: it keeps the flag, the value and what the option
    accepts, so that a value a preset file set can be blamed on the file's key instead of a flag never typed."""

    def __init__(self, what: str, where: str, fix: str, *, flag: str, value: object, problem: str,
                 allowed: str) -> None:
        super().__init__(what, where, fix)
        self.flag = flag
        self.value = value
        self.problem = problem
        self.allowed = allowed


class DownscaleError(SplatuError):
    """A scene that cannot load at its downscale factor (a pre-downscaled images_N copy of the wrong size), told
    without naming --downscale as typed: `train` may have chosen the factor itself, and then says so. Its fix is one
    every command can follow; a new run, free to choose its size, adds full size (`copy_at_fault`)."""

    def __init__(self, what: str, where: str, fix: str, *, factor: int, copy_at_fault: bool) -> None:
        super().__init__(what, where, fix)
        self.factor = factor
        self.copy_at_fault = copy_at_fault
        """Whether the copy is the wrong size, not turned on its side (a camera given the wrong way round): training
        at full size then does without it."""


def a_few(paths: Sequence[Path], most: int = 3) -> str:
    """Up to `most` of `paths`, shell-quoted to paste, as "A, B or C (3 of 7)": a fix that names what is there
    saves a look around, and a long list would bury the line."""
    shown = [shlex.quote(str(path)) for path in paths[:most]]
    listed = shown[0] if len(shown) == 1 else f"{', '.join(shown[:-1])} or {shown[-1]}"
    return listed if len(paths) <= most else f"{listed} ({most} of {len(paths)})"


def require_file(path: Path, what: str, fix: str) -> Path:
    """Return `path` if it is an existing file; otherwise raise a one-line SplatuError."""
    if not path.is_file():
        raise SplatuError(f"{what} not found", f"in {path}", fix)
    return path


def _out_of_range(flag: str, value: float, allowed: str) -> OptionError:
    """The one line for option `flag` outside what it takes (`allowed`, e.g. "at least 1")."""
    return OptionError(f"{flag} must be {allowed} (got {value})", "in the options", f"pass {flag} of {allowed}",
                       flag=flag, value=value, problem=f"must be {allowed}", allowed=allowed)


def require_at_least(value: float, minimum: float, flag: str) -> None:
    """Raise a one-line SplatuError unless option `flag` (a count, rate or size) is finite and at least `minimum`."""
    if not (value == value and abs(value) != float("inf") and value >= minimum):
        raise _out_of_range(flag, value, f"at least {minimum:g}")


def require_at_most(value: float, maximum: float, flag: str) -> None:
    """Raise a one-line SplatuError if option `flag` exceeds `maximum` (a finite lower bound is checked apart)."""
    if value > maximum:
        raise _out_of_range(flag, value, f"at most {maximum:g}")


def load_number_array(path: Path, what: str, fix: str) -> np.ndarray:
    """The .npy array of numbers at `path`, or one line saying it is not one: np.load raises many types on an
    empty, truncated, pickled or foreign file, and loads an .npz or a bool or string array without complaint."""
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, EOFError, OSError):
        array = None
    if not isinstance(array, np.ndarray) or array.dtype.kind not in "iuf":
        raise SplatuError(f"{what} is not a valid .npy array of numbers", f"in {path}", fix)
    return array


def creatable_dir(path: Path, option: str) -> Path:
    """Prove now that `path` is, or could be made, a writable folder, without making it: a command refused later
    (a missing scene, a bad option) then leaves no empty folders behind. The probe is a temporary file in `path`,
    or in its nearest existing ancestor."""
    existing = path
    while not existing.exists() and not existing.is_symlink() and existing != existing.parent:
        existing = existing.parent
    if existing.is_symlink() and not existing.exists():
        raise SplatuError(f"cannot write the output folder ({existing} is a broken link)", f"in {path}",
                          f"remove or repoint the link, or pass another {option}")
    if not existing.is_dir():
        raise SplatuError(f"cannot write the output folder ({existing} is a file)", f"in {path}",
                          f"pass a writable {option}")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as err:
        raise SplatuError(f"cannot write the output folder ({err.strerror or type(err).__name__})", f"in {path}",
                          f"pass a writable {option}") from None
    return path


@contextlib.contextmanager
def no_empty_folders_left(path: Path) -> Iterator[None]:
    """Remove, when the block ends, the folders on the way to `path` (itself included) that it made and left empty:
    `creatable_dir` made none before the command could fail, and a write that fails later (a full disk, Ctrl-C)
    must not leave them either. A folder that existed before is never removed."""
    made = []
    for folder in (path, *path.parents):
        if folder.exists() or folder.is_symlink():
            break
        made.append(folder)  # deepest first, so each one is empty when its turn comes
    try:
        yield
    finally:
        for folder in made:
            with contextlib.suppress(OSError):  # not empty (the command's output), or already gone
                folder.rmdir()


def os_error_behind(err: BaseException) -> OSError | None:
    """The OSError behind a failed write, if that is what failed: torch.save re-raises a failed write (a full
    disk, a file-size limit) as a RuntimeError whose context is the OSError. Other errors are bugs."""
    if isinstance(err, RuntimeError):
        err = err.__cause__ or err.__context__
    if isinstance(err, io.UnsupportedOperation):  # an OSError by class, but a writer's bug (reading a write-only file)
        return None
    return err if isinstance(err, OSError) else None


FREE_AND_RERUN = "free space on that disk or make the folder writable, then run the command again"
RESUME_AFTER_FREEING = (f"{FREE_AND_RERUN} (a training continues from its last checkpoint with "
                        "`splatu train --resume RUN`)")


def unwritable(path: Path, err: OSError, fix: str = RESUME_AFTER_FREEING) -> SplatuError:
    """A write that the disk refused (full, read-only, over a quota or size limit) as one line."""
    reason = err.strerror or str(err) or type(err).__name__
    return SplatuError(f"could not write {path.name} ({reason})", f"in {path.parent}", fix)


def unwritable_folder(folder: Path, err: OSError) -> SplatuError:
    """Files the disk refused to take (full, read-only, over a quota) while a folder of them was written, as one
    line: np.save reports a short write with no file name, so the folder is what can be named."""
    reason = err.strerror or str(err) or type(err).__name__
    return SplatuError(f"could not write the files ({reason})", f"in {folder}", FREE_AND_RERUN)
