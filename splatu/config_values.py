"""Typed option values from YAML: a mapping applied to a dataclass config, each value checked against the
field's type, and a config turned back into plain YAML-safe values.

Presets, saved run configs and checkpoints all go through here, so a wrong value in any of them is one
line naming the option, the file, the expected type and the value, never a traceback or a silent cast.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import functools
import math
import types
import typing
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import yaml

from splatu.errors import SplatuError


def read_yaml(path: Path) -> dict[str, Any]:
    """A YAML mapping, or a one-line error naming the file. The file is read each time and parsed once per text
    (`_parsed`): a train command consults its preset three times (loading, the --steps rescale, the note)."""
    try:
        values = copy.deepcopy(_parsed(path.read_text(encoding="utf-8")))  # the caller's own, free to change
    except _DuplicateKey as err:
        raise SplatuError(f"option {err.key!r} is given twice (first at line {err.first})",
                          f"in {path}, line {err.line}",
                          "keep one of the two lines, the one with the value you mean") from None
    except (OSError, yaml.YAMLError) as err:
        mark = getattr(err, "problem_mark", None)  # a syntax error's place: the file alone sent users searching it
        at = f", line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise SplatuError(f"cannot read YAML ({type(err).__name__})", f"in {path}{at}",
                          "check the file exists and is valid YAML") from None
    if values is None:
        return {}
    if not isinstance(values, dict):
        raise SplatuError("a config file must hold a mapping of option: value", f"in {path}",
                          "write one `option: value` per line")
    return values


class _DuplicateKey(Exception):
    """A mapping of the YAML text gives `key` twice, at 1-based lines `first` and `line`: YAML keeps the last value
    without a word, so a preset's `sh_degree: 2` above `sh_degree: 3` was silently 3."""

    def __init__(self, key: str, first: int, line: int) -> None:
        super().__init__(key)
        self.key, self.first, self.line = key, first, line


def _refuse_duplicate_keys(node: yaml.Node | None, prefix: str = "") -> None:
    """Raise `_DuplicateKey` for the first key given twice in one mapping of the composed YAML `node`, by its dotted
    name (`model.sh_degree`)."""
    if isinstance(node, yaml.SequenceNode):
        for item in node.value:
            _refuse_duplicate_keys(item, prefix)
    if not isinstance(node, yaml.MappingNode):
        return
    seen: dict[Any, int] = {}
    for key, value in node.value:
        name = f"{prefix}{key.value}" if isinstance(key, yaml.ScalarNode) else None
        if name is not None and (key.tag, key.value) in seen:
            raise _DuplicateKey(name, seen[(key.tag, key.value)], key.start_mark.line + 1)
        if name is not None:
            seen[(key.tag, key.value)] = key.start_mark.line + 1
        _refuse_duplicate_keys(value, f"{name}." if name is not None else prefix)


@functools.lru_cache(maxsize=16)
def _parsed(text: str) -> Any:
    """`text` parsed as YAML, refusing a key given twice. Keyed by the text, not by path and mtime, so a file
    rewritten within the clock tick its filesystem stamps (tests rewrite a preset in a row) is never answered from
    its old contents."""
    _refuse_duplicate_keys(yaml.compose(text, Loader=yaml.SafeLoader))
    return yaml.safe_load(text)


def apply_values(config: Any, values: Mapping[str, Any], source: str, prefix: str = "") -> Any:
    """A copy of dataclass `config` with `values` (nested dicts for nested configs) applied.

    `prefix` is the dotted path of `config` inside the root config, so errors name `densify.refine_every`.
    """
    hints = typing.get_type_hints(type(config))
    changes: dict[str, Any] = {}
    for raw_key, value in values.items():
        key = _option_name(raw_key, hints, prefix, source)
        if key not in hints:
            names = [f.name for f in dataclasses.fields(config)]
            near = difflib.get_close_matches(key, names, n=1)  # a misspelt key, which a list of 25 hides
            known = f"did you mean {prefix + near[0]!r}?" if near else f"use one of: {', '.join(names)}"
            raise SplatuError(f"unknown option {prefix + key!r} for {type(config).__name__}", f"in {source}", known)
        current = getattr(config, key)
        if dataclasses.is_dataclass(current) and isinstance(value, Mapping):
            changes[key] = apply_values(current, value, source, f"{prefix}{key}.")
        else:
            changes[key] = _coerce_option(hints[key], value, prefix + key, source)
    return dataclasses.replace(config, **changes)


def without_options(values: Mapping[str, Any], dropped: Collection[str], prefix: str = "") -> dict[str, Any]:
    """`values` (nested mappings for nested configs) without the options whose dotted names are in `dropped`."""
    kept: dict[str, Any] = {}
    for key, value in values.items():
        if isinstance(value, Mapping):
            kept[key] = without_options(value, dropped, f"{prefix}{key}.")
        elif f"{prefix}{key}" not in dropped:
            kept[key] = value
    return kept


