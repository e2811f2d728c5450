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
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=repo, capture_output=True, text=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "splatu"], cwd=repo, capture_output=True, text=True)
    except OSError:  # no git
        return "unknown"
    if head.returncode != 0:
        return "unknown"
    return head.stdout.strip() + (" + uncommitted changes" if dirty.stdout.strip() else "")


def measured_on() -> dict[str, Any]:
    """Today's date, the commit, the CPU, torch's thread count and version."""
    return {"date": time.strftime("%Y-%m-%d"), "revision": source_revision(), "cpu": cpu_name(),
            "threads": torch.get_num_threads(), "torch": torch.__version__}
