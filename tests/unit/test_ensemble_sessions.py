"""An ensemble's folder lock."""

import dataclasses
import json
from pathlib import Path

import pytest

from splatu import ensemble_training, train_command
from splatu import run_dir as run_dir_module
from splatu.checkpoint import list_checkpoints
from splatu.errors import SplatuError
from splatu.methods import get_method
from splatu.train_config import TrainConfig
from tests.unit.test_trainer import tiny_config, tiny_scene


@pytest.fixture
def scene(monkeypatch):
    scene = tiny_scene()
    monkeypatch.setattr(train_command, "load_scene", lambda data_config: scene)
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

