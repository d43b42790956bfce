"""The command being run, as results and figures record it: set by the ``dockingrl`` command
line, read by the library functions that write a result's command and footer."""

from __future__ import annotations

import shlex
import sys

_ARGV: list[str] = []


def set_command_line(argv: list[str]) -> None:
    """Record ``argv`` (the arguments after ``dockingrl``) as the command being run."""
    _ARGV[:] = argv


def command_line() -> str:
    """The command being run, as a user would type it."""
    return shlex.join(["dockingrl", *_ARGV])


def script_command(script: str, argv: list[str] | None = None) -> str:
    """A script's command line as a user would type it: ``python scripts/SCRIPT ARGS``, where
    ARGS is ``argv`` or, when ``argv`` is None, the arguments the process was started with."""
    args = sys.argv[1:] if argv is None else argv
    return shlex.join(["python", f"scripts/{script}", *args])


def footer_text(extra: str = "", device: str | None = None) -> str:
    """A figure's footer: the command, the machine (and ``device``), and ``extra``."""
    from dockingrl.evaluation import describe_machine

    text = f"{command_line()}  |  {describe_machine(device)}"
    return f"{text}  |  {extra}" if extra else text
