"""Periodic success rates of several training runs in one figure, and their table as JSON.

Usage: ``python scripts/compare_curves.py RUN_DIR [RUN_DIR ...] --out PREFIX [--key KEY]``

Each ``RUN_DIR`` holds a ``curves.csv`` (``dockingrl train``); ``--labels`` names them in the
legend (default: the folder names). Writes ``PREFIX.png`` and ``PREFIX.json`` (the curves, the
command and the runs' commands where their ``summary.json`` or ``config.json`` has them).
``--from-table TABLE.json`` draws the figure again from such a table, when its run folders are
gone (the curves, labels, title and machine of the runs are the table's). The figure's footer
and ``drawn`` in the JSON name the command, the machine it ran on and its wall-clock.
"""

from __future__ import annotations

import argparse
import json
import shlex
import time
from pathlib import Path

from dockingrl.evaluation import describe_machine
from dockingrl.io import atomic_write, write_json
from dockingrl.provenance import script_command
from dockingrl.training import read_curves


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="*", help="run folders with a curves.csv")
    parser.add_argument(
        "--from-table", metavar="TABLE", help="draw from a table this script wrote, not runs"
    )
    parser.add_argument("--out", required=True, help="output prefix (PREFIX.png, PREFIX.json)")
    parser.add_argument("--labels", nargs="+", help="legend labels, one per run")
    parser.add_argument("--key", default="eval/success_rate", help="curve to compare")
    parser.add_argument("--title", default="", help="figure title")
    parser.add_argument(
        "--machine", default="", help="where the runs trained (default: each run's summary)"
    )
    args = parser.parse_args(argv)
    started = time.perf_counter()
    if bool(args.runs) == bool(args.from_table):
        parser.error("give run folders or --from-table, not both or neither")
    if args.from_table:
        curves, machine, key, title, read_command = from_table(parser, args.from_table)
    else:
        curves, machine = from_runs(parser, args)
        key, title = args.key, args.title

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for label, curve in curves.items():
        steps, values = zip(*curve["points"], strict=True)
        seconds = curve["train_wall_clock_s"]
        spent = f", {seconds:.0f} s" if seconds is not None else ""
        legend = f"{label} ({curve['frames'] / 1e3:.0f} k steps{spent})"
        ax.plot([s / 1e3 for s in steps], values, marker=".", label=legend)
    ax.set_xlabel("env steps (thousands)")
    ax.set_ylabel(key)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    command = script_command("compare_curves.py", argv)
    # the wall-clock from the start to the footer (saving the figure follows)
    drawn = {"command": command, "machine": describe_machine()}
    drawn["wall_clock_s"] = time.perf_counter() - started
    fig.text(
        0.01,
        0.005,
        f"{command}  |  runs on: {machine}  |  drawn on {drawn['machine']} "
        f"in {drawn['wall_clock_s']:.2f} s",
        fontsize=6,
        wrap=True,
    )
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    prefix = Path(args.out)
    prefix.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(prefix.with_suffix(".png"), lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)
    # a table drawn again keeps the command that read the runs; ``drawn`` says what drew it
    made_by = read_command if args.from_table else command
    table = {"command": made_by, "machine": machine, "key": key, "title": title, "runs": curves}
    write_json(prefix.with_suffix(".json"), {**table, "drawn": drawn})
    return 0


def from_table(parser: argparse.ArgumentParser, path: str) -> tuple[dict, str, str, str, str]:
    """The curves, machine, key and title of a table this script wrote, and the command that
    read its runs."""
    try:
        table = json.loads(Path(path).read_text())
        curves, machine, key, command = (table[k] for k in ("runs", "machine", "key", "command"))
        for label, curve in curves.items():
            if not curve["points"] or "frames" not in curve or "train_wall_clock_s" not in curve:
                raise ValueError(f"run {label!r} has no points, frames or wall-clock")
    except (OSError, ValueError, KeyError, TypeError) as err:
        parser.error(f"--from-table {path}: not a table of compare_curves.py ({err})")
    return curves, machine, key, table.get("title") or title_from_command(command), command


def title_from_command(command: str) -> str:
    """The ``--title`` of a recorded command (tables written before ``title`` was kept)."""
    words = shlex.split(command)
    return words[words.index("--title") + 1] if "--title" in words[:-1] else ""


def from_runs(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[dict, str]:
    """The curves of the run folders, and the machines they trained on."""
    labels = args.labels or [Path(r).name for r in args.runs]
    if len(labels) != len(args.runs):
        parser.error("give one label per run")
    curves = {}
    for run, label in zip(args.runs, labels, strict=True):
        run_curves = read_curves(run)
        points = run_curves.get(args.key)
        if not points:
            parser.error(f"{run}: no {args.key!r} in its curves.csv")
        summary = Path(run) / "summary.json"
        elapsed = run_curves.get("time/elapsed_s", [(points[-1][0], None)])[-1]
        curves[label] = {
            "run": run,
            "frames": elapsed[0],
            "train_wall_clock_s": elapsed[1],
            "points": points,
            "summary": json.loads(summary.read_text()) if summary.exists() else None,
            "config": json.loads((Path(run) / "config.json").read_text()),
        }

    machine = args.machine or "; ".join(
        sorted({c["summary"]["machine"] for c in curves.values() if c["summary"]})
    )
    return curves, machine


if __name__ == "__main__":
    raise SystemExit(main())
