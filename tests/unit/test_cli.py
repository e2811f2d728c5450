import itertools
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from splatu.cli import entrypoint
from splatu.data.splits import contiguous_split, every_n_split, list_split
from splatu.errors import SplatuError
from splatu.methods import METHODS
from splatu.train_config import MAX_SEED


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "splatu", *args], capture_output=True, text=True, timeout=120)


def test_help_lists_subcommands():
    out = run_cli("--help")
    assert out.returncode == 0
    for name in ("train", "render-uncertainty", "eval-ause"):
        assert name in out.stdout


IMPORTED_BY_HELP = """
import sys
from splatu.cli import entrypoint
try:
    entrypoint(sys.argv[1:])
except SystemExit:
    pass
print(*(name for name in ("torch", "matplotlib", "pycolmap", "cv2") if name in sys.modules), file=sys.stderr)
"""


@pytest.mark.parametrize(("argv", "imported"), [
    (["--help"], ""), (["export", "--help"], "torch cv2"), (["eval-ause", "--help"], "torch cv2")])
def test_help_imports_only_what_the_options_shown_need(argv, imported):
    """`splatu --help` imported every command's module, torch, matplotlib and pycolmap among them (4-5 s here),
    and each command's help did too; eval-ause's plots (matplotlib) are its run's alone."""
    out = subprocess.run([sys.executable, "-c", IMPORTED_BY_HELP, *argv], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "usage: splatu" in out.stdout
    assert out.stderr.splitlines() == [imported]


def test_user_error_is_one_line_without_traceback(capsys, monkeypatch):
    from splatu import cli

    def boom(argv, debug=False):
        raise SplatuError("thing broke", "in /some/file", "do the fix")

    monkeypatch.setattr(cli, "main", boom)
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.strip() == "error: thing broke, in /some/file, do the fix"
    assert "Traceback" not in err


def test_debug_flag_shows_the_exception(monkeypatch):
    from splatu import cli

    def boom(argv, debug=False):
        raise SplatuError("thing broke", "here", "fix")

    monkeypatch.setattr(cli, "main", boom)
    with pytest.raises(SplatuError):
        entrypoint(["train", "--debug"])


def test_train_missing_path_is_one_clear_line():
    out = run_cli("train", "--data", "/nonexistent")
    assert out.returncode != 0
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), out.stderr
    assert "Traceback" not in out.stderr


def test_contiguous_split_is_a_seeded_block():
    train, ev = contiguous_split(20, 5, seed=3)
    assert len(ev) == 5 and ev == list(range(ev[0], ev[0] + 5))
    assert sorted(train + ev) == list(range(20))
    assert contiguous_split(20, 5, seed=3) == (train, ev)
    starts = {contiguous_split(100, 5, seed=s)[1][0] for s in range(10)}
    assert len(starts) > 1


def test_every_n_split_matches_nerfstudio_rule():
    train, ev = every_n_split(17, 8)
    assert ev == [0, 8, 16]
    assert 8 not in train and len(train) == 14


def test_split_errors_are_user_errors():
    with pytest.raises(SplatuError):
        contiguous_split(5, 5, 0)
    with pytest.raises(SplatuError):
        list_split(["a", "b"], ["c"], "eval.txt")
    with pytest.raises(SplatuError):
        list_split(["a", "b"], ["a", "b"], "eval.txt")


KILLED_AFTER_LOADING_COMMANDS = """
import os, signal, time
from splatu.cli import main
try:
    main(["process-images", "--help"])  # loads its module, and with it pycolmap
except SystemExit:
    pass
os.kill(os.getpid(), signal.SIGTERM)
time.sleep(60)
"""


def test_sigterm_ends_the_cli_quietly_rather_than_through_glogs_crash_handler():
    """pycolmap's import puts glog's handler on SIGTERM; it printed a native stack trace and then hung in malloc."""
    import signal

    def killed(code: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)

    bare = killed("import os, signal, time, pycolmap\nos.kill(os.getpid(), signal.SIGTERM)\ntime.sleep(60)")
    if "SIGTERM" not in bare.stderr:
        pytest.skip("this pycolmap does not install glog's SIGTERM handler, so there is nothing to undo")
    out = killed(KILLED_AFTER_LOADING_COMMANDS)
    assert out.returncode == -signal.SIGTERM
    assert "SIGTERM" not in out.stderr and "Aborted" not in out.stderr


