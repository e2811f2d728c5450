"""A command that a message tells the user to run is copied into a shell as it is printed: a run folder whose path
holds a space (a "My Drive" folder, a capture named "front door") must come out quoted, as one argument."""

from __future__ import annotations

import json
import shlex
import signal

import pytest

from splatu import trainer
from splatu.baselines.load import load_any_run
from splatu.errors import SplatuError
from splatu.interrupts import TrainingInterrupted
from splatu.train_config import save_config
from tests.unit.test_ensemble_sessions import ensemble_of_2, scene  # noqa: F401  (a fixture)
from tests.unit.test_trainer import tiny_config


def resume_target(text: str) -> str:
    """The run folder that the `splatu train --resume …` quoted in `text` would resume, as a shell splits it."""
    command = shlex.split(text.split("`splatu train --resume ", 1)[1].split("`", 1)[0])
    assert len(command) == 1, f"the suggested command splits into {command}"
    return command[0]


def test_the_resume_command_of_a_stopped_run_quotes_a_path_with_spaces(tmp_path):
    run_dir = tmp_path / "front door" / "splatu" / "run 1"
    stop = TrainingInterrupted("interrupted at step 3", run_dir, 3, signal.SIGINT)
    assert resume_target(stop.message) == str(run_dir)


def test_the_resume_commands_of_an_unfinished_ensemble_quote_a_path_with_spaces(tmp_path):
    unfinished = tmp_path / "my runs" / "unfinished"
    (unfinished / "members" / "0").mkdir(parents=True)
    with pytest.raises(SplatuError) as caught:
        load_any_run(unfinished)
    assert resume_target(caught.value.fix) == str(unfinished)

    missing = tmp_path / "my runs" / "missing member"
    missing.mkdir()
    (missing / "ensemble.json").write_text(json.dumps({"members": ["members/0", "members/1"]}))
    with pytest.raises(SplatuError) as caught:
        load_any_run(missing)
    assert resume_target(caught.value.fix) == str(missing)


def test_train_runs_refusal_of_a_member_folder_quotes_a_path_with_spaces(tmp_path, scene):  # noqa: F811
    ensemble = tmp_path / "my ensemble"
    save_config(ensemble_of_2(tmp_path), ensemble / "config.yml")
    member = ensemble / "members" / "1"
    with pytest.raises(SplatuError) as caught:
        trainer.train_run(tiny_config(tmp_path), scene, member)
    assert resume_target(caught.value.fix) == str(member)
