"""The subcommand registry: one entry per `splatu` subcommand.

Each command's module is imported only when that command is chosen: `splatu --help` lists them all without
importing torch, matplotlib or pycolmap, and `splatu export --help` does not import train's modules.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from splatu.cli import Command
from splatu.errors import SplatuError
from splatu.run_dir import DEMO_RUN


def _lazy(module: str, name: str) -> Callable[..., Any]:
    """`module.name`, called with the arguments given, its module imported at the first call."""
    def call(*args: Any, **kwargs: Any) -> Any:
        return getattr(importlib.import_module(module), name)(*args, **kwargs)

    return call


def _config_only(run: Callable[[Any], None]) -> Callable[[Any, Sequence[str]], None]:
    """A command that needs only its parsed config."""
    return lambda config, argv: run(config)


def _loading(run: Callable[[Any], None], alternative: str = "") -> Callable[[Any, Sequence[str]], None]:
    """A command whose --load defaults to the demo's run: run without --load where there is no such run (another
    folder), its error named a path the user never typed, so it says that path was --load's default."""
    def checked(config: Any, argv: Sequence[str]) -> None:
        typed = any(arg == "--load" or arg.startswith("--load=") for arg in argv)
        if not typed and config.load is not None and not config.load.exists():
            raise SplatuError(f"no --load given, and no run at its default {config.load}", f"in {Path.cwd()}",
                              "pass --load RUN, a run folder (outputs/<scene>/<method>/latest) or a checkpoint"
                              + alternative)
        run(config)

    return checked


def _loading_unless_maps(run: Callable[[Any], None]) -> Callable[[Any, Sequence[str]], None]:
    """eval-ause: --load defaults to the demo's run as the other commands' does, unless --maps names maps to score
    instead (its config leaves --load None, so that --maps and a typed --load are told apart)."""
    loading = _loading(run, ", or --maps DIR to score maps written elsewhere")

    def checked(config: Any, argv: Sequence[str]) -> None:
        if config.load is None and config.maps is None:
            config = dataclasses.replace(config, load=DEMO_RUN)
        loading(config, argv)

    return checked


COMMANDS: dict[str, Command] = {
    "train": Command("Train a 3DGS model with view-dependent uncertainty.",
                     _lazy("splatu.train_config", "default_config"), _lazy("splatu.train_command", "run_command")),
    "render-uncertainty": Command("Render RGB, depth and uncertainty maps of a trained run.",
                                  lambda argv: _lazy("splatu.render_uncertainty", "RenderUncertaintyConfig")(),
                                  _loading(_lazy("splatu.render_uncertainty", "run"))),
    "eval-ause": Command("Score uncertainty maps with sparsification curves and AUSE.",
                         lambda argv: _lazy("splatu.eval_ause", "EvalAuseConfig")(),
                         _loading_unless_maps(_lazy("splatu.eval_ause", "run"))),
    "export": Command("Write a run's model, or any checkpoint of it, as a standard 3DGS PLY.",
                      lambda argv: _lazy("splatu.export", "ExportConfig")(), _loading(_lazy("splatu.export", "run"))),
    "process-images": Command("Run structure from motion (pycolmap, CPU) on a folder of photos.",
                              lambda argv: _lazy("splatu.data.process_images", "ProcessImagesConfig")(
                                  images=Path("images")),
                              _config_only(_lazy("splatu.data.process_images", "run"))),
}