@pytest.mark.parametrize("argv", [
    ["render-uncertainty", "--gif-fps", "0"], ["render-uncertainty", "--views", "orbit", "--gif-fps", "1000"],
    ["render-uncertainty", "--fisher-probes", "0"],
    ["render-uncertainty", "--max-views", "-1"], ["render-uncertainty", "--orbit-frames", "0"],
    ["render-uncertainty", "--orbit-radius-scale", "0"], ["eval-ause", "--fisher-probes", "0"],
    ["render-uncertainty", "--views", "orbit", "--orbit-radius-scale", "0"],
    ["train", "--seed", "-1"], ["train", "--seed", str(2**44)], ["train", "--ssim-lambda", "2"],
    ["train", "--model.screen-blur", "0"], ["train", "--model.screen-blur", "nan"],
    ["train", "--model.u-init-logit", "inf"], ["train", "--model.u-init-logit", "nan"],
    ["train", "--model.u-init-logit", "1e30"], ["render-uncertainty", "--method", "random", "--seed", "-1"],
    ["eval-ause", "--method", "fisher", "--seed", str(2**40)], ["train", "--model.sh-degree-interval", "0"],
    ["train", "--densify.cull-alpha-thresh", "0"], ["train", "--densify.densify-grad-thresh", "nan"],
    ["train", "--densify.warmup-length", "-1"],
    ["render-uncertainty", "--orbit-frames", "4"], ["render-uncertainty", "--orbit-shape", "arc"],
    ["render-uncertainty", "--orbit-radius-scale", "1"], ["render-uncertainty", "--method", "ours", "--density-aware"],
    ["render-uncertainty", "--method", "random", "--fisher-probes", "4"],
    ["eval-ause", "--method", "ours", "--density-aware"],
    ["eval-ause", "--method", "fisher", "--fisher-probes", "0"],
    ["render-uncertainty", "--method", "random", "--seed", str(MAX_SEED)],
])
def test_an_option_out_of_range_or_unused_is_one_line_before_any_work(capsys, tmp_path, argv):
    """These used to fail late: a ZeroDivisionError after every view was rendered (--gif-fps 0), a GIF with no frame
    delay, which browsers play slower than at 20 fps (--gif-fps 1000), a NaN blamed on
    the model (--fisher-probes 0), an overflow in the camera shuffle (a huge seed); or to be ignored silently
    (an orbit option without --views orbit, a method option with another method)."""
    with pytest.raises(SystemExit) as exc:
        entrypoint([*argv, "--load" if argv[0] != "train" else "--data", str(tmp_path / "absent")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --") and err.count("\n") == 1, err


@pytest.mark.parametrize(("argv", "line"), [
    (["--model.u-sh-degree", "9"],
     "u_sh_degree = 9 is out of range, in --model.u-sh-degree, use a degree from 0 to 3"),
    (["--uncertainty.lam", "0.7"],
     "uncertainty λ = 0.7 is not in [0, 0.5), in --uncertainty.lam, use λ < 0.5 (the paper's condition), e.g. 0.3"),
    (["--uncertainty.extra-heads", "x"],
     "bad uncertainty head 'x': not key=value, in --uncertainty.extra-heads, write key=value pairs joined by commas, "
     "keys from kind, lam, threshold, num_dirs, degree"),
    (["--uncertainty.threshold", "0"],
     "uncertainty threshold = 0.0 is not a blend weight in (0, 0.99], in --uncertainty.threshold, use e.g. 0.05"),
    (["--uncertainty.threshold", "1"],
     "uncertainty threshold = 1.0 is above 0.99, the largest blend weight (α is clamped there), so it would supervise "
     "no Gaussian, in --uncertainty.threshold, use e.g. 0.05"),
    (["--uncertainty.extra-heads", "lam=0.1,threshold=0"],
     "uncertainty threshold = 0.0 is not a blend weight in (0, 0.99] in uncertainty head 'lam=0.1,threshold=0', "
     "in --uncertainty.extra-heads, use e.g. 0.05"),
    (["--uncertainty.kind", "weighted", "--uncertainty.threshold", "0.2"],
     "--uncertainty.threshold 0.2 is not read by the loss --uncertainty.kind weighted trains: that loss weights each "
     "Gaussian the view sees by its max blend weight, instead of a hard threshold, in --uncertainty.threshold, drop "
     "it, or use --uncertainty.kind antipodal or mean"),
    (["--uncertainty.num-dirs", "32"],
     "--uncertainty.num-dirs 32 is not read by the loss --uncertainty.kind antipodal trains: only the mean loss draws "
     "random directions, in --uncertainty.num-dirs, drop it, or use --uncertainty.kind mean"),
    (["--uncertainty.kind", "mean", "--uncertainty.extra-heads", "kind=weighted,threshold=0.2", "num_dirs=8"],
     "threshold=0.2 is not read by the loss of uncertainty head 'kind=weighted,threshold=0.2', whose kind is "
     "weighted: that loss weights each Gaussian the view sees by its max blend weight, instead of a hard threshold, "
     "in --uncertainty.extra-heads, drop threshold, or give the head kind antipodal or kind mean"),
    (["--uncertainty.extra-heads", "num_dirs=8"],
     "num_dirs=8 is not read by the loss of uncertainty head 'num_dirs=8', whose kind is antipodal: only the mean "
     "loss draws random directions, in --uncertainty.extra-heads, drop num_dirs, or give the head kind mean"),
    (["--degree-choice.on", "--ensemble", "2"],
     "an ensemble's members must differ only in seed, but each would choose its own degrees, in --degree-choice.on "
     "with --ensemble, choose the degrees with one run, then train the ensemble with --model.sh-degree and "
     "--model.u-sh-degree set to what it chose"),
])
def test_an_error_in_an_option_says_in_before_it(capsys, tmp_path, argv, line):
    """Every error reads "what, in WHERE, fix"; these named the option bare ("out of range, --model.u-sh-degree")."""
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train", *argv, "--data", str(tmp_path / "absent")])
    assert exc.value.code == 2
    assert capsys.readouterr().err == f"error: {line}\n"


@pytest.mark.parametrize(("argv", "line"), [
    (["--method", "splatfacto", "--uncertainty.kind", "mean", "--uncertainty.lam", "0.3"],
     "--uncertainty.kind mean --uncertainty.lam 0.3 set options of the uncertainty loss, which --method splatfacto "
     "does not train, in the options, drop them, or pass --method splatu to train the loss"),
    (["--method", "splatfacto", "--model.u-sh-degree", "1"],
     "--model.u-sh-degree 1 sets an option of the uncertainty loss, which --method splatfacto does not train, in the "
     "options, drop it, or pass --method splatu to train the loss"),
    (["--method", "ensemble", "--uncertainty.threshold", "0.1"],
     "--uncertainty.threshold 0.1 sets an option of the uncertainty loss, which --method ensemble (its members are "
     "plain splatfacto) does not train, in the options, drop it, or pass --method splatu to train the loss"),
    (["--uncertainty.off", "--uncertainty.kind", "weighted"],
     "--uncertainty.kind weighted sets an option of the uncertainty loss, which --uncertainty.off does not train, in "
     "the options, drop it, or drop --uncertainty.off to train the loss"),
    (["--uncertainty.off", "--method=splatu", "--uncertainty.kind", "weighted"],
     "--method splatu trains the uncertainty loss, which --uncertainty.off turns off, in the options, drop "
     "--uncertainty.off, or pass --method splatfacto for plain 3DGS"),
])
def test_uncertainty_options_typed_for_a_run_without_the_loss_are_refused(capsys, tmp_path, argv, line):
    """They were accepted, and config.yml recorded options that did nothing (the last only noted the run was filed
    as splatfacto)."""
    with pytest.raises(SystemExit):
        entrypoint(["train", *argv, "--data", str(tmp_path / "absent")])
    assert capsys.readouterr().err == f"error: {line}\n"


@pytest.mark.parametrize(("preset", "argv"), [
    ("model:\n  u_sh_degree: 1\nuncertainty:\n  lam: 0.2\n", ["--method", "splatfacto"]),  # the file's, not typed
    ("", ["--method", "ensemble", "--uncertainty.no-off", "--uncertainty.lam", "0.2"]),  # members with the loss
    ("", ["--method", "splatfacto", "--uncertainty.off"]),
])
def test_uncertainty_options_not_typed_or_trained_are_no_error(capsys, tmp_path, preset, argv):
    assert _train_error(capsys, tmp_path, preset, *argv).startswith("error: scene not found, in ")


def _train_error(capsys, tmp_path, preset: str, *flags: str) -> str:
    """What `splatu train` says (on stderr, exiting 2) with a preset file holding `preset`."""
    (tmp_path / "p.yaml").write_text(preset)
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train", "--preset", str(tmp_path / "p.yaml"), *flags, "--data", str(tmp_path / "absent")])
    assert exc.value.code == 2
    return capsys.readouterr().err


@pytest.mark.parametrize(("preset", "line"), [
    ("steps: -5\n", "steps: -5 must be at least 1, in {}, set steps to at least 1 in that file, or override it with "
                    "--steps"),
    ("model:\n  sh_degree_interval: 0\n", "model.sh_degree_interval: 0 must be at least 1, in {}, set "
     "model.sh_degree_interval to at least 1 in that file, or override it with --model.sh-degree-interval"),
    ("data:\n  downscale: 0\n", "data.downscale: 0 must be at least 1, in {}, set data.downscale to at least 1 in "
                                 "that file, or override it with --downscale"),
    ("model:\n  u_sh_degree: 9\n", "u_sh_degree = 9 is out of range, in {}, fix model.u_sh_degree in that file, or "
                                    "override it with --model.u-sh-degree"),
    ("optim:\n  means_lr: -1\n", "optim.means_lr must be a positive learning rate (got -1.0), in {}, fix "
                                  "optim.means_lr in that file, or override it with --optim.means-lr"),
    ("uncertainty:\n  lam: 0.7\n", "uncertainty λ = 0.7 is not in [0, 0.5), in {}, fix uncertainty.lam in that "
                                    "file, or override it with --uncertainty.lam"),
    # the fix of means_lr_steps mentions --steps in passing: the file's steps is not the one to blame
    ("steps: 100\noptim:\n  means_lr_steps: -1\n", "optim.means_lr_steps must be 0 or more (got -1), in {}, fix "
     "optim.means_lr_steps in that file, or override it with --optim.means-lr-steps"),
    ("degree_choice:\n  held_out: 0.125\n  at: 1.5\n", "held_out = 0.125 and at = 1.5 must both be in (0, 1), in {}, "
     "fix degree_choice.held_out or degree_choice.at in that file, or override it with --degree-choice.held-out or "
     "--degree-choice.at"),
])
def test_a_bad_value_in_a_preset_file_is_blamed_on_the_file(capsys, tmp_path, preset, line):
    """It was told as the flag's ("--steps must be at least 1 (got -5), in the options"), which was never typed."""
    assert _train_error(capsys, tmp_path, preset) == f"error: {line.format(tmp_path / 'p.yaml')}\n"


@pytest.mark.parametrize("flag", ["--steps", "--steps=", "--model.sh_degree_interval", "--model.sh-degree-interval"])
def test_a_flag_replaces_a_bad_value_of_the_preset_file(capsys, tmp_path, flag):
    """The preset's value was refused before the flag could replace it."""
    preset = "steps: -5\n" if flag.startswith("--steps") else "model:\n  sh_degree_interval: 0\n"
    flags = [flag + "10"] if flag.endswith("=") else [flag, "10"]
    assert _train_error(capsys, tmp_path, preset, *flags).startswith("error: scene not found, in ")


@pytest.mark.parametrize(("preset", "flags", "line"), [
    ("data:\n  eval_every: 1\n", ["--eval-split", "every-n"],
     "data.eval_every: 1 must be at least 2, in {}, set data.eval_every to at least 2 in that file, or override it "
     "with --eval-every"),
    # the check's own fix: "override it with --eval-every" (or --downscale) was offered, and is refused just the same
    ("data:\n  eval_split: every-n\n  eval_every: 4\n", ["--eval-split", "contiguous"],
     "data.eval_every is not used by --eval-split contiguous, in {}, pass --eval-split every-n to use "
     "data.eval_every, or drop data.eval_every"),
    ("data:\n  downscale: 2\n", ["--max-image-size", "400"],
     "--max-image-size 400 is not used beside data.downscale 2, which sets the image size itself, in {}, drop "
     "--max-image-size, or drop data.downscale to have train choose the factor from it"),
])
def test_a_preset_value_refused_beside_a_flag_is_blamed_on_the_file(capsys, tmp_path, preset, flags, line):
    """A check of two options, one from the file and one typed, named the file's option by a flag never typed
    ("--eval-every must be at least 2 (got 1), in the options")."""
    assert _train_error(capsys, tmp_path, preset, *flags) == f"error: {line.format(tmp_path / 'p.yaml')}\n"


@pytest.mark.parametrize("preset", [None, "steps: 100\n"])
def test_a_typed_flags_error_whose_fix_names_the_files_option_is_the_flags(capsys, tmp_path, preset):
    """The fix's "over the run's --steps" named the file's steps in passing, and the typed flag's error was blamed
    on the file: on configs/fast.yaml for a bare `splatu train` (preset None)."""
    line = ("error: --optim.means-lr-steps must be 0 or more (got -1), in the training options, pass 0 to decay over "
            "the run's --steps\n")
    if preset is not None:
        assert _train_error(capsys, tmp_path, preset, "--optim.means-lr-steps", "-1") == line
        return
    with pytest.raises(SystemExit):
        entrypoint(["train", "--optim.means-lr-steps", "-1", "--data", str(tmp_path / "absent")])
    assert capsys.readouterr().err == line


def test_a_flag_typed_with_the_files_own_value_is_the_flags(capsys, tmp_path):
    """The command line tells a typed flag from the file's value, equal or not: it was blamed on the file."""
    flags = ("--eval-split", "every-n", "--eval-every", "1")
    assert _train_error(capsys, tmp_path, "data:\n  eval_every: 1\n", *flags) == (
        "error: --eval-every must be at least 2 (got 1), in the options, pass --eval-every of at least 2\n")


@pytest.mark.parametrize("preset", ["steps: -5\n", "steps: 20\n", "seed: 3\n"])
def test_a_bad_flag_beside_a_preset_file_is_the_flags(capsys, tmp_path, preset):
    assert _train_error(capsys, tmp_path, preset, "--steps", "-3") == (
        "error: --steps must be at least 1 (got -3), in the options, pass --steps of at least 1\n")


@pytest.mark.parametrize("flags", [["--max-image-size", "400"], ["--max-image-size=400", "--preset", "quality"]])
def test_a_typed_max_image_size_beside_downscale_is_refused(capsys, tmp_path, flags):
    """--downscale sets the size, so a --max-image-size typed beside it was ignored without a word."""
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train", "--downscale", "2", *flags, "--data", str(tmp_path / "absent")])
    assert exc.value.code == 2
    assert capsys.readouterr().err == (
        "error: --max-image-size 400 is not used beside --downscale 2, which sets the image size itself, in the "
        "options, drop --max-image-size, or drop --downscale to have train choose the factor from it\n")


def test_a_max_image_size_typed_at_the_presets_value_beside_downscale_is_refused(capsys, tmp_path):
    """fast's own 800 px typed beside --downscale asks for two sizes too: told by value, it went unrefused."""
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train", "--preset", "fast", "--downscale", "2", "--max-image-size", "800", "--data",
                    str(tmp_path / "absent")])
    assert exc.value.code == 2
    assert capsys.readouterr().err.startswith("error: --max-image-size 800 is not used beside --downscale 2")


