"""Where and when a measurement was taken, for benchmark results: timings from different CPUs do not compare,
and results files keep rows from earlier invocations."""

from __future__ import annotations

import platform
import subprocess
import time
from pathlib import Path
from typing import Any

import torch


def cpu_name() -> str:
    """The CPU's model name (Linux), else what `platform` knows."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def source_revision() -> str:
    """The git commit splatu/ was measured at (short hash), marked when splatu/ differs from it; "unknown" outside a
    git checkout (an installed package). A figure is quoted with its commit, which the file must then hold."""
    repo = Path(__file__).resolve().parents[1]

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", *args], cwd=repo, capture_output=True, text=True, timeout=30)
        except (OSError, subprocess.TimeoutExpired):  # no git, or a hung one
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    top = git("rev-parse", "--show-toplevel")  # a package installed inside another project's checkout is not ours
    head = git("rev-parse", "--short", "HEAD")
    if top is None or head is None or Path(top).resolve() != repo:
        return "unknown"
    return head + (" + uncommitted changes" if git("status", "--porcelain", "splatu") else "")


def measured_on() -> dict[str, Any]:
    """Today's date, the commit, the CPU, torch's thread count and version."""
    return {"date": time.strftime("%Y-%m-%d"), "revision": source_revision(), "cpu": cpu_name(),
            "threads": torch.get_num_threads(), "torch": torch.__version__}
