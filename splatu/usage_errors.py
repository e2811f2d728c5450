"""tyro's parse-error boxes, retold as splatu's one-line user errors.

tyro reports a mistyped flag or value in a boxed panel of a dozen lines, with the helptext of every flag it
guesses. Every other user error here is one line (`SplatuError`), so the box is read back and shortened to
what is wrong and how to fix it: tyro's own message, the flags it suggests, and the subcommand's `--help`.
Anything that does not read as such a box is left to tyro's own output.
"""

from __future__ import annotations

import ast
import difflib
import itertools
import re
from collections.abc import Collection, Sequence
from typing import Any

from splatu.config_values import flat_options, to_dict
from splatu.errors import SplatuError

_ANSI = re.compile(r"\x1b\[[0-9;]*m")  # tyro colours its boxes when stdout is a terminal
_RULE = re.compile(r"^(─+|-+)$")
_APPLIED_TO = re.compile(r"^(.+?) \(applied to [^)]*\)$")  # an item of tyro's "Unrecognized or misplaced options"
_VALUE_ERROR = re.compile(r"^Error parsing (--[\w.-]+): (.*)$")
_INVALID_CHOICE = re.compile(r"^invalid choice (.+) for argument '(--[\w.-]+)'\. Expected one of (\(.*\))\.?$")
_MISSING_VALUE = re.compile(r"^Missing value for argument '(--[\w.-]+)'\. Expected (\d+) values?\.?$")
_TYPE_WORDS = {"INT": ("a whole number", "whole numbers"), "FLOAT": ("a number", "numbers"),
               "STR": ("a text", "texts"), "PATH": ("a path", "paths")}
"""How each of tyro's metavars reads in a sentence, one and several; another (a custom one) keeps tyro's message."""


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


def _quoted(values: Sequence[str]) -> str:
    """Values as typed, each quoted: 'abc', or '1' '2' 'x' for a flag that takes several."""
    return " ".join(repr(value) for value in values)


def _choices(choices: Sequence[str]) -> str:
    """"one of a, b, c", with an Optional's None told last ("(or None)"): tyro lists an Optional Literal's choices
    in a set's order, which changes from run to run, so those are sorted."""
    named = [choice for choice in choices if choice != "None"]
    named = sorted(named) if len(named) < len(choices) else named
    listed = named[0] if len(named) == 1 else f"one of {', '.join(named)}"
    return f"{listed} (or None)" if len(named) < len(choices) else listed


def _takes(metavar: str) -> str | None:
    """What a flag with tyro's `metavar` takes, in words ("a whole number (or None)" for {None}|INT, "3 numbers"
    for FLOAT FLOAT FLOAT), or None for a metavar these words do not cover."""
    alternatives = metavar.split("|")
    optional = "{None}" in alternatives
    told = []
    for alternative in (a for a in alternatives if a != "{None}"):
        if alternative.startswith("{") and alternative.endswith("}"):
            inner = alternative[1:-1]
            if "," in inner or inner.split()[0] not in _TYPE_WORDS:  # {a,b,c}: choices, not a grouped tuple
                told.append(_choices(inner.split(",")))
                continue
            alternative = inner
        words = alternative.replace("[", " ").replace("]", " ").split()
        if "..." in words:  # a list: [INT [INT ...]] may be empty, INT [INT ...] may not
            kind = _TYPE_WORDS.get(words[0])
            if kind is None:
                return None
            told.append(f"{'any number of' if alternative.startswith('[') else 'one or more'} {kind[1]}")
        elif all(word in _TYPE_WORDS for word in words):
            if len(set(words)) == 1:
                told.append(_TYPE_WORDS[words[0]][0] if len(words) == 1 else f"{len(words)} {_TYPE_WORDS[words[0]][1]}")
            else:
                told.append(" then ".join(_TYPE_WORDS[word][0] for word in words))
        else:
            return None
    if not told:
        return None
    return " or ".join(told) + (" (or None)" if optional else "")