@pytest.mark.parametrize("preset", ["fast", "quality"])
def test_the_presets_max_image_size_beside_downscale_is_no_error(capsys, tmp_path, preset):
    """fast's own 800 px is no typed --max-image-size: --downscale alone goes on to load the scene."""
    with pytest.raises(SystemExit):
        entrypoint(["train", "--preset", preset, "--downscale", "2", "--data", str(tmp_path / "absent")])
    assert capsys.readouterr().err.startswith("error: scene not found, in ")


def test_version(capsys):
    from splatu import __version__

    entrypoint(["--version"])
    assert capsys.readouterr().out == f"splatu {__version__}\n"


@pytest.mark.parametrize(("argv", "said", "hint"), [
    (["train", "--steps", "abc"], "--steps takes a whole number, got 'abc'", "see `splatu train --help`"),
    (["train", "--stepz", "3"], "unrecognized options: --stepz, 3",
     "did you mean --steps? (see `splatu train --help`)"),
    (["--bogus"], "unrecognized or misplaced options: --bogus",
     "put each option after its subcommand; available subcommands: train, render-uncertainty, eval-ause, export, "
     "process-images (see `splatu --help`)"),
    (["render-uncertainty", "--views", "bogus"], "--views takes one of eval, train, orbit, cameras, got 'bogus'",
     "see `splatu render-uncertainty --help`"),
    (["train", "--steps"], "--steps needs a value after it", "see `splatu train --help`"),
    ([], "expected one of {train, render-uncertainty, eval-ause, export, process-images}", "see `splatu --help`"),
])
def test_a_parse_error_is_one_line_with_the_fix(capsys, argv, said, hint):
    """tyro draws a parse error as a box of up to 15 lines; like every other user error, it is one line."""
    with pytest.raises(SystemExit) as exc:
        entrypoint(argv)
    assert exc.value.code == 2
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1 and captured.err.startswith("error: "), captured.err
    assert said in captured.err and hint in captured.err and "│" not in captured.err, captured.err


