"""Whole-file writes that never leave half a file: a temporary sibling, fsync, then one rename.

A crash mid-write (power loss, SIGKILL, a full disk) then leaves the previous file or none, never a
torn one. That matters for anything read back as a record of the run: checkpoints, the config,
`summary.json` (whose presence marks an ensemble member finished), the PLY and the reports.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

from splatu.errors import RESUME_AFTER_FREEING, os_error_behind, unwritable


def atomic_write(path: Path, write: Callable[[BinaryIO], None], fix: str = RESUME_AFTER_FREEING) -> None:
    """Call `write` on a binary temporary sibling of `path`, fsync it, then rename it over `path`. A write the disk
    refuses is one line, ending in `fix`."""
    path = Path(path)
    tmp = temporary_sibling(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    except Exception as err:
        if isinstance(err.__context__, KeyboardInterrupt):  # torch.save re-raises a Ctrl-C inside it as RuntimeError
            raise err.__context__ from None
        refused = os_error_behind(err)
        if refused is None:
            raise
        raise unwritable(path, refused, fix) from err
    finally:
        with contextlib.suppress(OSError):  # e.g. the parent is a file: the error above is the one to report
            tmp.unlink(missing_ok=True)


def file_identity(path: Path) -> tuple[int, int] | None:
    """Inode and modification time of `path`, None when absent: a file `atomic_write` replaced has another, so
    comparing them tells whether a stopped command replaced it."""
    try:
        found = path.stat()
    except FileNotFoundError:
        return None
    return found.st_ino, found.st_mtime_ns


def what_a_stop_left(written: Path, earlier: tuple[int, int] | None, thing: str, where: Path) -> str:
    """What a Ctrl-C or SIGTERM left of `thing` in `where`, told by `written`, which was `earlier` (`file_identity`)
    when the command began and is replaced whole (`atomic_write`, or last, as a staged render's swap does): either the
    earlier one, unchanged, or the whole new one. The line `interrupted: …` says it, so a user knows what survived."""
    if file_identity(written) != earlier:
        return f"the new {thing} was already written in full to {where}"
    if earlier is None:
        return f"no {thing} written to {where}"
    return f"no {thing} written; the earlier {thing} in {where} is unchanged"


def temporary_sibling(path: Path) -> Path:
    """Where `path` is written whole before it is renamed into place: hidden, and named by the writing process, so
    two writers never share one and a killed writer's leftover can be found (`leftover_temporaries`)."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def leftover_temporaries(folder: Path, name_glob: str) -> list[Path]:
    """The temporary siblings (`temporary_sibling`) of the names matching `name_glob` in `folder`: what writers
    killed outright (SIGKILL, out of memory) left, and whose rename never came."""
    return sorted(folder.glob(f".{name_glob}.tmp-*"))


def sync_appended(path: Path) -> None:
    """fsync a file written in place (appended to, not replaced), and its folder, which holds its name if it is new."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    _fsync_dir(path.parent)


def _fsync_dir(folder: Path) -> None:
    """Make the rename itself durable before anything that relies on it (pruning older checkpoints): some
    file systems may otherwise persist a later deletion but not the rename."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError as err:  # some network and FUSE file systems cannot fsync a folder; the file itself is safe
        if err.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise
    finally:
        os.close(fd)


def atomic_write_text(path: Path, text: str, fix: str = RESUME_AFTER_FREEING) -> None:
    """Write `text` (UTF-8) to `path` atomically (see `atomic_write`)."""
    atomic_write(path, lambda f: f.write(text.encode("utf-8")), fix)


def swap_in_folder(staging: Path, root: Path) -> None:
    """Rename `staging` to `root`, moving any earlier `root` aside first and deleting it only once `staging` is in
    place: a stop or a failure leaves the earlier folder, as it was, at `root` or (between two renames) aside.
    Another process may be swapping in its own directory at the same moment (two `eval-ause --load` runs of one
    method on one run): the last rename wins and neither fails."""
    aside = root.with_name(f".{root.name}.old-{os.getpid()}")
    shutil.rmtree(aside, ignore_errors=True)
    while True:
        try:
            os.rename(staging, root)  # POSIX: replaces a missing or empty `root`, refuses a full one
            break
        except OSError as err:
            if err.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                raise
        shutil.rmtree(aside, ignore_errors=True)  # a later pass's: another process's folder took `root` since
        try:
            os.rename(root, aside)
        except FileNotFoundError:  # the other process moved it aside first
            continue
    shutil.rmtree(aside, ignore_errors=True)
