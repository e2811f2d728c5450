"""Where and when a measurement was taken, for benchmark results: timings from different CPUs do not compare,
and results files keep rows from earlier invocations."""

from __future__ import annotations

import platform
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


def measured_on() -> dict[str, Any]:
    """Today's date, the CPU, torch's thread count and version."""
    return {"date": time.strftime("%Y-%m-%d"), "cpu": cpu_name(), "threads": torch.get_num_threads(),
            "torch": torch.__version__}
