"""The per-view bar of evaluations and renders (train_progress.view_progress): every view counted on a terminal,
nothing written off one or with --no-progress, and during training drawn under the training bar. The same bar counts
the other waits of several seconds: a baseline's passes over the training views, the writing of a render's files
and the first build of the poster stand-in."""

from __future__ import annotations

import dataclasses
import io
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import torch

from splatu import evaluation, train_command, train_progress, trainer
from splatu.baselines import METHODS_FROM_TRAINING_VIEWS
from splatu.baselines.load import LoadedRun, build_method
from splatu.baselines.model_sources import OursSource
from splatu.checkpoint import list_checkpoints
from splatu.data.poster import PosterConfig, build_poster_standin
from splatu.data.scene import Scene
from splatu.model import GaussianModel, ModelConfig
from splatu.render_uncertainty import RenderedView, ViewSpec, render_views, write_outputs
from splatu.train_config import flags_given, load_config, preset_config
from tests.small_models import noise_views, overlapping_gaussians
from tests.unit.test_trainer import parsed, serve_scene, tiny_config, tiny_scene

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
    serve_scene(monkeypatch, lambda data_config: tiny_scene())
    with on_a_terminal(monkeypatch) as screen:
        train_command.train(tiny_config(tmp_path, steps=12, checkpoint_every=0, progress=True, eval_every_steps=6))
    drawn = screen.getvalue()
    under = [frame.splitlines() for frame in frames(drawn) if VIEW_BAR.search(frame)]
    assert any(len(lines) == 2 and lines[0].startswith("step      6/12") and VIEW_BAR.match(lines[1])
               for lines in under)
    assert ("eval", 2, 2) in view_counts(drawn)
    assert any(re.fullmatch(r"step 6 eval \(2 views\): PSNR \d+\.\d\d dB, SSIM \d\.\d{3}", frame.splitlines()[0])
               for frame in frames(drawn))


def test_a_resume_with_no_progress_draws_no_bar_on_a_terminal(tmp_path, monkeypatch):
    """--no-progress beside --resume was ignored (the run's saved options hold it), so a batch job resuming a run
    could not turn the bar off. The run's config.yml takes the session's value, and its older checkpoint, written
    with the bar on, still resumes."""
    serve_scene(monkeypatch, lambda data_config: tiny_scene())
    run_dir = train_command.train(tiny_config(tmp_path, progress=True))  # checkpoints at steps 6 and 12
    first = list_checkpoints(run_dir)[0]
    argv = ["--resume", str(first), "--no-progress"]
    with on_a_terminal(monkeypatch) as screen:
        train_command.train(parsed(argv), typed=flags_given(argv))
    drawn = screen.getvalue()
    assert "resuming" in drawn and "ignoring" not in drawn
    assert not [frame for frame in frames(drawn) if re.match(r"step +\d+/12", frame)]
    assert not load_config(run_dir / "config.yml").progress
    with on_a_terminal(monkeypatch) as screen:  # not refused as a checkpoint of another run
        train_command.train(parsed(["--resume", str(first)]), typed=flags_given(["--resume", str(first)]))
    assert any(re.match(r"step +12/12", frame) for frame in frames(screen.getvalue()))


def test_a_run_started_without_progress_stays_without_it_when_resumed_without_the_flag(tmp_path, monkeypatch):
    """The display option is the command's only where typed: a plain `--resume` of a run started with --no-progress
    drew the bar again, and `--progress` beside the resume draws it."""
    serve_scene(monkeypatch, lambda data_config: tiny_scene())
    run_dir = train_command.train(tiny_config(tmp_path, progress=False))  # checkpoints at steps 6 and 12
    first = list_checkpoints(run_dir)[0]
    for argv, bar in ((["--resume", str(first)], False), (["--resume", str(first), "--progress"], True)):
        with on_a_terminal(monkeypatch) as screen:
            train_command.train(parsed(argv), typed=flags_given(argv))
        assert any(re.match(r"step +\d+/12", frame) for frame in frames(screen.getvalue())) == bar, argv


def small_run() -> tuple[LoadedRun, Scene]:
    """A run of a few Gaussians over a scene of a few noise views, for the baselines that look at them first."""
    config = preset_config("fast")
    config = dataclasses.replace(config, model=dataclasses.replace(config.model, sh_degree=0))
    views = noise_views()
    return LoadedRun(Path("run"), config, [overlapping_gaussians()], None, [None]), Scene("t", "t", views, views,
                                                                                          torch.zeros(0, 3))


PASSES = {"visibility": ["visibility"], "fisher": ["information"], "angle": ["coverage"],
          "residual": ["residuals"], "ours-residual": ["residuals"], "ours-residual-angle": ["residuals", "coverage"],
          "ours-view-residual-angle": ["residuals", "coverage"]}
"""The passes over the training views each method makes, by the last word of their bar."""


@pytest.mark.parametrize("method", METHODS_FROM_TRAINING_VIEWS)
def test_a_baseline_counts_its_passes_over_the_training_views_on_a_terminal(monkeypatch, method):
    """Their setup took ~10-40 s on the poster stand-in with nothing on screen before the render's bar."""
    run, scene = small_run()
    with on_a_terminal(monkeypatch) as screen:
        build_method(method, run, scene)
    views = len(scene.train)
    counts = view_counts(screen.getvalue())
    assert [name for name in dict.fromkeys(name for name, _, _ in counts)] == PASSES[method]
    assert all((name, views, views) in counts for name in PASSES[method])
    assert screen.getvalue().endswith("\x1b[2K")  # erased at the end, before the render's bar


