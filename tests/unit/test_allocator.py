"""keep_freed_memory: freed tensors stay in the process, so steps of changing sizes stop page-faulting."""

import os
import platform
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
                                reason="malloc tuning applies to glibc only")

STEPS = """
import resource, sys, torch
from splatu.allocator import keep_freed_memory
tuned = keep_freed_memory() if sys.argv[1] == "tuned" else False
def step(r):  # a few MB-sized buffers whose size changes every step, like a render's per-entry tensors
    buffers = [torch.ones((2 + (r * 7) % 9) << 18) for _ in range(6)]
    del buffers
for r in range(5):
    step(r)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for r in range(20):
    step(r)
print(tuned, (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 20)
"""


def _faults_per_step(mode: str, **env: str) -> tuple[bool, float]:
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("MALLOC_", "GLIBC_TUNABLES"))}
    out = subprocess.run([sys.executable, "-c", STEPS, mode], env={**clean, **env}, capture_output=True, text=True,
                         check=True).stdout.split()
    return out[0] == "True", float(out[1])


def test_fixed_thresholds_stop_the_page_faults_of_changing_buffer_sizes():
    tuned, tuned_faults = _faults_per_step("tuned")
    _, default_faults = _faults_per_step("default")
    assert tuned
    # measured: ~4,300 faults per step with glibc's defaults, ~130 with the thresholds fixed
    assert default_faults > 1000 and tuned_faults < 0.1 * default_faults, (default_faults, tuned_faults)


def test_a_user_who_tuned_malloc_is_left_alone():
    tuned, _ = _faults_per_step("tuned", MALLOC_TRIM_THRESHOLD_="131072")
    assert not tuned
