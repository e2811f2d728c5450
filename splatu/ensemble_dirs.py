"""Where an ensemble run keeps its members, and whether a folder is one of them.

Apart from splatu.ensemble_training, which imports the trainer, so that the trainer can tell a member's folder too.
"""

from __future__ import annotations

from pathlib import Path

from splatu.train_config import TrainConfig, load_config


def ensemble_members(run_dir: Path, config: TrainConfig) -> list[Path]:
    """Each member's run folder inside an ensemble run."""
    return [run_dir / "members" / str(k) for k in range(config.ensemble)]


def ensemble_config(run_dir: Path) -> TrainConfig | None:
    """The saved config when `run_dir` is an ensemble run directory, else None."""
    path = Path(run_dir).expanduser() / "config.yml"
    if not path.is_file():
        return None
    config = load_config(path)
    return config if config.ensemble > 1 else None


def enclosing_ensemble(run_dir: Path) -> Path | None:
    """The ensemble run whose member `run_dir` is (ENSEMBLE/members/k, k below its member count), else None."""
    ensemble = run_dir.parent.parent
    config = ensemble_config(ensemble) if run_dir.parent.name == "members" else None
    return ensemble if config is not None and run_dir in ensemble_members(ensemble, config) else None