@pytest.mark.parametrize(("argv", "line"), [
    (["--uncertainty.off", "True"], "--uncertainty.off takes no value, got 'True', on the command line, write "
     "--uncertainty.off alone to turn it on, or --uncertainty.no-off to turn it off"),
    (["--uncertainty.off=True"], "--uncertainty.off takes no value, got 'True', on the command line, write "
     "--uncertainty.off alone to turn it on, or --uncertainty.no-off to turn it off"),
    (["--no-progress", "false"], "--no-progress takes no value, got 'false', on the command line, write --progress "
     "alone to turn it on, or --no-progress to turn it off"),
    (["--steps=3", "4"], "unrecognized options: 4, on the command line, see `splatu train --help`"),  # not a switch
    (["--steps", "5", "5"], "unrecognized options: 5, on the command line, see `splatu train --help`"),  # twice
    (["--no-progress", "--steps", "5", "5"], "unrecognized options: 5, on the command line"),  # a switch elsewhere
    (["--uncertainty.off", "--steps", "5", "--bogus", "5"], "unrecognized options: --bogus, 5, on the command line"),
    (["--off", "True"], "unrecognized options: --off, True, on the command line"),  # a last name, but no flag here
])
def test_a_value_after_a_boolean_flag_says_the_flag_takes_none(capsys, argv, line):
    """`--uncertainty.off True` said "unrecognized options: True", of a word the user meant as the flag's value."""
    with pytest.raises(SystemExit):
        entrypoint(["train", "--data", "poster", *argv])
    assert capsys.readouterr().err.startswith(f"error: {line}")


