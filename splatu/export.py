"""`splatu export`: any checkpoint of a run as the standard 3DGS PLY that training writes at its end, so a run
stopped early, or an earlier step of a finished one, can be opened in a viewer too."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rich.console import Console

from splatu.atomic import file_identity, what_a_stop_left
from splatu.checkpoint import load_run, resolve_checkpoint, run_folder
from splatu.errors import SplatuError, creatable_dir
from splatu.interrupts import saying_what_is_left
from splatu.ply import save_ply
from splatu.run_dir import DEMO_RUN


@dataclass
class ExportConfig:
    """Options of `splatu export`."""

    load: Path = DEMO_RUN
    """A training run directory (its newest checkpoint is exported) or one of its checkpoint files."""
    output: Path | None = None
    """The .ply to write; default: <run>/exports/splat-<checkpoint's name>.ply, e.g. splat-step-0001000.ply (a finished
    run's own splat.ply is the export of its last step)."""


def export_path(load: Path, checkpoint: Path, output: Path | None) -> Path:
    """Where the PLY goes, refused in one line before anything is read if it cannot be written there."""
    path = output or run_folder(load) / "exports" / f"splat-{checkpoint.stem}.ply"
    if path.suffix.lower() != ".ply" or path.is_dir():  # X.PLY too, as viewers and file pickers take it
        example = path / f"splat-{checkpoint.stem}.ply" if path.is_dir() else path.with_suffix(".ply")  # a file in it
        raise SplatuError("--output must name a .ply file", f"in {path}", f"pass a path such as {example}")
    creatable_dir(path.parent, "--output (a .ply path in a writable folder)")
    return path


def run(config: ExportConfig) -> None:
    checkpoint = resolve_checkpoint(config.load)
    output = export_path(config.load, checkpoint, config.output)
    earlier = file_identity(output)
    with saying_what_is_left(lambda: what_a_stop_left(output, earlier, "export", output)):
        trained = load_run(checkpoint)
        if trained.frame is None:
            raise SplatuError("this checkpoint predates the record of the scene's normalisation, so its Gaussians "
                              "cannot be put back in the data's coordinates", f"in {checkpoint}",
                              "retrain the run to export it")
        save_ply(trained.model, output, trained.frame, uncertainty=not trained.config.uncertainty.off)
    Console().print(f"wrote {output} ({len(trained.model):,} Gaussians, from {checkpoint.name})", soft_wrap=True)
