"""The subcommand registry: one entry per `splatu` subcommand.

A subcommand whose issue has not landed is registered as `_unbuilt`: it parses its
options but exits with one clear line instead of pretending to work.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from splatu.cli import Command
from splatu.errors import SplatuError


def _unbuilt(name: str) -> Any:
    def run(config: Any) -> None:
        raise SplatuError(f"`splatu {name}` is not built yet", "in this version of splatu", "see the open issues")

    return run


@dataclass
class _TrainStub:
    data: str = "poster"
    """Scene: `poster` (built-in stand-in) or a path to a nerfstudio/COLMAP/blender scene."""


@dataclass
class _LoadStub:
    load: Path = Path("outputs/poster/splatu/latest")
    """A training run directory."""


@dataclass
class _RenderStub(_LoadStub):
    pass


COMMANDS: dict[str, Command] = {
    "train": Command("Train a 3DGS model with view-dependent uncertainty.", lambda argv: _TrainStub(),
                     _unbuilt("train")),
    "render-uncertainty": Command("Render RGB, depth and uncertainty maps of a trained run.",
                                  lambda argv: _RenderStub(), _unbuilt("render-uncertainty")),
    "eval-ause": Command("Score uncertainty maps with sparsification curves and AUSE.",
                         lambda argv: _LoadStub(), _unbuilt("eval-ause")),
}
