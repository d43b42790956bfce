"""Command-line argument checking for ``dockingrl``: a parser whose errors are one line, the
error that a command raises for a command line it cannot run, argparse types that refuse
out-of-range numbers as usage errors, and the policy that ``--policy`` and its options name."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from dockingrl.env.bounds import MAX_BATCH, MAX_SEED


class UsageError(ValueError):
    """A command line that cannot run as given (exit status 2); ``prog`` names the command
    whose ``--help`` explains it."""

    def __init__(self, message: str, prog: str | None = None) -> None:
        super().__init__(message)
        self.prog = prog


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` that raises :class:`UsageError` instead of printing its usage and
    exiting, so that ``dockingrl`` reports every error the same way, in one line."""

    def error(self, message: str):
        raise UsageError(message, self.prog)


def integer(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """An argparse type: an integer ``>= minimum`` (and ``<= maximum`` where given)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}, got {text!r}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"must be an integer <= {maximum}, got {text!r}")
        return value

    return parse


def number(*, above: float | None = None, minimum: float | None = None) -> Callable[[str], float]:
    """An argparse type: a finite number, ``> above`` and ``>= minimum`` where given."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
        if above is not None and not value > above:
            raise argparse.ArgumentTypeError(f"must be > {above:g}, got {text!r}")
        if minimum is not None and value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum:g}, got {text!r}")
        return value

    return parse


#: the usual argparse types: a count of at least 1, a count of at least 0, a seed, a finite
#: number, a positive one and a non-negative one
COUNT = integer(1)
EPISODES = integer(1, MAX_BATCH)  # an evaluation's episodes run as one batch
NON_NEGATIVE_INT = integer(0)
SEED = integer(0, MAX_SEED)
FINITE = number()
POSITIVE = number(above=0.0)
NON_NEGATIVE = number(minimum=0.0)


def output_folder(text: str) -> str:
    """An argparse type: a folder to write into, refused up front (not after the work) when it,
    or a folder above it, is a file."""
    from pathlib import Path

    from dockingrl.io import file_in_the_way

    blocker = file_in_the_way(text)
    if blocker is not None:
        what = "" if blocker == Path(text) else f" ({blocker} is a file)"
        raise argparse.ArgumentTypeError(f"{text}: not a folder{what}")
    return text


def results_folder(text: str) -> str:
    """:func:`output_folder` that is not a training run's folder (its ``config.json`` beside a
    ``summary.json`` or ``checkpoints/``), whose ``eval.json`` and ``curves.csv`` are the run's
    own: a command that writes files of those names is refused there up front."""
    from pathlib import Path

    text = output_folder(text)
    path = Path(text)
    if (path / "config.json").is_file() and (
        (path / "summary.json").is_file() or (path / "checkpoints").is_dir()
    ):
        raise argparse.ArgumentTypeError(
            f"{text}: a training run's folder, whose eval.json and curves.csv are the run's "
            "own; give another folder"
        )
    return text


def output_file(text: str) -> str:
    """An argparse type: a file to write, refused up front (not after the work) when it is a
    folder or a folder above it is a file."""
    from pathlib import Path

    from dockingrl.io import file_in_the_way

    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: a folder; give a file's path")
    blocker = file_in_the_way(path.parent)
    if blocker is not None:
        raise argparse.ArgumentTypeError(f"{text}: cannot be written ({blocker} is a file)")
    return text


def csv_file(text: str) -> str:
    """An argparse type: a CSV file to write (:func:`output_file`, whose name ends in .csv)."""
    from pathlib import Path

    output_file(text)
    if Path(text).suffix.lower() != ".csv":
        raise argparse.ArgumentTypeError(f"{text}: a CSV file; its name must end in .csv")
    return text


def distinct_output(out: str, **inputs: str) -> None:
    """``UsageError`` when the file ``out`` would be written over one of the command's
    ``inputs`` (option name -> path): a replay's commands over its log, a log over its policy."""
    from pathlib import Path

    for option, path in inputs.items():
        if Path(out).resolve() == Path(path).resolve():
            flag = option.replace("_", "-")
            raise UsageError(f"--out {out} is the --{flag} file; write to another")


def existing_file(text: str) -> str:
    """An argparse type: a file to read, refused up front when it is missing or a folder."""
    from pathlib import Path

    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: a folder, not a file")
    if not path.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    return text


def filter_params_file(text: str) -> str:
    """An argparse type: a learned Q/R file (``dockingrl learn-filter``) to read, or ``none``
    for Table 1's hand-tuned filter."""
    return text if text == "none" else existing_file(text)


def torch_device(text: str) -> str:
    """An argparse type: a torch device this machine has (``cpu``, ``cuda``, ``cuda:1``)."""
    from dockingrl.env.checks import available_device

    try:
        return available_device(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def policy_from_args(args: argparse.Namespace) -> tuple:
    """The policy that ``--policy`` names (``--use-filter``, on ``--device``; torch set to
    ``--threads`` threads) and the scenario to run it in: ``--scenario``, else the one it was
    trained in, else ``noise``. Returns :func:`~dockingrl.policies.resolve_policy`'s ``(policy,
    name, scenario, options, trained)`` with that scenario."""
    import torch

    from dockingrl.evaluation.machine import note_shared_cores
    from dockingrl.policies import resolve_policy
    from dockingrl.scenarios import FILTERED_OBSERVATION_KEYS

    note_shared_cores(args.threads)
    torch.set_num_threads(args.threads)
    policy, name, trained_scenario, options, trained = resolve_policy(
        args.policy, use_filter=args.use_filter, device=args.device
    )
    scenario = args.scenario or trained_scenario or "noise"
    if args.use_filter:
        if name != "managed_surge":
            raise UsageError(
                "--use-filter is for --policy managed_surge (a trained policy "
                "reads what its scenario gives it)"
            )
        if scenario not in FILTERED_OBSERVATION_KEYS:
            raise UsageError(
                f"--use-filter needs a scenario that runs the EKF (filtered or "
                f"compound), not {scenario!r}"
            )
    return policy, name, scenario, options, trained
