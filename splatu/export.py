"""`splatu export`: any checkpoint of a run as the standard 3DGS PLY that training writes at its end, so a run
stopped early, or an earlier step of a finished one, can be opened in a viewer too."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rich.console import Console

from splatu.atomic import file_identity
from splatu.checkpoint import load_run, resolve_checkpoint, run_folder
from splatu.errors import SplatuError, creatable_dir
from splatu.interrupts import saying_what_is_left
from splatu.ply import save_ply


@dataclass
class ExportConfig:
    """Options of `splatu export`."""

    load: Path = Path("outputs/poster/splatu/latest")
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


def left_by_a_stop(output: Path, earlier: tuple[int, int] | None) -> str:
    """What a Ctrl-C left at `output`, which was `earlier` (`file_identity`): the PLY is written beside it and renamed
    over it whole (`atomic_write`), so it is the earlier file (or none) or the whole new one."""
    if file_identity(output) != earlier:
        return f"the export was already written in full to {output}"
    if earlier is None:
        return f"no export written to {output}"
    return f"no export written; the earlier {output} is unchanged"


def run(config: ExportConfig) -> None:
    checkpoint = resolve_checkpoint(config.load)
    output = export_path(config.load, checkpoint, config.output)
    earlier = file_identity(output)
    with saying_what_is_left(lambda: left_by_a_stop(output, earlier)):
        trained = load_run(checkpoint)
        if trained.frame is None:
            raise SplatuError("this checkpoint predates the record of the scene's normalisation, so its Gaussians "
                              "cannot be put back in the data's coordinates", f"in {checkpoint}",
                              "retrain the run to export it")
        save_ply(trained.model, output, trained.frame, uncertainty=not trained.config.uncertainty.off)
    Console().print(f"wrote {output} ({len(trained.model):,} Gaussians, from {checkpoint.name})", soft_wrap=True)
