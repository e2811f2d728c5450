"""tyro's parse-error boxes, retold as splatu's one-line user errors.

tyro reports a mistyped flag or value in a boxed panel of a dozen lines, with the helptext of every flag it
guesses. Every other user error here is one line (`SplatuError`), so the box is read back and shortened to
what is wrong and how to fix it: tyro's own message, the flags it suggests, and the subcommand's `--help`.
Anything that does not read as such a box is left to tyro's own output.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Sequence

from splatu.errors import SplatuError

_ANSI = re.compile(r"\x1b\[[0-9;]*m")  # tyro colours its boxes when stdout is a terminal
_RULE = re.compile(r"^(─+|-+)$")
_APPLIED_TO = re.compile(r"^(.+?) \(applied to [^)]*\)$")  # an item of tyro's "Unrecognized or misplaced options"


def _box_lines(text: str) -> list[str]:
    """The content lines of tyro's box: drawn with │ sides (a UTF-8 stdout), or as a title line, a rule of
    dashes and lines indented by two spaces (any other stdout encoding). Empty when `text` is neither."""
    lines = [_ANSI.sub("", line).rstrip() for line in text.splitlines()]
    if any(line.startswith("╭") for line in lines):
        return [line[2:-1].rstrip() for line in lines if line.startswith("│") and line.endswith("│")]
    first_rule = next((i for i, line in enumerate(lines) if _RULE.match(line.strip())), None)
    return [line[2:] for line in lines[2:]] if first_rule == 1 else []


def _box_sections(text: str) -> list[list[str]]:
    """The box's content cut into sections at its rules, without blank lines."""
    sections: list[list[str]] = [[]]
    for line in _box_lines(text):
        if _RULE.match(line.strip()):
            sections.append([])
        elif line.strip():
            sections[-1].append(line)
    return [s for s in sections if s]


def _flag_names(lines: list[str], help_command: str) -> list[str]:
    """The flags under "Perhaps you meant:" that belong to `help_command`: a line indented by exactly four spaces
    names a flag, and tyro may end its entry with "in splatu SUBCOMMAND --help", which can be another
    subcommand's (whose flags would be refused here too)."""
    names: list[str] = []

    def keep(name: str) -> None:
        if name.startswith("-") and name not in names:
            names.append(name)

    current: str | None = None  # the flag whose entry is being read, until its "in ... --help" line
    for line in lines:
        text = line.strip()
        if line.startswith("    ") and not line.startswith("     "):
            if current is not None:
                keep(current)
            current = line.split()[0].rstrip(",")
        elif current is not None and text.startswith("in ") and text.endswith(" --help"):
            if text == f"in {help_command} --help":
                keep(current)
            current = None
    if current is not None:
        keep(current)
    return names


def _misplaced(section: list[str]) -> list[str]:
    """The arguments that tyro lists as misplaced, one a line with "(applied to splatu)" after each: its note on
    argument order, which follows them, is left out."""
    return [found.group(1) for line in section[1:] if (found := _APPLIED_TO.match(line.strip()))]


def usage_error(tyro_output: str, help_command: str, subcommands: Sequence[str]) -> SplatuError | None:
    """The one-line error for tyro's parse-error box `tyro_output`, or None when it is not one. `subcommands` are
    named from the registry: tyro's own list is wrapped over lines of the box."""
    sections = _box_sections(tyro_output)
    if not sections:
        return None
    hints = []
    misplaced = _misplaced(sections[0])
    if misplaced:
        message = f"{sections[0][0].strip().rstrip(':')}: {', '.join(misplaced)}"
        hints.append("put each option after its subcommand")
    else:
        message = " ".join(line.strip() for line in sections[0]).rstrip(".")
    message = re.sub(r"^Error parsing ", "", message)
    message = message[:1].lower() + message[1:]
    for section in sections[1:]:
        heading = section[0].strip()
        if heading.startswith("Perhaps you meant"):
            names = _flag_names(section[1:], help_command)
            if names:
                hints.append(f"did you mean {' or '.join(names)}?")
        elif heading.startswith("Argument helptext") and len(section) > 1:
            hints.append(f"pass {section[1].strip()}")
        elif heading.startswith("Available subcommands"):
            hints.append(f"available subcommands: {', '.join(subcommands)}")
    see_help = f"see `{help_command} --help`"
    return SplatuError(message, "on the command line", f"{'; '.join(hints)} ({see_help})" if hints else see_help)


def _closest(word: str, subcommands: Sequence[str]) -> str | None:
    """The subcommand `word` most likely meant: a near spelling (`trian`), else the only one it begins or begins a
    part of (`render`, `ause`)."""
    word = word.lower()
    near = difflib.get_close_matches(word, subcommands, n=1)
    if near:
        return near[0]
    begun = [name for name in subcommands if any(part.startswith(word) for part in (name, *name.split("-")))]
    return begun[0] if len(begun) == 1 else None


def unknown_subcommand(word: str, subcommands: Sequence[str]) -> SplatuError:
    """The error for a first argument that names no subcommand (`splatu trian --steps 3`), told before tyro parses:
    its box calls every argument after it misplaced, and wraps its list of subcommands over lines."""
    listed = ", ".join(subcommands)
    guess = _closest(word, subcommands)
    fix = (f"did you mean `splatu {guess}`? (the subcommands are {listed}; see `splatu --help`)" if guess
           else f"use one of {listed} (see `splatu --help`)")
    return SplatuError(f"unknown subcommand {word!r}", "on the command line", fix)
