"""The kernels' compile clock (splatu.rasterizer.kernels.compile_seconds), which hangs on dynamo's private compile
callbacks: it must follow every compile, and stop, saying so, rather than stop a training when torch changes them.

torch.compile is replaced by stand-ins here, so that no test waits for inductor: `timed_compile` calls the
callbacks around its first call as dynamo does around a compile."""

from __future__ import annotations

import sys
import time
import warnings
from collections.abc import Callable

import pytest
import torch
from torch._dynamo.callback import CallbackTrigger, callback_handler

from splatu.rasterizer import kernels

COMPILE_SECONDS = 0.05


def doubled(x: torch.Tensor) -> torch.Tensor:
    """A pure tensor function, as `kernels.compiled` takes."""
    return x * 2


def timed_compile(fn: Callable, **_options: object) -> Callable:
    """torch.compile as the clock sees it: the first call compiles, inside dynamo's start and end callbacks."""
    compiled = []

    def call(*args: torch.Tensor) -> torch.Tensor:
        if not compiled:
            with callback_handler.install_callbacks(CallbackTrigger.DYNAMO, "0/0"):
                time.sleep(COMPILE_SECONDS)
            compiled.append(True)
        return fn(*args)

    return call


@pytest.fixture
def clock(monkeypatch) -> None:
    """A process that has compiled nothing yet, with the kernels routed through torch.compile."""
    monkeypatch.setattr(kernels, "_compile_seconds", 0.0)
    monkeypatch.setattr(kernels, "_compile_began", None)
    monkeypatch.setattr(kernels, "_compiled", {})
    monkeypatch.setattr(kernels, "_use_compile", True)
    monkeypatch.setattr(kernels, "_compile_failed", False)


def test_a_compile_after_dynamo_reset_is_still_timed(clock, monkeypatch):
    """torch._dynamo.reset() drops every callback (the tests reset it); a kernel made before it compiles again after
    it, and that compile went uncounted."""
    monkeypatch.setattr(torch, "compile", timed_compile)
    run = kernels.compiled(doubled)
    run(torch.ones(3))
    timed = kernels.compile_seconds()
    assert timed >= COMPILE_SECONDS
    callback_handler.clear()  # what torch._dynamo.reset() does to them
    run(torch.ones(3, dtype=torch.float64))  # another dtype: another compile
    assert kernels.compile_seconds() >= timed + COMPILE_SECONDS


def test_a_torch_without_the_callback_api_stops_the_clock_not_the_training(clock, monkeypatch):
    """torch._dynamo.callback is private: without it the first compiled kernel raised ImportError, ending the run."""
    monkeypatch.setattr(torch, "compile", timed_compile)
    monkeypatch.setitem(sys.modules, "torch._dynamo.callback", None)  # as if this torch had no such module
    with pytest.warns(UserWarning, match="compile time cannot be timed apart") as said:
        assert torch.equal(kernels.compiled(doubled)(torch.ones(3)), torch.full((3,), 2.0))
        kernels.compiled(doubled)(torch.ones(3, dtype=torch.float64))
    assert len(said) == 1
    assert kernels.compile_seconds() is None


def test_a_compile_the_callbacks_miss_stops_the_clock(clock, monkeypatch):
    """A torch that keeps the callback API but no longer calls it around a compile would have had its compiles
    counted in the steps while train_compile_seconds said 0."""
    monkeypatch.setattr(torch, "compile", lambda fn, **_options: fn)  # compiles without a callback
    with pytest.warns(UserWarning, match="without calling its compile callbacks"):
        kernels.compiled(doubled)(torch.ones(3))
    assert kernels.compile_seconds() is None


def test_the_callbacks_take_whatever_dynamo_passes(clock, monkeypatch):
    """A callback that failed on dynamo's arguments would fail every compile, and the kernels run eager."""
    monkeypatch.setattr(torch, "compile", timed_compile)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        kernels.compiled(doubled)(torch.ones(3))
    kernels._compile_started(object(), "more", trigger=None)
    kernels._compile_ended(object(), "more", trigger=None)
    assert kernels.compile_seconds() >= COMPILE_SECONDS


