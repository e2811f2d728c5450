"""The `splatu` command line: tyro subcommands over dataclass configs, nerfstudio style.

Each subcommand is a `Command`: a description, a function that builds its default config
(it sees the raw arguments, so `train --preset quality` can change the defaults that
`--help` shows), and the function that runs it. User errors (`SplatuError`) print one line
and exit 2; `--debug` or SPLATU_DEBUG=1 shows the traceback instead.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import sys
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from typing import Any, NoReturn

import tyro

from splatu.allocator import keep_freed_memory
from splatu.errors import SplatuError
from splatu.interrupts import Interrupted, exit_code
from splatu.option_help import hand_option_help_to_tyro
from splatu.usage_errors import switch_flags, unknown_subcommand, usage_error


@dataclass(frozen=True)
class Command:
    description: str
    default_config: Callable[[Sequence[str]], Any]
    run: Callable[[Any, Sequence[str]], None]
    """Runs the parsed config; it sees the subcommand's raw arguments too (train tells which flags were typed)."""


def _commands() -> dict[str, Command]:
    """Every subcommand, imported here so that one list is the whole CLI."""
    from splatu.commands import COMMANDS

    return COMMANDS


def main(argv: Sequence[str], debug: bool = False) -> None:
    commands = _commands()
    if argv and argv[0].replace("_", "-") in commands:  # tyro takes render_uncertainty for render-uncertainty too
        argv = [argv[0].replace("_", "-"), *argv[1:]]
    if argv and argv[0] not in commands and not argv[0].startswith("-"):
        raise unknown_subcommand(argv[0], list(commands))
    chosen = argv[0] if argv and argv[0] in commands else None
    # only the chosen subcommand's config is built, which imports its module (seconds, for torch): the others are
    # listed by name and description. One typed after options (`splatu --steps 3 train`) is built too, for tyro to
    # tell those options misplaced. Only the chosen sees the arguments: `eval-ause --method fisher` is not `train
    # --method`
    built = [name for name in commands
             if name == chosen or (chosen is None and name in (a.replace("_", "-") for a in argv))]
    defaults = {name: (cmd.default_config(list(argv[1:]) if name == chosen else []) if name in built
                       else _stand_in(name)) for name, cmd in commands.items()}
    for name in built:
        hand_option_help_to_tyro(type(defaults[name]))
    descriptions = {name: cmd.description for name, cmd in commands.items()}
    config_type = tyro.extras.subcommand_type_from_defaults(defaults, descriptions=descriptions)
    switches = switch_flags(defaults[chosen]) if chosen else frozenset()
    config = _parse(config_type, argv, f"splatu {chosen}" if chosen else "splatu", list(commands), debug, switches)
    name = next(n for n, d in defaults.items() if type(d) is type(config))
    commands[name].run(config, list(argv[1:]))


def _stand_in(name: str) -> Any:
    """An empty config in place of a subcommand not chosen, for tyro to list it by name."""
    return dataclasses.make_dataclass(name.replace("-", "_"), [], frozen=True)()


def _parse(config_type: Any, argv: Sequence[str], help_command: str, subcommands: Sequence[str], debug: bool,
           switches: Collection[str]) -> Any:
    """tyro.cli with what it prints to stderr held back: a parse-error box is retold as one `SplatuError` line
    (unless --debug); anything else (tyro's warnings, a box we cannot read) is passed on as it was. `switches`: the
    chosen command's boolean flags."""
    captured = io.StringIO()
    error = None
    try:
        with contextlib.redirect_stderr(captured):
            return tyro.cli(
                config_type,
                args=list(argv),
                prog="splatu",
                description="3D Gaussian Splatting on the CPU with view-dependent uncertainty. A user error prints "
                            "one line and exits 2; add --debug (or set SPLATU_DEBUG=1) for its traceback.",
            )
    except SystemExit as stop:
        if stop.code not in (0, None) and not debug:
            error = usage_error(captured.getvalue(), help_command, subcommands, argv, switches)
        if error is None:
            raise
        raise error from None
    finally:
        if error is None:
            sys.stderr.write(captured.getvalue())


def _run(args: list[str], debug: bool) -> None:
    """The command, then its output flushed: a reader that left (`splatu --version | true`) is then a
    BrokenPipeError for `entrypoint` to end on quietly, not Python's own at exit ("Exception ignored", status 120),
    which it was wherever the whole output fitted in stdout's buffer."""
    try:
        if args == ["--version"]:
            from splatu import __version__

            print(f"splatu {__version__}")
        else:
            keep_freed_memory()  # every command renders: no step should page-fault its buffers back in
            main(args, debug)
    except SystemExit as done:
        if done.code in (0, None):  # --help: tyro prints it, then exits; a reader that left is entrypoint's to end
            sys.stdout.flush()
        else:  # a stopped training's 130 or 143 says more than a closed pipe's 1
            _flush_or_drop()
        raise
    sys.stdout.flush()  # not in a `finally`: a refused flush would replace the command's own error or stop


def _drop_unread_output() -> None:
    """Point stdout at /dev/null, which could not take the output (its reader left): the exit's own flush must not
    fail too, which Python reports as "Exception ignored ... BrokenPipeError" with status 120, in place of the
    command's own."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def _flush_or_drop() -> None:
    """Write out what the command printed, or drop it if stdout cannot take it (its reader left, a full disk)."""
    try:
        sys.stdout.flush()
    except OSError:
        _drop_unread_output()


def _end(status: int, line: str) -> NoReturn:
    """Exit with `status` after saying why on stderr. What the command printed goes first (so a log of both streams
    keeps their order), or nowhere if stdout cannot take it (its reader left, a full disk): the line and the status
    are what still matter."""
    _flush_or_drop()
    print(line, file=sys.stderr)
    sys.exit(status)


def entrypoint(argv: Sequence[str] | None = None) -> None:
    for stream in (sys.stdout, sys.stderr):  # help texts hold λ, σ, ≈…: an ASCII-only console shows "?", not a crash
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="replace")
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args or os.environ.get("SPLATU_DEBUG", "") not in ("", "0")
    args = [a for a in args if a != "--debug"]
    try:
        _run(args, debug)
    except SplatuError as err:
        if debug:
            raise
        _end(2, f"error: {err}")
    except KeyboardInterrupt as stop:
        _end(exit_code(stop), f"interrupted: {stop.left}" if isinstance(stop, Interrupted) else "interrupted")
    except BrokenPipeError:  # `splatu train --help | head`: the reader left, so there is no one to tell
        if debug:
            raise
        _drop_unread_output()
        sys.exit(1)