def flat_options(values: Any, prefix: str = "") -> dict[str, Any]:
    """`values` (nested mappings for nested configs) as one mapping of dotted option names to values."""
    if not isinstance(values, Mapping):
        return {prefix.rstrip("."): values}
    return {k: v for key, value in values.items() for k, v in flat_options(value, f"{prefix}{key}.").items()}


def nested_options(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted option names as nested mappings, the form `apply_values` takes: the inverse of `flat_options`."""
    nested: dict[str, Any] = {}
    for name, value in flat.items():
        *parents, last = name.split(".")
        level = nested
        for part in parents:
            level = level.setdefault(part, {})
        level[last] = value
    return nested


YAML11_BOOL_WORDS = {True: ("on", "yes", "true"), False: ("off", "no", "false")}
"""YAML 1.1 reads these unquoted keys as booleans, so a hand-written `off: true` arrives as the key False."""


def _option_name(key: Any, hints: Mapping[str, Any], prefix: str, source: str) -> str:
    """A mapping key as an option name: a YAML 1.1 boolean key back to the option it spelt (`on`, `off`)."""
    if isinstance(key, bool):
        key = next((word for word in YAML11_BOOL_WORDS[key] if word in hints), key)
    if not isinstance(key, str):
        raise SplatuError(f"option name {prefix}{key!r} is not a word", f"in {source}",
                          "write each option as `name: value`, with the option's name as the key")
    return key


class _Mismatch(Exception):
    """`value` does not fit the type being tried; caught by `_coerce_option` (or by a union trying its next arm)."""


def _coerce_option(tp: Any, value: Any, key: str, source: str) -> Any:
    """`_coerce`, or a one-line error naming the option, the file, the expected type and the value."""
    try:
        return _coerce(tp, value, key, source)
    except _Mismatch:
        raise SplatuError(f"option {key!r} expects {_type_name(tp)}, got {value!r}", f"in {source}",
                          f"write {key} as {_type_name(tp)}") from None


def _type_name(tp: Any) -> str:
    """How an option's type reads in an error: `int`, `one of 'random', 'black'`, `a list of 3 float`."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join("null" if a is type(None) else _type_name(a) for a in args)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_type_name(args[0])}"
        return f"a list of {len(args)} {' / '.join(dict.fromkeys(_type_name(a) for a in args))}"
    if dataclasses.is_dataclass(tp):
        return f"a mapping of {tp.__name__} options"
    return "a path" if tp is Path else tp.__name__


def _float(value: Any) -> float:
    """A YAML number as a float; also a numeric string, since YAML 1.1 reads `1e-3` (no dot) as a string."""
    if isinstance(value, bool):
        raise _Mismatch
    if isinstance(value, int | float):
        return float(value)
    if isinstance(value, str):
        try:
            number = float(value)
        except ValueError:
            raise _Mismatch from None
        if math.isfinite(number):
            return number
    raise _Mismatch


def _coerce(tp: Any, value: Any, key: str, source: str) -> Any:
    """Turn a YAML scalar/list into the field's type (paths, tuples, optional values); `_Mismatch` if it cannot."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        for arm in (a for a in args if a is not type(None)):
            try:
                return _coerce(arm, value, key, source)
            except _Mismatch:
                continue
        raise _Mismatch
    if origin is Literal:
        # `type(...) is` too: YAML `true` must not pass as the choice 1
        if any(value == a and type(value) is type(a) for a in args):
            return value
        raise _Mismatch
    if origin is tuple:
        if not isinstance(value, Sequence) or isinstance(value, str):
            raise _Mismatch
        arms = [args[0]] * len(value) if len(args) == 2 and args[1] is Ellipsis else list(args)
        if len(arms) != len(value):
            raise _Mismatch
        return tuple(_coerce(a, v, key, source) for a, v in zip(arms, value, strict=True))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise _Mismatch
        return apply_values(tp(), value, source, f"{key}.")
    if tp is Path:
        if not isinstance(value, str | Path):
            raise _Mismatch
        return Path(value)
    if tp is float:
        return _float(value)
    # bool is an int in Python, but `steps: true` is a mistake, not 1
    if isinstance(value, tp) and not (isinstance(value, bool) and tp is not bool):
        return value
    raise _Mismatch


def to_dict(config: Any) -> dict[str, Any]:
    """A plain dict of YAML-safe values (paths as strings, tuples as lists)."""

    def plain(value: Any) -> Any:
        if dataclasses.is_dataclass(value):
            return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, Path):
            return str(value)
        if isinstance(value, tuple | list):
            return [plain(v) for v in value]
        return value

    return plain(config)


def changed_options(config: Any, base: Any) -> list[str]:
    """Dotted names of the options where dataclass `config` differs from `base`, in field order."""
    mine, theirs = flat_options(to_dict(config)), flat_options(to_dict(base))
    return [name for name, value in mine.items() if theirs.get(name) != value]
