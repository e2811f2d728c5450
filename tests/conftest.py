"""Shared fixtures: the real data in ../shared/data, skipped with a reason when absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("SPLATU_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_scene(name: str) -> Path:
    """Path to ../shared/data/<name>, or skip the test saying why."""
    path = SHARED_DATA / name
    if not path.is_dir():
        pytest.skip(f"real data {name!r} not found at {path} (../shared/data is absent on this machine)")
    return path


@pytest.fixture(scope="module")
def fast():
    """The rasterizer under test, as a module (the exactness and hard-case tests call fast.rasterize)."""
    import splatu.rasterizer

    return splatu.rasterizer


@pytest.fixture(autouse=True)
def _seeded_torch():
    """Every test starts from the same global torch RNG state, whatever ran before it."""
    torch.manual_seed(0)
    yield
