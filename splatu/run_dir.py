"""Where a run's files go: <output_dir>/<scene>/<method>/<timestamp>/ plus a `latest` symlink."""

from __future__ import annotations

import os
import time
from pathlib import Path

from splatu.errors import SplatuError

LATEST = "latest"


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
    link = run_dir.parent / LATEST
    tmp = run_dir.parent / f".{LATEST}.tmp-{os.getpid()}"
    tmp.unlink(missing_ok=True)
    tmp.symlink_to(run_dir.name, target_is_directory=True)
    os.replace(tmp, link)
    return link
