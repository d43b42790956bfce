"""The ``dockingrl`` command line: one module per group of subcommands (see ``dockingrl
--help``), each parsing its arguments and calling the library."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback
from pathlib import Path

from dockingrl.cli.arguments import Parser, UsageError
from dockingrl.provenance import set_command_line

DEBUG_HELP = "on an error, show its traceback instead of one line"

#: the groups of subcommands, in ``dockingrl --help``'s order: each group's module, the function
#: of it that adds the group's subcommands, and their names. A command line imports only its own
#: command's group; ``dockingrl --help`` and an unknown command, all of them.
COMMAND_GROUPS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("evaluate", "add_evaluation_commands", ("eval", "export")),
    ("train", "add_training_commands", ("train", "recipes")),
    ("grid", "add_grid_commands", ("grid", "table")),
    (
        "filter",
        "add_filter_commands",
        ("filter-figure", "learn-filter", "filter-ablation"),
    ),
    ("filter_comparison", "add_filter_comparison_command", ("ppo-filter-comparison",)),
    ("stress", "add_stress_command", ("stress",)),
    ("onboard", "add_onboard_commands", ("record-log", "replay")),
    ("upgrade", "add_upgrade_command", ("upgrade",)),
)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``dockingrl`` with the subcommands of ``command``'s group, or with all of
    them when ``command`` is None or no subcommand's name."""
    groups = [g for g in COMMAND_GROUPS if command in g[2]] or COMMAND_GROUPS
    parser = Parser(
        prog="dockingrl",
        description="AUV docking with deep RL: evaluation and training. An error is one line "
        "on stderr and exit status 1 (2: a bad command line, 130: interrupted).",
    )
    parser.add_argument("--debug", action="store_true", help=DEBUG_HELP)
    sub = parser.add_subparsers(dest="command", required=True)
    for module, adder, _ in groups:
        getattr(importlib.import_module(f"dockingrl.cli.{module}"), adder)(sub)
    for subparser in sub.choices.values():  # --debug also after the command's name
        subparser.add_argument(
            "--debug", action="store_true", default=argparse.SUPPRESS, help=DEBUG_HELP
        )
    return parser


class CommandFailed(SystemExit):
    """How a failed ``dockingrl`` command ends, after printing its one line on stderr:
    ``code`` is the exit status, ``str()`` the line."""

    def __init__(self, line: str, code: int) -> None:
        super().__init__(code)
        self.line = line

    def __str__(self) -> str:
        return self.line


def _raised_by_dockingrl(exc: BaseException) -> bool:
    """Whether the innermost frame of ``exc``'s traceback is dockingrl's own code."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    package = Path(__file__).resolve().parents[1]
    return tb is not None and package in Path(tb.tb_frame.f_code.co_filename).resolve().parents


def error_line(exc: BaseException, command: str | None) -> tuple[str, int]:
    """The one line (after ``dockingrl: error: ``) and the exit status that report ``exc``:
    2 for a bad command line, 130 for an interrupt, 1 otherwise. Errors of bad input (values,
    files, the checks of dockingrl's own code) say their message; anything else is a bug and
    says so."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, UsageError):
        return f"{text} (see {exc.prog or f'dockingrl {command}'} --help)", 2
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted", 130
    if isinstance(exc, (ValueError, OSError)) or (
        isinstance(exc, RuntimeError) and _raised_by_dockingrl(exc)
    ):
        return text, 1
    if len(text) > 300:
        text = text[:297] + "..."
    gist = f"{type(exc).__name__}: {text}" if text != type(exc).__name__ else text
    return f"{gist} (unexpected: run with --debug for the traceback)", 1


def main(argv: list[str] | None = None) -> int:
    """Run ``dockingrl`` with ``argv`` (default: the process's arguments) and return its exit
    status. An error prints one line on stderr (with ``--debug``: its traceback) and raises
    :class:`CommandFailed`, a ``SystemExit`` with the status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    set_command_line(argv)
    debug, command = "--debug" in argv, None
    try:
        first_word = next((word for word in argv if not word.startswith("-")), None)
        args, extra = build_parser(first_word).parse_known_args(argv)
        debug, command = args.debug, args.command
        if extra:
            raise UsageError(f"unrecognized arguments: {' '.join(extra)}")
        return args.func(args)
    except BrokenPipeError:
        # the reader of stdout went away (`dockingrl recipes | head -1`): stop quietly, as a
        # pipe's writer does, and keep the interpreter's last flush from failing again
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):  # a stdout without a file descriptor
            pass
        return 128 + 13  # killed by SIGPIPE, as the shell reports it
    except BaseException as exc:
        if isinstance(exc, SystemExit) and not isinstance(exc.code, str):
            raise
        if debug:
            traceback.print_exc()
        line, code = error_line(exc, command)
        print(f"dockingrl: error: {line}", file=sys.stderr)
        raise CommandFailed(f"dockingrl: error: {line}", code) from None


if __name__ == "__main__":
    raise SystemExit(main())
