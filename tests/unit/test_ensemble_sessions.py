"""An ensemble's folder lock and its record of every session that trained a member (ensemble_sessions.json)."""

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from splatu import ensemble_dirs, ensemble_training, train_command, trainer
from splatu import run_dir as run_dir_module
from splatu.checkpoint import RESUME_KEYS, list_checkpoints, read_checkpoint
from splatu.errors import SplatuError
from splatu.interrupts import TrainingInterrupted
from splatu.methods import get_method
from splatu.train_config import TrainConfig, from_dict, save_config
from tests.unit.test_trainer import serve_scene, tiny_config, tiny_scene


@pytest.fixture
def scene(monkeypatch):
    scene = tiny_scene()
    serve_scene(monkeypatch, lambda data_config: scene)
    return scene


def ensemble_of_2(root: Path, **changes) -> TrainConfig:
    return get_method("ensemble").configure(tiny_config(root, steps=4, checkpoint_every=2, ensemble=2,
                                                        method="ensemble", **changes))


def test_train_ensemble_called_from_python_holds_the_ensembles_lock(tmp_path, scene, monkeypatch):
    """`train_ensemble` locked each member but not the ensemble folder: a second Python session starting between two
    members of the first trained the next member itself, and each then wrote ensemble_sessions.json from what it had
    read at its start, so one session's wall time was lost (and config.yml was the last caller's). Now the second
    session is refused at the ensemble folder, having written nothing."""
    run_dir = tmp_path / "ensemble"
    config = ensemble_of_2(tmp_path)
    second: list[pytest.ExceptionInfo[SplatuError]] = []

    class SecondSessionBetweenMembers:
        def print(self, text: str, **options: object) -> None:
            if text.startswith("ensemble member 2/2") and not second:  # the first session's member 0 is done
                config_yml = (run_dir / "config.yml").read_bytes()
                with pytest.raises(SplatuError) as caught:
                    second.append(caught)
                    ensemble_training.train_ensemble(dataclasses.replace(config, seed=7), scene, run_dir, 0.0)
                assert (run_dir / "config.yml").read_bytes() == config_yml
                assert not list_checkpoints(run_dir / "members" / "1")

    monkeypatch.setattr(ensemble_training, "console", SecondSessionBetweenMembers())
    seen: list[bool] = []
    ensemble_training.train_ensemble(config, scene, run_dir, 0.0,
                                     hooks=[lambda step, state: seen.append(run_dir_module.still_training(run_dir))])
    assert second[0].value.what == "another `splatu train` is training this run now"
    assert second[0].value.where == f"in {run_dir}"
    assert seen and all(seen) and not run_dir_module.still_training(run_dir)
    record = json.loads((run_dir / "ensemble.json").read_text())
    assert record["seeds"] == [0, 1] and len(record["session_seconds"]) == 1


def sessions_in_record(run_dir: Path) -> list[float]:
    record = json.loads((run_dir / "ensemble.json").read_text())
    assert record["wall_seconds"] == pytest.approx(sum(record["session_seconds"]))
    return record["session_seconds"]


def ctrl_c(step: int, state: object) -> None:
    raise KeyboardInterrupt


def test_a_members_own_resume_counts_in_the_ensembles_wall_time(tmp_path, scene):
    """A member retrained by `splatu train --resume ENSEMBLE/members/k/...` was missing from ensemble_sessions.json,
    so ensemble.json's wall_seconds (the ensemble's training time in render and eval-ause timings) left it out: both
    when the ensemble had finished once (ensemble.json was never rewritten) and when a later `--resume ENSEMBLE`
    wrote it. A session stopped by Ctrl-C counts too, as an ensemble's own does."""
    run_dir = train_command.train(ensemble_of_2(tmp_path))
    sessions = sessions_in_record(run_dir)
    member = run_dir / "members" / "1"
    resume_member = dataclasses.replace(tiny_config(tmp_path), resume=list_checkpoints(member)[0])
    with pytest.raises(TrainingInterrupted):
        train_command.train(resume_member, hooks=[ctrl_c])
    assert sessions_in_record(run_dir)[:1] == sessions and len(sessions := sessions_in_record(run_dir)) == 2
    train_command.train(dataclasses.replace(tiny_config(tmp_path), resume=member))  # finishes it
    assert sessions_in_record(run_dir)[:2] == sessions and len(sessions := sessions_in_record(run_dir)) == 3

    (run_dir / "ensemble.json").unlink()  # as before an unfinished ensemble's first whole resume
    train_command.train(dataclasses.replace(resume_member, resume=list_checkpoints(member)[0]))  # an earlier one
    assert not (run_dir / "ensemble.json").exists()  # its resume writes it, once every member is trained
    train_command.train(dataclasses.replace(tiny_config(tmp_path), resume=run_dir))
    assert sessions_in_record(run_dir)[:3] == sessions and len(sessions_in_record(run_dir)) == 4


