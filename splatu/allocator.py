"""Keep freed memory in the process, so that each training step does not page-fault its buffers back in.

A training step allocates and frees tens of MB of tensors whose sizes change every step (each camera
sees a different number of Gaussians). glibc's malloc starts by giving such blocks back to the kernel
(mmap'd blocks above a dynamic threshold, and the heap's top beyond a trim threshold), so the next step
faults fresh zeroed pages in again. Measured by `python benchmarks/allocator.py --steps 500 --measured 100`
(poster stand-in, `fast` preset, fresh processes, 2 cores): 12,000–18,000 page faults and 40–60 ms of kernel
time per step with glibc's defaults, none with the thresholds fixed as below; 293 → 249 ms per step with the
uncertainty loss, 298 → 244 without. glibc raises its thresholds by itself only after it has seen large
frees, so the first training of a process paid this and later ones did not.
"""

from __future__ import annotations

import ctypes
import os
import platform
from collections.abc import Mapping

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 << 20
"""glibc's largest allowed mmap threshold on 64-bit (DEFAULT_MMAP_THRESHOLD_MAX): blocks below it come from the
heap and are reused; a fixed value also stops the threshold from moving."""
TRIM_THRESHOLD_BYTES = 1 << 30
"""Free memory at the heap's top kept before returning it to the kernel; a step's peak is well below it."""

_tuned = False


def keep_freed_memory() -> bool:
    """Fix glibc malloc's mmap and trim thresholds (once per process); returns whether they are set.

    A no-op on other C libraries (macOS, musl, Windows) and when the user tuned malloc through the environment.
    """
    global _tuned
    if _tuned:
        return True
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc" or user_tuned_malloc(os.environ):
        return False
    libc = ctypes.CDLL(None)
    _tuned = bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    return _tuned


def user_tuned_malloc(environment: Mapping[str, str]) -> bool:
    """Whether malloc was tuned through the environment (MALLOC_* variables, or glibc.malloc.* tunables)."""
    return (any(name.startswith("MALLOC_") for name in environment)
            or "glibc.malloc." in environment.get("GLIBC_TUNABLES", ""))
