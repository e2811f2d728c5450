"""Each option's `--help` text as one paragraph, which the terminal then wraps.

tyro 1.0 joins a docstring's lines only where the next line starts with a letter, and it does so before it
removes the indentation, so every line break of an indented attribute docstring reached `--help` and cut
sentences at any terminal width. docstring_parser, which tyro reads options' help through, takes `:param name:`
entries from a class's own docstring before the attribute docstrings; so the options' docstrings are handed
over there, each already joined into one line.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import itertools
import textwrap

_HANDED_OVER = "__splatu_option_help__"


def attribute_docstrings(config_class: type) -> dict[str, str]:
    """Field name → the docstring written under it in `config_class`'s own source."""
    body = ast.parse(textwrap.dedent(inspect.getsource(config_class))).body[0].body
    return {field.target.id: doc.value.value for field, doc in itertools.pairwise(body)
            if isinstance(field, ast.AnnAssign) and isinstance(field.target, ast.Name)
            and isinstance(doc, ast.Expr) and isinstance(doc.value, ast.Constant) and isinstance(doc.value.value, str)}


def one_line(docstring: str) -> str:
    return " ".join(docstring.split())


def hand_option_help_to_tyro(config_class: type) -> None:
    """Put the option docstrings of `config_class` and of every config nested in it into their classes' own
    docstrings as `:param` entries, one line each. Once per class; the attribute docstrings stay the source."""
    if getattr(config_class, _HANDED_OVER, False):
        return
    try:
        docs = attribute_docstrings(config_class)
    except OSError:  # no source installed: tyro cannot read the docstrings either, and the options still parse
        return
    own = config_class.__doc__ if config_class.__doc__ and not config_class.__doc__.startswith(
        f"{config_class.__name__}(") else ""  # dataclass's generated signature is not a description
    params = "\n".join(f":param {name}: {one_line(doc)}" for name, doc in docs.items())
    config_class.__doc__ = f"{inspect.cleandoc(own)}\n\n{params}".strip() if params else own
    setattr(config_class, _HANDED_OVER, True)
    for field in dataclasses.fields(config_class):
        nested = field.default_factory() if field.default_factory is not dataclasses.MISSING else field.default
        if dataclasses.is_dataclass(nested):
            hand_option_help_to_tyro(type(nested))
