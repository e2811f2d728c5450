"""The ensemble baseline: per-pixel std of RGB across members that differ only in seed (REFERENCE §5).

The std is the population std over members (ddof 0), averaged over the RGB channels, of the colours each
member shows: clipped to [0, 1], as every image eval-ause scores is, so disagreement past white (which no scored
error can see) is not counted as uncertainty. The render is the mean of those clipped colours. The
density-aware variant adds (1 − mean accumulated alpha)², so empty space, where members agree
on "nothing", still reads as uncertain.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from splatu.baselines import UncertaintyRender
from splatu.camera import Camera
from splatu.errors import SplatuError
from splatu.json_files import is_finite_number, read_json
from splatu.model import GaussianModel, ModelRender

ENSEMBLE_FILE = "ensemble.json"


@dataclass(frozen=True)
class EnsembleRecord:
    """What `splatu train --ensemble N` wrote: member run dirs and the total wall time."""

    members: list[Path]
    wall_seconds: float | None


def read_ensemble(run_dir: Path) -> EnsembleRecord:
    """Parse <run>/ensemble.json; members are resolved relative to the run directory."""
    path = run_dir / ENSEMBLE_FILE
    if not path.is_file():
        raise SplatuError("not an ensemble run (no ensemble.json)", f"in {run_dir}",
                          "train one with `splatu train --method ensemble` or pick another --method")
    try:
        record = read_json(path)
        members = [run_dir / m for m in record["members"]]
    except (KeyError, TypeError) as err:
        raise SplatuError(f"ensemble.json is malformed ({type(err).__name__})", f"in {path}",
                          "retrain the ensemble or fix its members list") from None
    if len(members) < 2:
        raise SplatuError(f"an ensemble needs at least 2 members, ensemble.json lists {len(members)}", f"in {path}",
                          "train with --ensemble 2 or more")
    wall = record.get("wall_seconds")
    if wall is not None and not is_finite_number(wall):
        raise SplatuError(f"wall_seconds is {wall!r}, not a number", f"in {path}", "fix or regenerate the file")
    return EnsembleRecord(members, wall)


@dataclass
class EnsembleSource:
    """Mean render of the members, with their per-pixel RGB std as the uncertainty."""

    members: list[GaussianModel]
    sh_degree: int
    background: Tensor
    density_aware: bool = False

    def render(self, camera: Camera) -> UncertaintyRender:
        outs = [m.render(camera, self.sh_degree, self.background) for m in self.members]
        rgbs = torch.stack([o.rgb for o in outs]).clamp(0.0, 1.0)
        alpha = torch.stack([o.alpha for o in outs]).mean(dim=0)
        uncertainty = rgbs.std(dim=0, correction=0).mean(dim=-1)
        if self.density_aware:
            uncertainty = uncertainty + (1.0 - alpha).square()
        return UncertaintyRender(rgbs.mean(dim=0), pooled_depth(outs), alpha, uncertainty)


def pooled_depth(outs: list[ModelRender]) -> Tensor:
    """The members' blended depth pooled as one render's is, Σ_m α_m·d_m / Σ_m α_m, 0 where none drew anything: the
    plain mean counted a member that drew nothing at a pixel as depth 0 there, halving the depth of a pixel only half
    the members cover."""
    alphas = torch.stack([o.alpha for o in outs])
    covered = alphas.sum(dim=0)
    weighted = (alphas * torch.stack([o.depth for o in outs])).sum(dim=0)
    return torch.where(covered > 0, weighted / covered.clamp_min(1e-10), 0.0)