@pytest.mark.parametrize("disabled", ["TORCHDYNAMO_DISABLE", "config"])
def test_with_dynamo_disabled_nothing_compiles_and_nothing_is_said(clock, monkeypatch, disabled):
    """With dynamo off (TORCHDYNAMO_DISABLE=1, or TORCH_COMPILE_DISABLE=1 as torch._dynamo.config.disable) torch.compile
    is a no-op: the clock warned that a kernel compiled without its callbacks and went null, though nothing compiled.
    The kernels run eager instead, and the compile time stays 0."""
    if disabled != "config":
        monkeypatch.setenv(disabled, "1")
    # dynamo's own patch for its config: monkeypatch's undo left torch._dynamo.config without the key, and every
    # later compiled kernel failed on reading it
    with torch._dynamo.config.patch(disable=disabled == "config"), warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # the clock's warning (loading inductor may deprecate things)
        assert torch.equal(kernels.compiled(doubled)(torch.ones(3)), torch.full((3,), 2.0))
        assert kernels.compile_seconds() == 0.0
        assert kernels.compiled(doubled) is doubled
        assert not kernels.compile_pending() and not kernels.kernels_compiled()  # no compile to announce


def halved(x: torch.Tensor) -> torch.Tensor:
    """A second pure tensor function: another kernel."""
    return x / 2


def failing_compile(fn: Callable, **_options: object) -> Callable:
    """torch.compile where it cannot compile (no C++ compiler): its first call raises."""

    def call(*_args: torch.Tensor) -> torch.Tensor:
        raise RuntimeError("no C++ compiler")

    return call


def test_a_compile_that_failed_is_not_tried_again_by_a_later_session(clock, monkeypatch):
    """A failed compile (no C++ compiler) turns every kernel eager, with one warning. A later session of the process
    (an ensemble's next member) calls set_compile(True) again, and each kernel the first session had not yet run was
    compiled again, failed again and warned again, one more warning per member."""
    monkeypatch.setattr(torch, "compile", failing_compile)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        for _session in range(2):
            kernels.set_compile(True)  # as `train_locked_run` does for each run and member
            assert torch.equal(kernels.compiled(doubled)(torch.ones(3)), torch.full((3,), 2.0))
            assert torch.equal(kernels.compiled(halved)(torch.ones(3)), torch.full((3,), 0.5))
    told = [str(w.message).split(" failed")[0] for w in said if "rasterizer kernel" in str(w.message)]
    assert told == ["torch.compile of rasterizer kernel doubled"]
    assert not kernels.kernels_compiled() and not kernels.compile_pending()


def test_a_kernel_called_again_compiles_nothing_and_the_clock_runs_on(clock, monkeypatch):
    """Only a kernel's first call with new dtypes compiles: a call that compiles nothing must neither stop the clock
    (taken for a compile the callbacks missed, every run warned and recorded a null compile time) nor add to it (a
    callback registered again, or the compiler's load counted again, at every call of every step)."""
    monkeypatch.setattr(torch, "compile", timed_compile)
    run = kernels.compiled(doubled)
    run(torch.ones(3))
    timed = kernels.compile_seconds()
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        for _ in range(3):
            assert torch.equal(run(torch.ones(3)), torch.full((3,), 2.0))
    assert kernels.compile_seconds() == timed


def out_of_memory(x: torch.Tensor) -> torch.Tensor:
    """A kernel whose inputs fail it compiled or not, as a render too large for memory does."""
    raise MemoryError(f"cannot allocate {x.numel()} elements")


def test_a_kernel_that_fails_eager_too_raises_its_error_and_stays_compiled(clock, monkeypatch):
    """A compiled kernel that ran out of memory was taken for a failed compile: it warned 'torch.compile ... failed',
    turned every kernel eager for the rest of the process, and, the eager retry failing too, raised from inside the
    handler. The fault is the inputs', so their error is raised, with no warning, and compiling stays on."""
    monkeypatch.setattr(torch, "compile", timed_compile)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        with pytest.raises(MemoryError, match="cannot allocate 3 elements"):
            kernels.compiled(out_of_memory)(torch.ones(3))
        assert torch.equal(kernels.compiled(doubled)(torch.ones(3)), torch.full((3,), 2.0))
    assert kernels.kernels_compiled()
    assert kernels.compiled(doubled) is not doubled
