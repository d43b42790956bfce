"""The command being run, as results and figures record it: set by the ``dockingrl`` command
line, read by the library functions that write a result's command and footer."""

from __future__ import annotations

import shlex
import sys
from collections.abc import Iterable
from pathlib import Path

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


def shorten_folders(command: str, folders: Iterable[str | Path], least: int = 4) -> str:
    """``command`` with each group of at least ``least`` arguments from ``folders`` that share a
    parent folder written once: ``PARENT/*`` where they are all of its subfolders (what the shell
    expands back), ``PARENT/<N folders>`` otherwise. For a figure's footer, where a grid's
    command would list every trial."""
    words = shlex.split(command)
    given = {str(Path(f)) for f in folders}
    groups: dict[Path, list[int]] = {}
    for i, word in enumerate(words):
        if str(Path(word)) in given:
            groups.setdefault(Path(word).parent, []).append(i)
    shown = [shlex.quote(w) for w in words]
    for parent, places in groups.items():
        if len(places) < least:
            continue
        named = {Path(words[i]).name for i in places}
        every = parent.is_dir() and named == {d.name for d in parent.iterdir() if d.is_dir()}
        tail = "/*" if every else f"/<{len(places)} folders>"
        shown[places[0]] = shlex.quote(str(parent)) + tail
        for i in places[1:]:
            shown[i] = ""
    return " ".join(w for w in shown if w)


def footer_text(extra: str = "", device: str | None = None) -> str:
    """A figure's footer: the command, the machine (and ``device``), and ``extra``."""
    from dockingrl.evaluation import describe_machine

    text = f"{command_line()}  |  {describe_machine(device)}"
    return f"{text}  |  {extra}" if extra else text
