"""The method registry, in the manner of nerfstudio's: a method is a named config change.

Adding a method is one entry here: a function TrainConfig -> TrainConfig plus a description.
The trainer never branches on the method name; it only uses it to name the output folder.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from splatu.errors import SplatuError

if TYPE_CHECKING:
    from splatu.train_config import TrainConfig

PAPER_ENSEMBLE_SIZE = 10


@dataclass(frozen=True)
class Method:
    description: str
    configure: Callable[[TrainConfig], TrainConfig]
    ensemble: bool = False
    """Whether it trains several models (`--ensemble N`) rather than one: a run is named after it only if so."""


def _splatu(config: TrainConfig) -> TrainConfig:
    return dataclasses.replace(config, uncertainty=dataclasses.replace(config.uncertainty, off=False))


def _splatfacto(config: TrainConfig) -> TrainConfig:
    return dataclasses.replace(config, uncertainty=dataclasses.replace(config.uncertainty, off=True))


def _ensemble(config: TrainConfig) -> TrainConfig:
    """Plain 3DGS members; the paper's baseline uses 10 unless --ensemble says otherwise."""
    members = config.ensemble if config.ensemble > 1 else PAPER_ENSEMBLE_SIZE
    return dataclasses.replace(_splatfacto(config), ensemble=members)


METHODS: dict[str, Method] = {
    "splatu": Method("3DGS with the view-dependent SH uncertainty trained in the same step (the paper).", _splatu),
    "splatfacto": Method("Plain splatfacto-style 3DGS, no uncertainty loss.", _splatfacto),
    "ensemble": Method("N plain 3DGS members differing only in seed; uncertainty = std across members.", _ensemble,
                       ensemble=True),
}


def method_help() -> str:
    """`--method`'s help: the registry's names and descriptions, so a new entry documents itself."""
    listed = " ".join(f"{name}: {method.description}" for name, method in METHODS.items())
    return f"Registered method; it sets defaults before the other flags. {listed}"


def loss_setting(name: str, config: TrainConfig) -> bool | None:
    """Whether registered method `name` turns the uncertainty loss on (True: splatu) or off (False: splatfacto,
    ensemble) for `config`, or None if it leaves `--uncertainty.off` as given; read from its configure, so that a new
    entry needs no other code to be told apart."""
    if name not in METHODS:  # a name the registry does not know (from Python): nothing to read
        return None
    configure = METHODS[name].configure
    trains_on, trains_off = (not configure(_with_loss_off(config, off)).uncertainty.off for off in (False, True))
    return trains_on if trains_on == trains_off else None


def _with_loss_off(config: TrainConfig, off: bool) -> TrainConfig:
    """`config` with the uncertainty loss off or on, and without extra heads, which a config with the loss off refuses
    (a method's configure is tried on it to see what the method changes)."""
    return dataclasses.replace(config, uncertainty=dataclasses.replace(config.uncertainty, off=off, extra_heads=()))


def _kind(config: TrainConfig) -> tuple[bool, bool]:
    """What sets methods apart where they are filed: whether the loss trains, and whether several models do."""
    return config.uncertainty.off, config.ensemble > 1


def method_of(config: TrainConfig) -> str:
    """The registered method `config` trains: the one it names unless a flag undid it (`--uncertainty.off` makes
    `splatu` plain splatfacto), so a run is filed and summarised as what it is, not as what it was called. A method
    fits only as many models as it trains: an ensemble whose members keep the uncertainty loss is no splatu run
    (its `latest` would be an ensemble that `render-uncertainty` refuses), so it keeps the name it was given. Only
    that kind (`_kind`) is compared: a flag that overrides another of a method's settings (a budget) leaves the run
    filed under the method it named."""
    if config.method not in METHODS:  # a name the registry does not know (from Python): nothing to compare with
        return config.method
    candidates = [config.method, *(name for name in METHODS if name != config.method)]
    tried = _with_loss_off(config, config.uncertainty.off)
    return next((name for name in candidates if _kind(METHODS[name].configure(tried)) == _kind(config)
                 and METHODS[name].ensemble == (config.ensemble > 1)), config.method)


def get_method(name: str) -> Method:
    if name not in METHODS:
        raise SplatuError(f"unknown method {name!r}", "in --method", f"use one of {', '.join(METHODS)}")
    return METHODS[name]
