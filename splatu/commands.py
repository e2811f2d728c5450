"""The subcommand registry: one entry per `splatu` subcommand."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from splatu.cli import Command
from splatu.data.process_images import ProcessImagesConfig
from splatu.data.process_images import run as run_process_images
from splatu.errors import SplatuError
from splatu.eval_ause import EvalAuseConfig
from splatu.eval_ause import run as run_eval_ause
from splatu.export import ExportConfig
from splatu.export import run as run_export
from splatu.render_uncertainty import RenderUncertaintyConfig
from splatu.render_uncertainty import run as run_render_uncertainty
from splatu.train_command import run_command as run_train
from splatu.train_config import default_config as train_default_config


def _config_only(run: Callable[[Any], None]) -> Callable[[Any, Sequence[str]], None]:
    """A command that needs only its parsed config."""
    return lambda config, argv: run(config)


def _loading(run: Callable[[Any], None]) -> Callable[[Any, Sequence[str]], None]:
    """A command whose --load defaults to the demo's run: run without --load where there is no such run (another
    folder), its error named a path the user never typed, so it says that path was --load's default."""
    def checked(config: Any, argv: Sequence[str]) -> None:
        typed = any(arg == "--load" or arg.startswith("--load=") for arg in argv)
        if not typed and not config.load.exists():
            raise SplatuError(f"no --load given, and no run at its default {config.load}", f"in {Path.cwd()}",
                              "pass --load RUN, a run folder (outputs/<scene>/<method>/latest) or a checkpoint")
        run(config)

    return checked


COMMANDS: dict[str, Command] = {
    "train": Command("Train a 3DGS model with view-dependent uncertainty.", train_default_config, run_train),
    "render-uncertainty": Command("Render RGB, depth and uncertainty maps of a trained run.",
                                  lambda argv: RenderUncertaintyConfig(), _loading(run_render_uncertainty)),
    "eval-ause": Command("Score uncertainty maps with sparsification curves and AUSE.",
                         lambda argv: EvalAuseConfig(), _config_only(run_eval_ause)),
    "export": Command("Write a run's model, or any checkpoint of it, as a standard 3DGS PLY.",
                      lambda argv: ExportConfig(), _loading(run_export)),
    "process-images": Command("Run structure from motion (pycolmap, CPU) on a folder of photos.",
                              lambda argv: ProcessImagesConfig(images=Path("images")),
                              _config_only(run_process_images)),
}
