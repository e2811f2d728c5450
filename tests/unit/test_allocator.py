"""keep_freed_memory: the buffers a step frees stay in the process, so the next step does not fault them in again."""

import os
import platform
import subprocess
import sys

import pytest

from splatu.allocator import user_tuned_malloc

pytestmark = pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
                                reason="malloc tuning applies to glibc only")

STEPS = """
import resource, sys, torch
from splatu.allocator import keep_freed_memory
tuned = keep_freed_memory() if sys.argv[1] == "tuned" else False
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for megabytes in range(8, 31):  # a step's buffer, a little larger every step, as the entries of a render vary
    buffer = torch.ones(megabytes << 18)
    del buffer
print(tuned, (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 23)
"""


def _faults_per_step(mode: str, **env: str) -> tuple[bool, float]:
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("MALLOC_", "GLIBC_TUNABLES"))}
    out = subprocess.run([sys.executable, "-c", STEPS, mode], env={**clean, **env}, capture_output=True, text=True,
                         check=True).stdout.split()
    return out[0] == "True", float(out[1])


def test_fixed_thresholds_keep_a_steps_freed_buffers_in_the_process():
    tuned, tuned_faults = _faults_per_step("tuned")
    _, default_faults = _faults_per_step("default")
    assert tuned
    if default_faults < 100:  # e.g. transparent huge pages on "always": one fault maps 2 MB
        pytest.skip(f"glibc's defaults fault only {default_faults:.0f} times per step on this machine")
    # glibc's defaults mmap each new largest buffer and unmap it on free, so every page faults every step;
    # with the thresholds fixed the heap keeps them. Measured (glibc 2.36, torch 2.13, deterministic):
    # 4,867 faults per step with the defaults, 1,560 fixed
    assert tuned_faults < 0.5 * default_faults, (default_faults, tuned_faults)


@pytest.mark.parametrize("setting", [{"MALLOC_TRIM_THRESHOLD_": "131072"},
                                     {"GLIBC_TUNABLES": "glibc.pthread.rseq=0:glibc.malloc.trim_threshold=131072"}])
def test_a_user_who_tuned_malloc_is_left_alone(setting):
    tuned, _ = _faults_per_step("tuned", **setting)
    assert not tuned


def test_tunables_of_other_parts_of_glibc_do_not_count_as_tuning_malloc():
    assert not user_tuned_malloc({"GLIBC_TUNABLES": "glibc.pthread.rseq=0", "PATH": "/usr/bin"})
    assert user_tuned_malloc({"MALLOC_ARENA_MAX": "2"})