def test_a_members_own_resume_is_refused_while_the_ensemble_trains(tmp_path, scene):
    """The member's session is the ensemble's too: it holds the ensemble's lock, so it cannot record its time beside a
    training of the ensemble that rewrites the same files."""
    run_dir = train_command.train(ensemble_of_2(tmp_path))
    before = (run_dir / "ensemble_sessions.json").read_bytes()
    with run_dir_module.training_lock(run_dir), pytest.raises(SplatuError) as caught:
        train_command.train(dataclasses.replace(tiny_config(tmp_path), resume=run_dir / "members" / "1"))
    assert caught.value.where == f"in {run_dir}"
    assert (run_dir / "ensemble_sessions.json").read_bytes() == before


def test_only_a_member_folder_of_an_ensemble_counts_as_one(tmp_path):
    """members/k is an ensemble's member only beside an ensemble's config.yml and for k below its member count."""
    single, ensemble = tmp_path / "single", tmp_path / "ensemble"
    save_config(tiny_config(tmp_path), single / "config.yml")
    save_config(ensemble_of_2(tmp_path), ensemble / "config.yml")
    assert ensemble_dirs.enclosing_ensemble(ensemble / "members" / "1") == ensemble
    assert ensemble_dirs.enclosing_ensemble(ensemble / "members" / "2") is None
    assert ensemble_dirs.enclosing_ensemble(single / "members" / "0") is None
    assert ensemble_dirs.enclosing_ensemble(tmp_path / "elsewhere") is None


def test_train_run_refuses_an_ensembles_member_folder_in_one_line(tmp_path, scene):
    """`train_run` on ENSEMBLE/members/k from Python trained the member without the ensemble's lock and left its
    session out of ensemble_sessions.json, which `splatu train --resume MEMBER` counts. It is refused now, before
    it writes anything, and the message names the command that counts it."""
    run_dir = train_command.train(ensemble_of_2(tmp_path))
    member = run_dir / "members" / "1"
    first = list_checkpoints(member)[0]
    checkpoint = read_checkpoint(first, RESUME_KEYS)
    before = {path: path.read_bytes() for path in [*run_dir.glob("*.json"), *member.rglob("*")] if path.is_file()}
    with pytest.raises(SplatuError) as caught:
        trainer.train_run(from_dict(checkpoint["config"], str(first)), scene, member, checkpoint=checkpoint)
    assert caught.value.where == f"in {member}"
    assert f"splatu train --resume {member}" in caught.value.fix and "\n" not in str(caught.value)
    assert {path: path.read_bytes() for path in before} == before
    assert sorted(p for p in [*run_dir.glob("*.json"), *member.rglob("*")] if p.is_file()) == sorted(before)
    trainer.train_run(tiny_config(tmp_path), scene, tmp_path / "single")  # a folder of no ensemble still trains


def test_a_members_resume_refused_before_it_trains_adds_no_session(tmp_path, scene, monkeypatch):
    """A member's `--resume` that ended before training (its checkpoint did not fit the scene, a SplatuError raised
    once the ensemble's lock was held) still added its seconds to ensemble_sessions.json; so did a Python
    `train_ensemble` refused at an unfinished member the same way. Only a session that trained counts; one that
    found the member finished, or its lock held, never did and still does not."""
    run_dir = train_command.train(ensemble_of_2(tmp_path))
    sessions = sessions_in_record(run_dir)
    member = run_dir / "members" / "1"
    train_command.train(dataclasses.replace(tiny_config(tmp_path), resume=member))  # already finished
    with run_dir_module.training_lock(member), pytest.raises(SplatuError):
        train_command.train(dataclasses.replace(tiny_config(tmp_path), resume=member))  # its lock is held
    assert sessions_in_record(run_dir) == sessions
    moved = dataclasses.replace(scene, center=torch.tensor([0.0, 0.0, 1.0]))  # normalised unlike the trained one
    serve_scene(monkeypatch, lambda data_config: moved)
    with pytest.raises(SplatuError, match="normalis"):
        train_command.train(dataclasses.replace(tiny_config(tmp_path), resume=list_checkpoints(member)[0]))
    assert sessions_in_record(run_dir) == sessions
    assert json.loads((run_dir / "ensemble_sessions.json").read_text())["session_seconds"] == sessions

    (member / "summary.json").unlink()  # member 1 unfinished again, its newest checkpoint the scene's misfit
    with pytest.raises(SplatuError, match="normalis"):
        ensemble_training.train_ensemble(ensemble_of_2(tmp_path), moved, run_dir, 0.0)
    assert json.loads((run_dir / "ensemble_sessions.json").read_text())["session_seconds"] == sessions