def test_a_method_that_renders_the_model_alone_draws_nothing_before_its_render(monkeypatch):
    run, scene = small_run()
    with on_a_terminal(monkeypatch) as screen:
        build_method("ours", run, scene)
    assert screen.getvalue() == ""


def test_writing_a_render_counts_its_views_on_a_terminal(monkeypatch, tmp_path):
    """PNGs and matplotlib panels took 6-9 s for the stand-in's 33 eval views after the render's bar was gone."""
    maps = {"rgb": np.zeros((4, 6, 3)), "depth": np.ones((4, 6)), "alpha": np.ones((4, 6)),
            "uncertainty": np.full((4, 6), 0.5)}
    views = [RenderedView(f"v{k}", dict(maps)) for k in range(3)]
    with on_a_terminal(monkeypatch) as screen:
        write_outputs(tmp_path, views, orbit=False, fps=6)
    assert view_counts(screen.getvalue())[-1] == ("write", 3, 3)
    assert len(list((tmp_path / "panels").iterdir())) == 3


TINY_POSTER = PosterConfig(width=16, height=24, frames=8, eval_block=2, interp_every=3, points=50, supersample=1)


def test_the_first_build_of_the_poster_stand_in_counts_its_frames_on_a_terminal(monkeypatch, tmp_path):
    """~11 s at the default size with nothing on screen; a second load finds it built and draws nothing."""
    with on_a_terminal(monkeypatch) as screen:
        build_poster_standin(TINY_POSTER, tmp_path)
    drawn = [frame for frame in frames(screen.getvalue()) if "building the poster stand-in" in frame]
    assert drawn and re.search(rf"stand-in +{TINY_POSTER.frames}/{TINY_POSTER.frames} views", drawn[-1])
    assert screen.getvalue().endswith("\x1b[2K")
    with on_a_terminal(monkeypatch) as screen:
        build_poster_standin(TINY_POSTER, tmp_path)
    assert screen.getvalue() == ""


@pytest.mark.parametrize("force_color", [None, "1"])
def test_off_a_terminal_the_setup_the_writing_and_the_stand_in_draw_nothing(capsys, monkeypatch, tmp_path,
                                                                          force_color):
    """Loading a scene, in particular, says nothing in a log or a pipe (test_loaders pins it for load_scene)."""
    monkeypatch.delenv("TTY_COMPATIBLE", raising=False)
    if force_color is None:
        monkeypatch.delenv("FORCE_COLOR", raising=False)
    else:
        monkeypatch.setenv("FORCE_COLOR", force_color)
    run, scene = small_run()
    build_method("ours-residual-angle", run, scene)
    maps = {"rgb": np.zeros((4, 6, 3)), "depth": np.ones((4, 6)), "alpha": np.ones((4, 6)),
            "uncertainty": np.zeros((4, 6))}
    write_outputs(tmp_path / "render", [RenderedView("v", maps)], orbit=False, fps=6)
    build_poster_standin(TINY_POSTER, tmp_path / "cache")
    assert capsys.readouterr() == ("", "")


def test_the_training_bar_shows_the_time_elapsed_while_the_first_step_compiles(tmp_path, monkeypatch):
    """Step 0 with no rate and no ETA stayed still for the ~10 s (a minute cold) of the kernels' compile. Its loss,
    PSNR and rate are dashes: they read `loss 0.0000 PSNR  0.00 0.0 it/s`, figures no step had."""
    serve_scene(monkeypatch, lambda data_config: tiny_scene())
    with on_a_terminal(monkeypatch) as screen:  # 80 columns, which cut the bar's end
        train_command.train(tiny_config(tmp_path, steps=2, checkpoint_every=0, progress=True))
    drawn = frames(screen.getvalue())
    assert any(re.match(r"step +0/2 loss +- PSNR +- #G +300 +- it/s \d:\d\d:\d\d<", frame) for frame in drawn)


def test_the_training_bar_says_the_first_step_compiles_then_shows_its_figures(tmp_path, monkeypatch):
    """On a terminal the bar sat on step 0 with dashes for the compile's ~10 s (minutes cold), while a log was told
    (COMPILE_LINE); the compile itself is not run here, only said to be due."""
    monkeypatch.setattr(trainer, "compile_pending", lambda: True)
    serve_scene(monkeypatch, lambda data_config: tiny_scene())
    with on_a_terminal(monkeypatch) as screen:
        train_command.train(tiny_config(tmp_path, steps=2, checkpoint_every=0, progress=True))
    drawn = [frame for frame in frames(screen.getvalue()) if re.match(r"step +\d/2", frame)]
    assert any(re.match(rf"step +0/2 {train_progress.COMPILE_FIGURES} +\d:\d\d:\d\d<", frame) for frame in drawn)
    assert not [frame for frame in drawn if "compiling" in frame and not frame.startswith("step      0/2")]
    assert re.match(r"step +2/2 +loss \d\.\d{4} PSNR", drawn[-1])


def test_the_training_bar_keeps_every_figure_on_an_80_column_terminal(tmp_path, monkeypatch):
    """The issue's figures (step, loss, PSNR, Gaussians, it/s, ETA) all on the line: the bar, last, takes the rest."""
    serve_scene(monkeypatch, lambda data_config: tiny_scene())
    with on_a_terminal(monkeypatch) as screen:
        assert train_progress.console.width == 80
        train_command.train(tiny_config(tmp_path, steps=2, checkpoint_every=0, progress=True))
    last = [frame for frame in frames(screen.getvalue()) if frame.startswith("step ") and "/2" in frame][-1]
    assert re.match(r"step +2/2 +loss \d\.\d{4} PSNR +[\d.]+ #G +\d+ +[\d.]+ it/s \d:\d\d:\d\d<\d:\d\d:\d\d ━", last)

