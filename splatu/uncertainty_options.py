"""Which uncertainty a run's maps show: the options `splatu render-uncertainty` and `splatu eval-ause --load` share,
declared once so the two commands spell, check and label them the same way."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import tyro

from splatu.baselines import METHODS_WITH_OURS, UncertaintyMethod, method_list, own_method
from splatu.errors import SplatuError, require_at_least
from splatu.losses import canonical_head

SEEDED_METHODS = ("random", "fisher")
"""The methods whose maps depend on --seed."""
OWN_METHOD = "the run's own: ours, or ensemble for an ensemble run"
"""What no --method means, for --help."""


@dataclass
class UncertaintyOptions:
    """The method and every option that changes its maps."""

    data: str | None = None
    """Scene to render the run on; default: the one the run was trained on (its recorded path, split and
    downscale)."""
    # None until the run is loaded (`for_run`); parsed as the methods alone (None is no choice to type), with the
    # default told in words
    method: Annotated[UncertaintyMethod | None, tyro.conf.arg(
        constructor=UncertaintyMethod, help_behavior_hint=f"(default: {OWN_METHOD})")] = None
    """Which uncertainty to render: ours, the ensemble's std, or a baseline (splatu.baselines describes each)."""
    head: str | None = None
    """With a method that reads ours (ours, ours-spread, ours-residual, ours-residual-angle,
    ours-view-residual-angle): one of the run's extra uncertainty heads (its spec, as given to
    --uncertainty.extra-heads); default: the run's own."""
    density_aware: bool = False
    """With --method ensemble: add (1 - accumulated alpha)² to the std, for empty space."""
    fisher_probes: int = 2
    """With --method fisher: Rademacher probes per training view."""
    seed: int = 0
    """Seed of the random method and of the Fisher probes, so a seed's maps can be reproduced."""

    def __post_init__(self) -> None:
        require_at_least(self.fisher_probes, 1, "--fisher-probes")

    def check(self, ensemble: bool | None = None) -> None:
        """Refuse, in one line, an option the method never reads (a head is ours', density-aware the ensemble's,
        probes Fisher's, the seed random's and Fisher's) rather than ignore it silently; and a seed outside
        training's range. Before the run is loaded, a method left to its default is not checked yet: `for_run`
        checks it, passing `ensemble` (whether the run is one), so that the error names what the run rendered with
        and suggests only the methods it can render."""
        from splatu.train_config import MAX_SEED  # here: it pulls in the trainer stack, which --maps never needs

        require_at_least(self.seed, 0, "--seed")
        if self.seed >= MAX_SEED:  # the maps seed torch with seed · 1,000,003 + a 32-bit hash (64 bits)
            raise SplatuError(f"--seed {self.seed} is too large", "in the command's options",
                              f"pass a seed below {MAX_SEED:,}")
        if self.method is None:
            return
        if self.head is not None and self.method not in METHODS_WITH_OURS:
            raise SplatuError(f"--head picks an uncertainty head of ours; --method {self.method} has none",
                              "in the command's options",
                              f"drop --head, or use --method {method_list(METHODS_WITH_OURS)}")
        for flag, is_set, readers in (("--density-aware", self.density_aware, ("ensemble",)),
                                      ("--fisher-probes", self.fisher_probes != DEFAULTS.fisher_probes, ("fisher",)),
                                      ("--seed", self.seed != DEFAULTS.seed, SEEDED_METHODS)):
            if is_set and self.method not in readers:
                methods = " or ".join(f"--method {reader}" for reader in readers)
                if ensemble is None:
                    raise SplatuError(f"{flag} only applies with {methods}", "in the command's options",
                                      f"drop {flag}, or pass {methods}")
                # an ensemble run renders with the ensemble alone, a single run with any other method
                usable = " or ".join(f"--method {reader}" for reader in readers if (reader == "ensemble") == ensemble)
                run = "an ensemble run" if ensemble else "a single run"
                raise SplatuError(f"{flag} only applies with {methods}; this is {run}, rendered with {self.method} "
                                  "without --method", "in the command's options",
                                  f"drop {flag}, or pass {usable}" if usable else
                                  f"drop {flag} (it applies to {'a single' if ensemble else 'an ensemble'} run)")

    def for_run(self, ensemble: bool) -> UncertaintyOptions:
        """These options for the run just loaded (`ensemble`: whether it is an ensemble run): a method left to its
        default becomes the run's own (`own_method`) and is checked now; a method typed is kept, already checked."""
        if self.method is not None:
            return self
        resolved = dataclasses.replace(self, method=own_method(ensemble))
        resolved.check(ensemble)
        return resolved

    def label(self, load: Path | None = None, member_steps: tuple[int, ...] | None = None) -> str:
        """The method's name in folder and file names, with every option that changes its maps and is not at its
        default (`ours-<head spec>`, `ensemble-density-aware`, `fisher-4-probes-seed-1`) and, when `load` names a
        checkpoint file rather than the run, that file's name (`ours-step-0001000`), or for an ensemble not whole now
        the steps of its members' checkpoints (`ensemble-steps-30-25`, `LoadedRun.member_steps`), so that one
        variant's maps and scores never overwrite another's, nor an earlier checkpoint's the final model's; a head
        has one spelling (`canonical_head`), so the same head asked for twice writes one set of files. `data` is not
        part of it: it only says where the run's own scene now is (another scene's normalisation is refused), so its
        maps are the same maps."""
        assert self.method is not None, "the method is resolved once the run is loaded (for_run)"
        parts = [self.method if self.head is None else f"{self.method}-{canonical_head(self.head)}"]
        if load is not None and Path(load).expanduser().is_file():
            parts.append(Path(load).stem)
        if member_steps is not None:
            parts.append("steps-" + "-".join(map(str, member_steps)))
        if self.density_aware:
            parts.append("density-aware")
        if self.fisher_probes != DEFAULTS.fisher_probes:
            parts.append(f"{self.fisher_probes}-probes")
        if self.seed != DEFAULTS.seed:
            parts.append(f"seed-{self.seed}")
        return "-".join(parts)

    def record(self) -> dict[str, Any]:
        """The options as a JSON record, beside the maps or scores they made: the method resolved (`for_run`)."""
        assert self.method is not None, "the method is resolved once the run is loaded (for_run)"
        return {name: getattr(self, name) for name in OPTION_NAMES}


OPTION_NAMES = tuple(f.name for f in dataclasses.fields(UncertaintyOptions))
DEFAULTS = UncertaintyOptions()
