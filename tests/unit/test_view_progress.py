"""The per-view bar of evaluations and renders (train_progress.view_progress): every view counted on a terminal,
nothing written off one or with --no-progress, and during training drawn under the training bar."""

from __future__ import annotations

import io
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import torch

from splatu import evaluation, train_command, train_progress
from splatu.baselines.model_sources import OursSource
from splatu.model import GaussianModel, ModelConfig
from splatu.render_uncertainty import ViewSpec, render_views
from tests.unit.test_trainer import tiny_config, tiny_scene

VIEW_BAR = re.compile(r"(\w+) +(\d+)/(\d+) views ")
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


class Terminal(io.StringIO):
    """stderr as a terminal would be, recording what is drawn on it."""

    def isatty(self) -> bool:
        return True


@contextmanager
def on_a_terminal(monkeypatch) -> Iterator[Terminal]:
    """stderr swapped for a terminal inside a test's body: pytest's capture sets it back between fixtures and body."""
    for variable in ("FORCE_COLOR", "TTY_COMPATIBLE", "TTY_INTERACTIVE"):
        monkeypatch.delenv(variable, raising=False)
    monkeypatch.setenv("TERM", "xterm")  # not a dumb terminal, on which rich draws no live display
    monkeypatch.setattr(train_progress.console, "is_interactive", True)  # rich decides it once, at import
    screen, captured = Terminal(), sys.stderr
    sys.stderr = screen
    try:
        yield screen
    finally:
        sys.stderr = captured


def frames(drawn: str) -> list[str]:
    """What each redraw showed, escape codes removed."""
    return [ANSI.sub("", frame) for frame in drawn.split("\r") if ANSI.sub("", frame).strip()]


def view_counts(drawn: str) -> list[tuple[str, int, int]]:
    return [(m[1], int(m[2]), int(m[3])) for m in VIEW_BAR.finditer(ANSI.sub("", drawn))]


def empty_model() -> GaussianModel:
    return GaussianModel.empty_like_config(0, ModelConfig(sh_degree=0))  # renders the background alone


def test_an_evaluation_counts_every_view_on_a_terminal_and_leaves_nothing_behind(monkeypatch):
    views = tiny_scene(n_train=1, n_eval=3).eval
    views.mask_files = torch.ones(views.images.shape[:3])
    views.mask_files[1] = 0.0  # a view with nothing to score still counts as gone through
    with on_a_terminal(monkeypatch) as screen:
        metrics = evaluation.evaluate_views(empty_model(), views, 0, torch.zeros(3), "interp")
    assert metrics["num_images"] == 2
    counts = view_counts(screen.getvalue())
    assert counts[0] == ("interp", 0, 3) and counts[-1] == ("interp", 3, 3)
    assert screen.getvalue().endswith("\x1b[2K")  # the bar's line is erased at the end


def test_a_render_counts_every_view_on_a_terminal(monkeypatch):
    views = tiny_scene(n_train=1, n_eval=2).eval
    with on_a_terminal(monkeypatch) as screen:
        render_views(OursSource(empty_model(), 0, torch.zeros(3)),
                     ViewSpec(views.cameras, views.names, views, [0, 1]))
    assert view_counts(screen.getvalue())[-1] == ("render", 2, 2)


@pytest.mark.parametrize("force_color", [None, "1"])
def test_off_a_terminal_evaluations_and_renders_draw_nothing(capsys, monkeypatch, force_color):
    """A log file or CI gets no bar, also when FORCE_COLOR makes rich believe it writes to a terminal: the eval
    line or the command's closing line reports the result there."""
    monkeypatch.delenv("TTY_COMPATIBLE", raising=False)
    if force_color is None:
        monkeypatch.delenv("FORCE_COLOR", raising=False)
    else:
        monkeypatch.setenv("FORCE_COLOR", force_color)
    views = tiny_scene(n_train=1, n_eval=2).eval
    evaluation.evaluate_views(empty_model(), views, 0, torch.zeros(3))
    render_views(OursSource(empty_model(), 0, torch.zeros(3)), ViewSpec(views.cameras, views.names, views, [0, 1]))
    assert capsys.readouterr() == ("", "")


def test_without_progress_an_evaluation_draws_nothing_on_a_terminal(monkeypatch):
    views = tiny_scene(n_train=1, n_eval=2).eval
    with on_a_terminal(monkeypatch) as screen:
        evaluation.evaluate_views(empty_model(), views, 0, torch.zeros(3), progress=False)
    assert screen.getvalue() == ""


def test_a_periodic_evaluation_draws_under_the_training_bar(tmp_path, monkeypatch):
    """Both bars in one live display: the eval bar below the training bar, and the eval line printed whole above
    them, not cut into by a redraw."""
    monkeypatch.setattr(train_command, "load_scene", lambda data_config: tiny_scene())
    with on_a_terminal(monkeypatch) as screen:
        train_command.train(tiny_config(tmp_path, steps=12, checkpoint_every=0, progress=True, eval_every_steps=6))
    drawn = screen.getvalue()
    under = [frame.splitlines() for frame in frames(drawn) if VIEW_BAR.search(frame)]
    assert any(len(lines) == 2 and lines[0].startswith("step      6/12") and VIEW_BAR.match(lines[1])
               for lines in under)
    assert ("eval", 2, 2) in view_counts(drawn)
    assert any(re.fullmatch(r"step 6 eval \(2 views\): PSNR \d+\.\d\d dB, SSIM \d\.\d{3}", frame.splitlines()[0])
               for frame in frames(drawn))