def test_a_value_after_a_boolean_flag_of_a_config_without_its_prefix_says_the_flag_takes_none(capsys):
    """render-uncertainty takes its uncertainty options without the `uncertainty.` prefix (tyro's OmitArgPrefixes)."""
    with pytest.raises(SystemExit):
        entrypoint(["render-uncertainty", "--density-aware", "true"])
    assert capsys.readouterr().err.startswith("error: --density-aware takes no value, got 'true', on the command "
                                              "line, write --density-aware alone to turn it on, or --no-density-aware")


@pytest.mark.parametrize(("argv", "line"), [
    (["train", "--downscale", "abc"], "--downscale takes a whole number (or None), got 'abc'"),
    (["train", "--downscale=2.5"], "--downscale takes a whole number (or None), got '2.5'"),
    (["train", "--steps", "1e3"], "--steps takes a whole number, got '1e3'"),
    (["train", "--steps", "['a', 'b']"], "--steps takes a whole number, got \"['a', 'b']\""),  # one value, not two
    (["train", "--downscale", "x']"], "--downscale takes a whole number (or None), got \"x']\""),
    (["train", "--ssim-lambda", "x"], "--ssim-lambda takes a number, got 'x'"),
    (["train", "--background", "1", "2", "x"], "--background takes 3 numbers, got '1' '2' 'x'"),
    (["train", "--background", "1", "2"], "--background needs 3 values after it"),
    (["train", "--train-background", "blue"], "--train-background takes one of random, black, white, got 'blue'"),
    (["train", "--extend-to", "x"], "--extend-to takes a whole number (or None), got 'x'"),
    (["render-uncertainty", "--method", "x"], "--method takes one of ours, ensemble, visibility, fisher, random, "
                                              "spread, ours-spread, residual, ours-residual, angle, "
                                              "ours-residual-angle, ours-view-residual-angle, got 'x'"),
    (["render-uncertainty", "--views", "all"], "--views takes one of eval, train, orbit, cameras, got 'all'"),
    (["eval-ause", "--metric", "mad"], "--metric takes one of mae, rmse, mse, got 'mad'"),
    (["export", "--load"], "--load needs a value after it"),
    (["process-images", "--camera-model", "FISHEYE"],
     "--camera-model takes one of SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, got 'FISHEYE'"),
    (["process-images", "--matcher", "vocab"], "--matcher takes one of exhaustive, sequential, got 'vocab'"),
])
def test_a_malformed_value_is_one_plain_line(capsys, argv, line):
    """tyro's message for a value of the wrong type showed Python's: "no type matching {None}|INT could be
    instantiated from ['abc']. Got errors: - <class 'NoneType'>: ..."; it says what the flag takes instead."""
    with pytest.raises(SystemExit) as exc:
        entrypoint(argv)
    assert exc.value.code == 2
    assert capsys.readouterr().err == f"error: {line}, on the command line, see `splatu {argv[0]} --help`\n"


def _tyro_box(argv: list[str]) -> str:
    """What tyro prints for `argv` against a config with the option types no splatu subcommand has yet."""
    import contextlib
    import dataclasses
    import io
    from typing import Literal

    import tyro

    @dataclasses.dataclass
    class Options:
        choice: Literal["x", "y"] | None = None
        numbers: list[int] = dataclasses.field(default_factory=list)
        pair: tuple[int, int] = (1, 2)
        scale: float | None = None
        level: Literal[0, 1, 2] = 0
        window: tuple[float, float] | None = None
        mixed: tuple[int, float] = (1, 2.0)

    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), pytest.raises(SystemExit):
        tyro.cli(Options, args=argv, prog="splatu")
    return stderr.getvalue()


@pytest.mark.parametrize(("argv", "what"), [
    (["--choice", "z"], "--choice takes one of x, y (or None), got 'z'"),
    (["--numbers", "1", "x"], "--numbers takes any number of whole numbers, got '1' 'x'"),
    (["--pair", "1", "x"], "--pair takes 2 whole numbers, got '1' 'x'"),
    (["--scale", "big"], "--scale takes a number (or None), got 'big'"),
    (["--level", "5"], "--level takes one of 0, 1, 2, got '5'"),
    (["--window", "1", "x"], "--window takes 2 numbers (or None), got '1' 'x'"),
    (["--mixed", "1.5", "2"], "--mixed takes a whole number then a number, got '1.5' '2'"),
])
def test_optional_literal_list_and_tuple_values_read_plainly_too(argv, what):
    from splatu.usage_errors import usage_error

    error = usage_error(_tyro_box(argv), "splatu", [])
    assert error is not None and error.what == what, (error, _tyro_box(argv))
    assert "<class" not in str(error) and "\n" not in str(error)


SUBCOMMANDS = "train, render-uncertainty, eval-ause, export, process-images"


