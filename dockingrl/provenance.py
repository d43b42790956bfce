"""The command being run, as results and figures record it: set by the ``dockingrl`` command
line, read by the library functions that write a result's command and footer."""

from __future__ import annotations

import shlex

_ARGV: list[str] = []


def set_command_line(argv: list[str]) -> None:
    """Record ``argv`` (the arguments after ``dockingrl``) as the command being run."""
    _ARGV[:] = argv


def command_line() -> str:
    """The command being run, as a user would type it."""
    return shlex.join(["dockingrl", *_ARGV])


def footer_text(extra: str = "", device: str | None = None) -> str:
    """A figure's footer: the command, the machine (and ``device``), and ``extra``."""
    from dockingrl.evaluation import describe_machine

    text = f"{command_line()}  |  {describe_machine(device)}"
    return f"{text}  |  {extra}" if extra else text
