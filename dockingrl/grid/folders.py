"""The state of a trial, from its run folder and its ``collect`` folder: finished or not, how
far it has come, whether its saved config is the grid's, and the copy of a finished trial's
small files."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from dockingrl.agents.config_diff import saved_differs
from dockingrl.grid.files import Grid, Trial
from dockingrl.io import fsync_path, sync_tree

#: a finished trial's files that ``collect`` keeps (small; the run folder keeps the rest)
COLLECTED = ("config.json", "summary.json", "eval.json", "curves.csv", "policy.pt")


def read_json(path: Path) -> dict | None:
    """The JSON object in ``path``; None where the file is missing, damaged (a torn write) or
    holds something else than an object."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def finished_trial(grid: Grid, trial: Trial) -> tuple[dict | None, str]:
    """The ``summary.json`` of the trial if it finished (in its run folder or ``collect``),
    and, where that run's saved config differs from the one the grid asks for now
    (:func:`~dockingrl.agents.config_diff.config_mismatch`), the one-line refusal of its
    folder ("" otherwise)."""
    for folder in (grid.run_dir(trial), grid.collect and grid.collect / trial.name):
        if folder and (summary := read_json(folder / "summary.json")) is not None:
            changed = saved_config_differs(grid, trial, folder)
            return summary, another_config(folder, changed) if changed else ""
    return None, ""


def finished_summary(grid: Grid, trial: Trial) -> dict | None:
    """The ``summary.json`` of the trial if it finished with the grid's config."""
    summary, refusal = finished_trial(grid, trial)
    return None if refusal else summary


def success_rate_text(summary: dict) -> str:
    """``"98.2 %"`` from a trial's summary, ``"unknown"`` where it holds no number."""
    rate = summary.get("success_rate")
    ok = isinstance(rate, (int, float)) and not isinstance(rate, bool)
    return f"{rate:.1f} %" if ok else "unknown"


def saved_config_differs(grid: Grid, trial: Trial, folder: Path) -> list[str]:
    """The fields in which the config saved in ``folder`` differs from the trial's (none
    where the folder holds no config)."""
    saved = read_json(folder / "config.json")
    if saved is None:
        return []
    return saved_differs(saved, trial.config(grid.out, grid.threads))


def another_config(folder: Path, changed: list[str]) -> str:
    """The one-line refusal of a folder that holds a run of another config."""
    return (
        f"{folder} holds a run of another config ({', '.join(changed)} differ): move it away "
        "or name the changed recipe anew"
    )


def progress(run_dir: Path) -> dict:
    """What a run folder shows of a trial under way: env steps and the latest periodic
    evaluation's success rate, from the end of its ``curves.csv``."""
    path = run_dir / "curves.csv"
    out: dict = {"steps": 0, "success": None}
    try:
        with path.open("rb") as f:
            f.seek(max(0, path.stat().st_size - 16384))
            lines = f.read().decode(errors="replace").splitlines()[1:]
    except OSError:
        return out
    for line in lines:
        parts = line.split(",")
        if len(parts) != 3 or not parts[0].isdigit():
            continue
        out["steps"] = max(out["steps"], int(parts[0]))
        if parts[1] == "eval/success_rate":
            out["success"] = float(parts[2])
    return out


def collect_trial(run_dir: Path, dest: Path) -> None:
    """Copy a finished trial's :data:`COLLECTED` files into ``dest``, whole or not at all (a
    sibling folder, then one rename)."""
    tmp = dest.with_name(dest.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in COLLECTED:
        if (run_dir / name).exists():
            shutil.copy2(run_dir / name, tmp / name)
    sync_tree(tmp)
    shutil.rmtree(dest, ignore_errors=True)
    tmp.rename(dest)
    fsync_path(dest.parent)  # the rename