@pytest.mark.parametrize(("argv", "line"), [
    (["bogus"], f"unknown subcommand 'bogus', on the command line, use one of {SUBCOMMANDS} (see `splatu --help`)"),
    (["render"], "unknown subcommand 'render', on the command line, did you mean `splatu render-uncertainty`? "
                 f"(the subcommands are {SUBCOMMANDS}; see `splatu --help`)"),
    (["trian", "--steps", "3"], "unknown subcommand 'trian', on the command line, did you mean `splatu train`? "
                                f"(the subcommands are {SUBCOMMANDS}; see `splatu --help`)"),
    (["--steps", "3", "train"], "unrecognized or misplaced options: --steps, 3, on the command line, put each option "
                                "after its subcommand (see `splatu --help`)"),
    # the subcommand in tyro's underscore spelling is built too, for tyro to tell the options before it misplaced
    (["--load", "x", "render_uncertainty"], "unrecognized or misplaced options: --load, x, on the command line, put "
                                            "each option after its subcommand (see `splatu --help`)"),
    # no subcommand: none is built, and the options it would take are misplaced all the same
    (["--load", "x"], "unrecognized or misplaced options: --load, x, on the command line, put each option after its "
                      f"subcommand; available subcommands: {SUBCOMMANDS} (see `splatu --help`)"),
])
def test_a_mistyped_subcommand_names_them_all_and_the_closest(capsys, argv, line):
    """tyro's list of subcommands is wrapped over two lines of its box, and only the first was kept
    ("export, (see"); a word after the mistyped one came with tyro's "(applied to splatu)" notes."""
    with pytest.raises(SystemExit) as exc:
        entrypoint(argv)
    assert exc.value.code == 2
    assert capsys.readouterr().err == f"error: {line}\n"


def test_only_the_chosen_subcommands_flags_are_suggested(capsys):
    """tyro suggests flags of every subcommand; `eval-ause --step` used to be told to try train's --steps."""
    with pytest.raises(SystemExit):
        entrypoint(["eval-ause", "--step", "3"])
    err = capsys.readouterr().err
    assert "unrecognized options: --step, 3" in err and "--steps" not in err and "did you mean" not in err


def test_the_nearest_suggested_flag_comes_first(capsys):
    """tyro lists its guesses alphabetically: `--step` read "did you mean --eval-every-steps or
    --max-nonfinite-steps or --optim.means-lr-steps or --steps?", the flag meant last."""
    with pytest.raises(SystemExit):
        entrypoint(["train", "--step", "3"])
    assert "did you mean --steps or " in capsys.readouterr().err