_TYPED_LIST = re.compile(r"(?:instantiated from|Could not parse arguments|valid parse for arguments:) \[")
"""Where tyro quotes every value typed for a flag as a list: "no type matching ... could be instantiated from
[...]", "Could not parse arguments [...] into tuple type", "Could not find valid parse for arguments: [...]"."""
_TYPED_LAST = re.compile(r": ('.*'|\".*\")\.?$")
"""Where Python's own message quotes the one value typed: "invalid literal for int() with base 10: 'x'"."""


def _typed_values(problem: str) -> list[str] | None:
    """The values tyro's parse error `problem` says were typed, or None when it quotes none this way. Only a list
    where tyro puts one counts: a value typed as "['a', 'b']" is one value, not two."""
    if listed := _TYPED_LIST.search(problem):
        start = listed.end() - 1
        for end in (i for i in range(start, len(problem)) if problem[i] == "]"):  # a value may hold "]" itself
            try:
                found = ast.literal_eval(problem[start:end + 1])
            except (ValueError, SyntaxError):
                continue
            return found if isinstance(found, list) and all(isinstance(v, str) for v in found) else None
        return None
    if (last := _TYPED_LAST.search(problem)) is None:
        return None
    try:
        value = ast.literal_eval(last.group(1))
    except (ValueError, SyntaxError):
        return None
    return [value] if isinstance(value, str) else None


def _plain_value_error(sections: list[list[str]]) -> str | None:
    """What is wrong with a flag's value, in words (--downscale takes a whole number (or None), got 'abc'), for
    tyro's "Error parsing", "invalid choice" and "Missing value" messages, which show Python's exceptions and class
    reprs (<class 'int'>: invalid literal for int() with base 10); None for any other message."""
    said = " ".join(line.strip() for line in sections[0])
    if found := _INVALID_CHOICE.match(said):
        try:
            value, choices = ast.literal_eval(found.group(1)), ast.literal_eval(found.group(3))
        except (ValueError, SyntaxError):
            return None
        return f"{found.group(2)} takes {_choices([str(choice) for choice in choices])}, got {value!r}"
    if found := _MISSING_VALUE.match(said):
        count = int(found.group(2))
        return f"{found.group(1)} needs {'a value' if count == 1 else f'{count} values'} after it"
    found = _VALUE_ERROR.match(said)
    helptext = next((s for s in sections[1:] if s[0].strip().startswith("Argument helptext")), None)
    if found is None or helptext is None or len(helptext) < 2:
        return None
    flag, metavar = found.group(1), helptext[1].strip().removeprefix(found.group(1)).strip()
    takes, values = _takes(metavar), _typed_values(found.group(2))
    if takes is None or not values:
        return None
    return f"{flag} takes {takes}, got {_quoted(values)}"


def _closest_first(names: list[str], problem: list[str]) -> list[str]:
    """tyro's suggested flags, the nearest spelling of a flag the user typed (in the box's first section) first:
    tyro lists them alphabetically, so `--step` read "did you mean --eval-every-steps or ... or --steps?"."""
    typed = re.findall(r"(?<![\w-])--[\w.-]+", " ".join(problem))
    if not typed:
        return names
    return sorted(names, key=lambda name: -max(difflib.SequenceMatcher(None, flag, name).ratio() for flag in typed))


def switch_flags(config: Any) -> frozenset[str]:
    """The boolean flags of a command's config instance, as tyro spells each (`--uncertainty.off`,
    `--uncertainty.no-off`), and by its last name alone too, as a config nested with tyro's OmitArgPrefixes takes it
    (render-uncertainty's `--density-aware`): only these take no value."""
    flags: set[str] = set()
    for name, value in flat_options(to_dict(config)).items():
        if isinstance(value, bool):
            parent, dot, last = name.replace("_", "-").rpartition(".")
            flags |= {f"--{parent}{dot}{last}", f"--{parent}{dot}no-{last}", f"--{last}", f"--no-{last}"}
    return frozenset(flags)


