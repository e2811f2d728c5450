"""Stopping a training cleanly: Ctrl-C or SIGTERM finishes the step and saves; a second one aborts."""

from __future__ import annotations

import os
import shlex
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM: the run was saved (when it stopped between steps) and can be resumed."""

    def __init__(self, what: str, run_dir: Path, step: int, signal_number: int, resumable: bool = True) -> None:
        self.message = (f"{what}; resume with `splatu train --resume {shlex.quote(str(run_dir))}`" if resumable
                        else f"{what}; nothing to resume, so run the same `splatu train` command again")
        super().__init__(self.message)
        self.what = what
        self.run_dir = run_dir
        self.step = step
        self.signal_number = signal_number


class Terminated(KeyboardInterrupt):
    """SIGTERM outside the steps (loading the scene, between ensemble members), unwinding as Ctrl-C does."""

    signal_number = signal.SIGTERM


class Interrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM that stopped a command, retold with what it left written: the CLI's `interrupted: LEFT`."""

    def __init__(self, left: str, signal_number: int) -> None:
        super().__init__(left)
        self.left = left
        self.signal_number = signal_number


@contextmanager
def saying_what_is_left(left: Callable[[], str]) -> Iterator[None]:
    """A stop within the block, Ctrl-C or SIGTERM (`sigterm_as_ctrl_c`: by default SIGTERM would end the process
    there and then, unsaid), becomes `Interrupted`, saying `left()`: what is written once the block has unwound (its
    staging folders and temporaries removed), so the user knows whether an earlier output survived."""
    try:
        with sigterm_as_ctrl_c():
            yield
    except KeyboardInterrupt as stop:
        raise Interrupted(left(), signal_of(stop)) from stop


def signal_of(stop: KeyboardInterrupt) -> int:
    """The signal behind a stop: SIGTERM for `Terminated` and what carries it, else Ctrl-C's SIGINT."""
    return int(getattr(stop, "signal_number", signal.SIGINT))


def exit_code(stop: KeyboardInterrupt) -> int:
    """128 + the signal that stopped the command, the shell's convention: 130 for Ctrl-C, 143 for SIGTERM."""
    return 128 + signal_of(stop)


@dataclass
class StopRequest:
    """A Ctrl-C or SIGTERM received during training, to act on at the end of the step."""

    requested: bool = False
    signal_number: int = signal.SIGINT
    aborted: bool = False
    """A second stop came and raised at once: whatever was running (a step, an evaluation, a save) did not finish."""
    at_once: bool = False
    """Set by `stop_at_once`: a first stop raises at once too."""
    first_at: float = 0.0
    """When the first stop came (time.monotonic): a second within SAME_STOP_SECONDS of it is the same stop."""


@contextmanager
def stop_at_once(flag: StopRequest) -> Iterator[None]:
    """Within the block a first stop raises at once instead of waiting for the step's end: for work that changes no
    state a checkpoint holds and that a resume redoes, such as a periodic evaluation, which can take minutes on a
    real scene (past a batch scheduler's grace period before its SIGKILL)."""
    flag.at_once = True
    try:
        yield
    finally:
        flag.at_once = False


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""Ctrl-C, and `kill` or a batch scheduler's time limit: both finish the step and save."""


SAME_STOP_SECONDS = 0.5
"""A second signal this soon after the first is the same stop, not a second Ctrl-C: GNU `timeout -s INT` signals
both the command and its process group, so the command gets two SIGINTs microseconds apart (1 run in 8 aborted,
unsaved). A deliberate second Ctrl-C comes after the stop line was read, seconds later; 0.5 s leaves room for a
handler delayed by a loaded machine (it runs between bytecodes, so is timed when it runs, not when the signal came)."""


def say_at_once(line: str) -> None:
    """Write `line` to stderr from a signal handler, which may have interrupted rich's console or sys.stderr mid-write:
    os.write to the descriptor passes their buffers and locks by. On a terminal the live bar's line is erased first,
    so the line stands on its own and the bar redraws below it. A stderr without a descriptor (a test's capture) gets
    a plain write. Nothing it raises leaves it: an exception out of a handler ends the step where it stood, unsaved,
    and `train ... 2>&1 | tee log` meets a pipe whose reader the same Ctrl-C has just ended (BrokenPipeError)."""
    try:
        try:
            fd = sys.stderr.fileno()
        except (AttributeError, OSError, ValueError):
            sys.stderr.write(line + "\n")
            return
        os.write(fd, (("\r\x1b[2K" if os.isatty(fd) else "") + line + "\n").encode(errors="replace"))
    except Exception:  # any failure to tell must not cost the stop its checkpoint
        return


@contextmanager
def deferred_interrupt(announce: Callable[[int], str] | None = None) -> Iterator[StopRequest]:
    """First Ctrl-C (or SIGTERM): finish the current step, then stop cleanly; a second one (after SAME_STOP_SECONDS)
    aborts at once. `announce(signal)`, when given, is the line said at the first: the step may take a minute yet
    (the first one compiles the kernels), and a silent wait made users press Ctrl-C again, which aborted."""
    flag = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def handler(signum: int, frame: Any) -> None:
        now = time.monotonic()
        if flag.requested:
            if now - flag.first_at < SAME_STOP_SECONDS:
                return
            flag.aborted = True
            raise KeyboardInterrupt
        flag.requested, flag.signal_number, flag.first_at = True, signum, now
        if flag.at_once:  # the stop's own message follows at once; a line written under a nested bar is redrawn over
            raise KeyboardInterrupt
        if announce is not None:
            say_at_once(announce(signum))

    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield flag
    finally:
        for sig, before in previous.items():
            if before is not None:  # None: a handler set outside Python, which cannot be put back from here
                signal.signal(sig, before)


@contextmanager
def finish_first() -> Iterator[None]:
    """Writes that must land together (a render swapped in, a score and its plot): a Ctrl-C or SIGTERM during the
    block waits for its end and is raised then, as the stop it was; a second one aborts at once."""
    with deferred_interrupt() as stop:
        yield
    if stop.requested:
        raise Terminated if stop.signal_number == signal.SIGTERM else KeyboardInterrupt


@contextmanager
def sigterm_as_ctrl_c() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt for a whole command, as Ctrl-C does: outside the steps too (loading the
    scene, between ensemble members), a kill then unwinds through the code that records a session."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    def terminated(signum: int, frame: Any) -> None:
        raise Terminated

    before = signal.signal(signal.SIGTERM, terminated)
    try:
        yield
    finally:
        if before is not None:
            signal.signal(signal.SIGTERM, before)
