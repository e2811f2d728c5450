"""A run as an older splatu saved it: with option values it allowed then and refuses for new runs now."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
import yaml

from splatu.checkpoint import list_checkpoints, read_checkpoint
from splatu.config_values import read_yaml


def saved_with(run_dir: Path, **changes: dict[str, Any]) -> None:
    """Rewrite `run_dir`'s config.yml and its checkpoints' configs with `changes` (part -> {option: value})."""

    def changed(values: dict[str, Any]) -> dict[str, Any]:
        return {**values, **{part: {**values[part], **options} for part, options in changes.items()}}

    (run_dir / "config.yml").write_text(yaml.safe_dump(changed(read_yaml(run_dir / "config.yml")), sort_keys=False))
    for path in list_checkpoints(run_dir):
        state = read_checkpoint(path)
        torch.save({**state, "config": changed(state["config"])}, path)


OLDER_VALUES: dict[str, dict[str, Any]] = {"uncertainty": {"threshold": 0.0, "num_dirs": 32},
                                           "model": {"u_init_logit": 45.0}}
"""Threshold 0, refused for new runs since 19c6c8f, a u_init_logit beyond ±30, since 36d6409, and a num_dirs the
antipodal loss never read, since cb1418d."""