@pytest.mark.parametrize("command", ["render-uncertainty", "export", "eval-ause"])
def test_a_missing_default_load_is_said_to_be_the_default(capsys, monkeypatch, tmp_path, command):
    """Without --load, in a folder with no demo run, the error named outputs/poster/splatu/latest as if typed;
    eval-ause asked for --load or --maps instead of defaulting as the others do."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit):
        entrypoint([command])
    or_maps = ", or --maps DIR to score maps written elsewhere" if command == "eval-ause" else ""
    assert capsys.readouterr().err == (
        f"error: no --load given, and no run at its default outputs/poster/splatu/latest, in {tmp_path}, pass --load "
        f"RUN, a run folder (outputs/<scene>/<method>/latest) or a checkpoint{or_maps}\n")


def test_eval_ause_without_load_scores_the_demo_run(monkeypatch, tmp_path):
    """eval-ause, like render-uncertainty and export, takes outputs/poster/splatu/latest when given no --load, and
    --maps alone reads its maps without looking there."""
    from splatu import eval_ause

    monkeypatch.chdir(tmp_path)
    demo = tmp_path / "outputs" / "poster" / "splatu" / "latest"
    demo.mkdir(parents=True)
    loaded: list[tuple] = []
    monkeypatch.setattr(eval_ause, "run", lambda config: loaded.append((config.load, config.maps)))
    entrypoint(["eval-ause"])
    entrypoint(["eval-ause", "--maps", "elsewhere"])
    assert loaded == [(Path("outputs/poster/splatu/latest"), None), (None, Path("elsewhere"))]


def test_debug_shows_tyros_own_parse_error(capsys):
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train", "--stepz", "3", "--debug"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Unrecognized options" in err and err.count("\n") > 3 and not err.startswith("error: ")


def test_help_still_prints_in_full(capsys):
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "--steps" in out and "--uncertainty.off" in out
    flat = " ".join(out.replace("│", " ").split())  # the help box wraps and frames each option's text
    for name, method in METHODS.items():  # the registry documents --method: a new entry needs no other edit
        assert f"{name}: {method.description}" in flat


def test_help_shows_the_presets_values_also_for_the_flags_typed_beside_it(capsys):
    """A run leaves the preset's values of typed flags out, for the flags to replace; --help must not, or it showed
    the full recipe's 30000 steps and 200000 Gaussians as the fast preset's defaults."""
    with pytest.raises(SystemExit):
        entrypoint(["train", "--preset", "fast", "--steps", "7", "--densify.max-gaussians", "5", "--help"])
    flat = " ".join(capsys.readouterr().out.replace("│", " ").split())
    assert re.search(r"--steps INT [^│]*?\(default: (\d+)\)", flat).group(1) == "2000"
    assert re.search(r"--densify.max-gaussians INT [^│]*?\(default: (\d+)\)", flat).group(1) == "20000"


def test_help_beside_steps_shows_the_schedule_the_run_trains_with(capsys):
    """`--steps 4000 --help` showed fast's 2000-step schedule as the defaults, not the one the run rescales it to.
    Each default is the value without that flag: --steps keeps the preset's length, and a schedule flag typed beside
    it shows the rescaled value it replaces; beside --resume, which keeps the run's saved schedule, the preset's."""
    def shown(*flags: str) -> list[str]:
        with pytest.raises(SystemExit):
            entrypoint(["train", *flags, "--help"])
        flat = " ".join(capsys.readouterr().out.replace("│", " ").split())
        return [re.search(re.escape(flag) + r" INT [^│]*?\(default: (\d+)\)", flat).group(1)
                for flag in ("--steps", "--resolution-interval", "--densify.refine-every", "--densify.stop-split-at")]

    assert shown("--steps", "4000", "--densify.refine-every", "5") == ["2000", "400", "13", "2000"]
    assert shown("--preset", "quality", "--steps=4000") == ["3000", "400", "13", "2000"]
    assert shown("--resume", "RUN", "--steps", "4000") == ["2000", "200", "7", "1000"]


def test_views_help_describes_the_orbit_of_every_shape(capsys):
    """--views' help called the orbit a circle, which --orbit-shape auto replaces with an arc for a capture taken from
    one side (lund_door, fox): the help must name both, and the option that chooses."""
    with pytest.raises(SystemExit):
        entrypoint(["render-uncertainty", "--help"])
    flat = " ".join(capsys.readouterr().out.replace("│", " ").split())
    views = re.search(r"--views \{eval,train,orbit,cameras\} (.*?)\(default: eval, or cameras with --cameras\)",
                      flat).group(1)
    assert "circle" in views and "arc" in views and "--orbit-shape" in views


def test_help_beside_a_flag_that_replaces_a_bad_preset_value_prints(capsys, tmp_path):
    """The run takes the flag in place of the file's bad value (test_a_flag_replaces_a_bad_value_of_the_preset_file),
    but --help beside it refused the value, with the fix of overriding it by the flag that was typed."""
    preset = tmp_path / "p.yaml"
    preset.write_text("steps: 0\nresolution_interval: 100\n")
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train", "--preset", str(preset), "--steps", "30", "--help"])
    assert exc.value.code == 0
    flat = " ".join(capsys.readouterr().out.replace("│", " ").split())
    assert re.search(r"--resolution-interval INT [^│]*?\(default: (\d+)\)", flat).group(1) == "100"


@pytest.mark.parametrize("steps", ["0", "-3"])
def test_help_beside_a_steps_below_one_prints(capsys, steps):
    """A run refuses it (one line, from its option checks); --help beside it must still print the help, not that
    error: the schedule shown for a typed --steps is rescaled only for a length a run can take."""
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train", "--steps", steps, "--help"])
    assert exc.value.code == 0
    assert "--resolution-interval" in capsys.readouterr().out


@pytest.mark.parametrize("spelling", ["render_uncertainty", "eval_ause", "process_images"])
def test_a_subcommand_spelt_with_underscores_is_still_that_subcommand(capsys, spelling):
    """tyro reads render_uncertainty as render-uncertainty; the check for mistyped subcommands refused it."""
    with pytest.raises(SystemExit) as exc:
        entrypoint([spelling, "--help"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: splatu {spelling.replace('_', '-')} ")


def test_a_box_usage_error_does_not_know_is_left_to_tyro():
    from splatu.usage_errors import usage_error

    assert usage_error("usage: splatu [-h]\nsplatu: error: something new\n", "splatu", ["train"]) is None


@pytest.mark.parametrize("command", ["train", "render-uncertainty", "eval-ause", "process-images"])
def test_option_help_wraps_only_where_the_terminal_is_full(command):
    """tyro 1.0 kept every line break of an indented option docstring, so --help cut sentences short at any
    width. Each help line now ends only where the next word would not fit."""
    out = subprocess.run([sys.executable, "-m", "splatu", command, "--help"], capture_output=True, text=True,
                         timeout=120, env={**os.environ, "COLUMNS": "100", "PYTHONIOENCODING": "utf-8"})
    rows = [line[2:-2] for line in out.stdout.splitlines() if line.startswith("│ ")]
    help_rows = [(row, row.startswith("      ") and row.strip() != "") for row in rows]
    assert sum(is_help for _, is_help in help_rows) > 5
    short = [(a.strip(), b.strip()) for (a, a_help), (b, b_help) in itertools.pairwise(help_rows)
             if a_help and b_help and len(a.rstrip()) + 1 + len(b.split()[0]) <= len(a)]
    assert not short, short


def test_an_ascii_only_console_gets_help_and_one_line_errors_not_a_crash():
    """Help texts hold λ, σ and ≈; printing them to an ASCII-only stream raised UnicodeEncodeError."""
    env = {**os.environ, "PYTHONIOENCODING": "ascii"}
    shown = subprocess.run([sys.executable, "-m", "splatu", "train", "--help"], capture_output=True, timeout=120,
                           env=env)
    assert shown.returncode == 0 and b"--uncertainty.lam" in shown.stdout and b"Traceback" not in shown.stderr
    refused = subprocess.run([sys.executable, "-m", "splatu", "train", "--stepz", "3"], capture_output=True,
                             timeout=120, env=env)  # tyro draws an ASCII box here: it is read back too
    assert refused.returncode == 2
    assert refused.stderr.decode("ascii").splitlines() == [
        "error: unrecognized options: --stepz, 3, on the command line, did you mean --steps? "
        "(see `splatu train --help`)"]


def _into_a_closed_pipe(*args: str, program: tuple[str, ...] = ("-m", "splatu")) -> tuple[int, str]:
    """Exit status and stderr of `splatu ARGS` (or of `python PROGRAM ARGS`) whose reader left before it wrote
    anything; stdout block-buffered, as it is for a user (PYTHONUNBUFFERED would write every print at once)."""
    env = {name: value for name, value in os.environ.items() if name != "PYTHONUNBUFFERED"}
    child = subprocess.Popen([sys.executable, *program, *args], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=env)
    child.stdout.close()  # before the child has imported torch, let alone written anything
    err = child.stderr.read()
    return child.wait(timeout=120), err


@pytest.mark.parametrize("args", [("train", "--help"), ("eval-ause", "--help"), ("--version",)])
def test_output_into_a_closed_pipe_is_no_traceback(args):
    """`splatu train --help | head -1`: the reader leaves before the output is written, which was a BrokenPipeError
    traceback, or, for an output that fits stdout's buffer (eval-ause's help, the version), Python's "Exception
    ignored" at exit with status 120; the command now just ends."""
    status, err = _into_a_closed_pipe(*args)
    assert status == 1
    assert err == ""