def _value_after_switch(sections: list[list[str]], argv: Sequence[str],
                        switches: Collection[str]) -> SplatuError | None:
    """The error for a value typed after a boolean flag (one of `switches`: `--uncertainty.off True`,
    `--no-progress=false`), which tyro lists as an unrecognized option alone ("unrecognized options: True"); None for
    any other box, such as a value typed twice (`--steps 5 5`), whose flag takes one. A flag tyro left unread is no
    flag of the command, whatever its name."""
    listed = " ".join(line.strip() for line in sections[0])
    if not listed.startswith("Unrecognized options: "):
        return None
    unread = listed.removeprefix("Unrecognized options: ").split(", ")
    for before, arg in itertools.pairwise(["", *argv]):
        flag, value = arg.split("=", 1) if arg.startswith("--") and "=" in arg else (before, arg)
        if (flag.replace("_", "-") in switches and flag not in unread and value in unread
                and not value.startswith("--")):
            parent, dot, last = flag[2:].replace("_", "-").rpartition(".")
            name = last.removeprefix("no-")
            on, off = f"--{parent}{dot}{name}", f"--{parent}{dot}no-{name}"
            return SplatuError(f"{flag} takes no value, got {value!r}", "on the command line",
                               f"write {on} alone to turn it on, or {off} to turn it off")
    return None


def usage_error(tyro_output: str, help_command: str, subcommands: Sequence[str],
                argv: Sequence[str] = (), switches: Collection[str] = ()) -> SplatuError | None:
    """The one-line error for tyro's parse-error box `tyro_output` of the command line `argv`, or None when it is
    not one. `subcommands` are named from the registry: tyro's own list is wrapped over lines of the box.
    `switches`: the chosen command's boolean flags (`switch_flags`)."""
    sections = _box_sections(tyro_output)
    if not sections:
        return None
    see_help = f"see `{help_command} --help`"
    if (plain := _plain_value_error(sections)) is not None:
        return SplatuError(plain, "on the command line", see_help)
    if (switch := _value_after_switch(sections, argv, switches)) is not None:
        return switch
    hints = []
    misplaced = _misplaced(sections[0])
    unplaced = _options_without_subcommand(sections)
    if misplaced:
        message = f"{sections[0][0].strip().rstrip(':')}: {', '.join(misplaced)}"
        hints.append("put each option after its subcommand")
    elif unplaced is not None:
        message = f"unrecognized or misplaced options: {unplaced}"
        hints.append("put each option after its subcommand")
    else:
        message = " ".join(line.strip() for line in sections[0]).rstrip(".")
    message = re.sub(r"^Error parsing ", "", message)
    message = message[:1].lower() + message[1:]
    for section in sections[1:]:
        heading = section[0].strip()
        if heading.startswith("Perhaps you meant"):
            names = _closest_first(_flag_names(section[1:], help_command), sections[0])
            if names:
                hints.append(f"did you mean {' or '.join(names)}?")
        elif heading.startswith("Argument helptext") and len(section) > 1:
            hints.append(f"pass {section[1].strip()}")
        elif heading.startswith("Available subcommands"):
            hints.append(f"available subcommands: {', '.join(subcommands)}")
    return SplatuError(message, "on the command line", f"{'; '.join(hints)} ({see_help})" if hints else see_help)


def _options_without_subcommand(sections: list[list[str]]) -> str | None:
    """The options of a box for a command line with no subcommand (tyro lists the subcommands then), or None: the
    CLI builds no subcommand's config unless one is named, so tyro cannot tell that `splatu --load x` holds options
    of a subcommand and calls them only unrecognized; they are misplaced too."""
    listed = " ".join(line.strip() for line in sections[0])  # a long list wraps over lines of the box
    if not listed.startswith("Unrecognized options: "):
        return None
    if not any(section[0].strip().startswith("Available subcommands") for section in sections[1:]):
        return None
    return listed.removeprefix("Unrecognized options: ")


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
