"""Where a run's files go: <output_dir>/<scene>/<method>/<timestamp>/ plus a `latest` symlink."""

from __future__ import annotations

import os
import time
from pathlib import Path

LATEST = "latest"


def new_run_dir(output_dir: Path, scene: str, method: str) -> Path:
    """Create a fresh timestamped run directory (a suffix keeps runs started in the same second apart)."""
    parent = Path(output_dir) / scene / method
    parent.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y-%m-%d_%H%M%S")
    for attempt in range(1000):
        run_dir = parent / (stamp if attempt == 0 else f"{stamp}_{attempt}")
        try:
            run_dir.mkdir()
        except FileExistsError:
            continue
        return run_dir
    raise RuntimeError(f"could not create a fresh run directory under {parent}")


def point_latest(run_dir: Path) -> Path:
    """Make <run_dir>/../latest a relative symlink to `run_dir`, replaced atomically."""
    link = run_dir.parent / LATEST
    tmp = run_dir.parent / f".{LATEST}.tmp-{os.getpid()}"
    tmp.unlink(missing_ok=True)
    tmp.symlink_to(run_dir.name, target_is_directory=True)
    os.replace(tmp, link)
    return link