PRINTS_THEN_FAILS = """
import sys
from splatu import cli
from splatu.errors import SplatuError

def prints_then_fails(args, debug):
    print("a first result")
    if args[0] == "stop":  # as `splatu train` ends a stopped training: its line, then its status
        print("stopped; resume it", file=sys.stderr)
        raise SystemExit(130)
    raise {"user error": SplatuError("thing broke", "in /some/file", "do the fix"),
            "ctrl-c": KeyboardInterrupt()}[args[0]]

cli.main = prints_then_fails
cli.entrypoint(sys.argv[1:])
"""
"""A command that prints to stdout, then fails: no command does so yet (each prints its result last), so a
stand-in one, run through the real entry point."""


@pytest.mark.parametrize(("failure", "status", "line"), [
    ("user error", 2, "error: thing broke, in /some/file, do the fix"), ("ctrl-c", 130, "interrupted"),
    ("stop", 130, "stopped; resume it")])
def test_a_command_that_printed_then_failed_into_a_closed_pipe_still_says_why(failure, status, line):
    """Its output still in stdout's buffer, the command's error was printed and then the exit's own flush failed:
    Python's "Exception ignored ... BrokenPipeError" after the line, and status 120 instead of the error's."""
    assert _into_a_closed_pipe(failure, program=("-c", PRINTS_THEN_FAILS)) == (status, line + "\n")


def test_a_closed_pipe_with_debug_shows_its_traceback():
    status, err = _into_a_closed_pipe("--debug", "--version")
    assert status != 0
    assert "BrokenPipeError" in err


def test_a_refused_command_leaves_no_empty_output_folders(tmp_path, capsys):
    """The output folders were made (empty) to prove them writable before the scene or run was read, so a mistyped
    path left `outputs/` or an `--output` folder behind; they are now proven writable without being made."""
    for args in (["train", "--data", str(tmp_path / "no_scene"), "--output-dir", str(tmp_path / "runs")],
                 ["eval-ause", "--load", str(tmp_path / "no_run"), "--output", str(tmp_path / "scores" / "a.json")],
                 ["render-uncertainty", "--load", str(tmp_path / "no_run"), "--output", str(tmp_path / "maps")]):
        with pytest.raises(SystemExit) as exc:
            entrypoint(args)
        assert exc.value.code == 2, args
        assert capsys.readouterr().err.startswith("error: ")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_an_output_folder_under_a_file_is_one_line(tmp_path, capsys):
    (tmp_path / "taken").write_text("a file")
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train", "--data", "poster", "--output-dir", str(tmp_path / "taken" / "runs")])
    assert exc.value.code == 2
    line = capsys.readouterr().err.strip()
    assert "cannot write the output folder" in line and "is a file" in line and "--output-dir" in line


def test_an_output_folder_through_a_broken_link_is_one_line(tmp_path, capsys):
    """A dangling link passed the writability probe (made in its parent) and the later mkdir raised FileExistsError."""
    (tmp_path / "gone").symlink_to(tmp_path / "nowhere")
    with pytest.raises(SystemExit) as exc:
        entrypoint(["train", "--data", "poster", "--output-dir", str(tmp_path / "gone" / "runs")])
    assert exc.value.code == 2
    line = capsys.readouterr().err.strip()
    assert "is a broken link" in line and "--output-dir" in line


def _killed(*args: object) -> None:
    """A stand-in for a stage of a command, where a SIGTERM (`kill`, a scheduler's time limit) lands."""
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(10)  # the handler raises within this
    raise AssertionError("SIGTERM did not stop the command")


@pytest.mark.parametrize("command", ["render-uncertainty", "eval-ause", "export"])
def test_a_sigterm_before_the_write_says_what_it_left(monkeypatch, tmp_path, capsys, command):
    """Only the write itself took SIGTERM as Ctrl-C: one during the scene's setup, the render or the checkpoint's
    load ended the process at once, without the `interrupted: ...` line the docs promise."""
    from types import SimpleNamespace

    from splatu import export, render_uncertainty

    def not_default(signum: int, frame: object) -> None:  # where SIGTERM's default would end pytest itself
        raise AssertionError("SIGTERM reached the handler from before the command")

    before = signal.signal(signal.SIGTERM, not_default)
    try:
        monkeypatch.setattr(render_uncertainty, "pinned_load", lambda load, written: load)
        monkeypatch.setattr(render_uncertainty, "_load", lambda load, options: (
            SimpleNamespace(member_steps=None), options.for_run(False)))
        monkeypatch.setattr(render_uncertainty, "_setup", _killed)
        monkeypatch.setattr(render_uncertainty, "render_eval_maps", _killed)
        monkeypatch.setattr(export, "resolve_checkpoint", lambda load: tmp_path / "step-0000001.pt")
        monkeypatch.setattr(export, "load_run", _killed)
        out = tmp_path / "out"
        output = {"render-uncertainty": out, "eval-ause": out / "ause.json", "export": out / "splat.ply"}[command]
        with pytest.raises(SystemExit) as stop:
            entrypoint([command, "--load", str(tmp_path), "--output", str(output)])
        assert signal.getsignal(signal.SIGTERM) is not_default
    finally:
        signal.signal(signal.SIGTERM, before)
    assert stop.value.code == 128 + signal.SIGTERM
    left = {"render-uncertainty": f"no render written to {out}",
            "eval-ause": "no scores written, so any earlier report is unchanged",
            "export": f"no export written to {output}"}[command]
    assert capsys.readouterr().err.endswith(f"interrupted: {left}\n")
