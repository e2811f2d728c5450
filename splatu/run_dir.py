"""Where a run's files go: <output_dir>/<scene>/<method>/<timestamp>/ plus a `latest` symlink."""

from __future__ import annotations

import fcntl
import os
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from splatu.atomic import temporary_sibling
from splatu.errors import SplatuError, unwritable

LATEST = "latest"
LOCK_FILE = ".training.lock"
LOCK_ATTEMPTS, LOCK_RETRY_SECONDS = 25, 0.02
"""A training asks for its lock this often before it refuses (half a second in all): `still_training` holds the lock
shared for an instant, and a render polling a run must not make a `--resume` starting then refuse."""


DEMO_RUN = Path("outputs/poster/splatu/latest")
"""Where --load of render-uncertainty, export and eval-ause points when not given: the run `make demo` trains."""


def new_run_dir(output_dir: Path, scene: str, method: str) -> Path:
    """Create a fresh timestamped run directory."""
    return new_timestamped_dir(Path(output_dir) / scene / method)


def new_timestamped_dir(parent: Path) -> Path:
    """Create parent/<time>, or parent/<time>_k when that exists: folders made in the same second stay apart."""
    parent.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y-%m-%d_%H%M%S")
    for attempt in range(1000):
        folder = parent / (stamp if attempt == 0 else f"{stamp}_{attempt}")
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return folder
    raise SplatuError("cannot create a fresh timestamped folder", f"in {parent}", "wait a second and run again")


def point_latest(run_dir: Path) -> Path:
    """Make <run_dir>/../latest a relative symlink to `run_dir`, replaced atomically."""
    return _point_link(run_dir.parent / LATEST, run_dir.name)


def _point_link(link: Path, target: str) -> Path:
    tmp = temporary_sibling(link)
    tmp.unlink(missing_ok=True)
    tmp.symlink_to(target, target_is_directory=True)
    os.replace(tmp, link)
    return link


@dataclass
class Began:
    """Passed to `train_locked_run` as its `began`: whether a session's training began (its state built and fitting
    the scene), so that a session refused before it, which did no work, is not counted in an ensemble's wall time
    nor kept as a run (`latest_new_run`)."""

    trained: bool = False

    def __call__(self) -> None:
        self.trained = True


@contextmanager
def latest_new_run(output_dir: Path, scene: str, method: str) -> Iterator[tuple[Path, Began]]:
    """A new run folder (`new_run_dir`) with `latest` pointed at it, and the `Began` to pass to its training. A user
    error (`SplatuError`) before its training began removes the folder, which then holds only what this command
    wrote (config.yml, an ensemble's member folders), and points `latest` back if no other run has taken it since:
    render-uncertainty's default --load must not find a stub of a command that failed. A stop by Ctrl-C keeps it,
    as a run that `--resume` restarts."""
    run_dir = new_run_dir(output_dir, scene, method)
    link = run_dir.parent / LATEST
    before = os.readlink(link) if link.is_symlink() else None
    point_latest(run_dir)
    began = Began()
    try:
        yield run_dir, began
    except SplatuError:
        if not began.trained:
            shutil.rmtree(run_dir, ignore_errors=True)
            if link.is_symlink() and os.readlink(link) == run_dir.name:  # else a run started since holds it
                if before is None:
                    link.unlink(missing_ok=True)
                else:
                    _point_link(link, before)
        raise


@contextmanager
def training_lock(run_dir: Path) -> Iterator[None]:
    """One training per run folder at a time: a second `--resume` of a run still training (a requeued batch job,
    a second terminal) would interleave its checkpoints and log with the first's. The kernel drops the lock when
    its process ends, however it ends, so a killed run never leaves a stale one. The file itself stays in the folder:
    deleting it on exit would let a process already waiting on it lock the deleted file while a third locks a new
    one. Where the file system has no locks, training goes on without the guard."""
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        lock = open(run_dir / LOCK_FILE, "a")  # noqa: SIM115 (closed by the `with` below, after the training)
    except OSError as err:
        raise unwritable(run_dir / LOCK_FILE, err) from None
    with lock:
        for attempt in range(LOCK_ATTEMPTS):
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:  # a training, or for an instant `still_training`'s probe of a render or query
                if attempt + 1 == LOCK_ATTEMPTS:
                    raise SplatuError("another `splatu train` is training this run now", f"in {run_dir}",
                                      "let it finish, or stop it (Ctrl-C saves) and then resume") from None
                time.sleep(LOCK_RETRY_SECONDS)
            except OSError:  # a file system without locks (some NFS mounts): train unguarded rather than not at all
                break
        yield


def still_training(run_dir: Path) -> bool:
    """Whether a `splatu train` holds the run's lock now (`training_lock`): its newest checkpoint is then an
    intermediate model that the next one replaces. False where there is no lock file or the file system has none."""
    try:
        with open(Path(run_dir) / LOCK_FILE) as lock:
            fcntl.flock(lock, fcntl.LOCK_SH | fcntl.LOCK_NB)  # released as the file closes
    except BlockingIOError:
        return True
    except OSError:
        return False
    return False
