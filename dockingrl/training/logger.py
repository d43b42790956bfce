"""What a run logs: ``curves.csv`` and the logger backend (wandb or CSV, ``logged.json``), and
the learning curve drawn from it."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from dockingrl.io import atomic_write, write_json


class RunLogger:
    """Namespaced scalars (``train/``, ``eval/``, ``losses/``, ``time/``) to a local
    ``curves.csv``, appended as they come, and to wandb (offline by default) or TorchRL's CSV
    logger.

    ``curves.csv`` is the record: a resumed run cuts it back to its checkpoint
    (:func:`drop_curves_after`). The backend receives the rows of ``curves.csv`` once
    each, in order: with ``buffered`` (a run that checkpoints), only when :meth:`flush` is
    called after a checkpoint and at the end, so that it never holds a step that a resumed run
    trains again; otherwise after every :meth:`log`. ``logged.json`` counts the rows the backend
    has; :meth:`sync` (on resume) rewrites the CSV backend's files from ``curves.csv`` and sends
    the rows it lacks."""

    def __init__(
        self,
        config: dict,
        kind: str,
        run_dir: Path,
        run_id: str,
        online: bool = False,
        *,
        buffered: bool = False,
    ) -> None:
        self.run_dir = run_dir
        self.curves = run_dir / "curves.csv"
        self.marker = run_dir / "logged.json"
        self.kind, self.buffered = kind, buffered
        self._pending: list[tuple[int, str, float]] = []
        self._sent = 0
        self.backend = None
        if kind == "wandb":
            from torchrl.record.loggers import WandbLogger

            self.backend = WandbLogger(
                exp_name=run_dir.name,
                offline=not online,
                save_dir=str(run_dir),
                id=run_id,
                project="dockingrl",
                config=config,
                resume="allow",
                log_env_packages=False,
            )
        elif kind == "csv":
            from torchrl.record.loggers import CSVLogger

            self.backend = CSVLogger(exp_name=run_dir.name, log_dir=str(run_dir / "csv"))
            self.backend.log_hparams(config)
        elif kind != "none":
            raise ValueError(f"unknown logger {kind!r}; valid: wandb, csv, none")

    def log(self, metrics: dict[str, float], step: int) -> None:
        rows = [(step, key, float(value)) for key, value in metrics.items()]
        new = not self.curves.exists()
        with self.curves.open("a", newline="") as f:
            writer = csv.writer(f)
            if new:
                writer.writerow(["step", "key", "value"])
            writer.writerows(rows)
        if self.backend is not None:
            self._pending.extend(rows)
            if not self.buffered:
                self.flush()

    def flush(self) -> None:
        """Send the backend the rows logged since the last flush, step by step; with
        ``buffered``, ``logged.json`` counts the rows sent after each step."""
        rows, self._pending = self._pending, []
        start = 0
        while start < len(rows):
            end = start
            while end < len(rows) and rows[end][0] == rows[start][0]:
                end += 1
            for step, key, value in rows[start:end]:
                self.backend.log_scalar(key, value, step=int(step))
            self._sent += end - start
            if self.buffered:
                write_json(self.marker, {"rows": self._sent})
            start = end

    def sync(self) -> None:
        """Make the backend hold the rows of ``curves.csv`` (cut back to the checkpoint on
        resume) once each: the CSV backend's files are written anew from it; another backend
        (wandb) is sent the rows that ``logged.json`` says it lacks."""
        if self.backend is None:
            return
        rows = curve_rows(self.curves)
        if self.kind == "csv":
            experiment = self.backend.experiment
            for handle in experiment.files.values():
                handle.close()
            experiment.files.clear()
            scalars = Path(experiment.log_dir) / "scalars"
            by_key: dict[str, str] = {}
            for step, key, value in rows:
                by_key[key] = by_key.get(key, "") + f"{step},{value}\n"
            for path in scalars.rglob("*.csv"):
                if path.relative_to(scalars).with_suffix("").as_posix() not in by_key:
                    path.unlink()
            for key, text in by_key.items():
                atomic_write(scalars / f"{key}.csv", lambda tmp, text=text: tmp.write_text(text))
            self._sent = len(rows)
            write_json(self.marker, {"rows": self._sent})
        else:
            try:
                self._sent = min(int(json.loads(self.marker.read_text())["rows"]), len(rows))
            except (OSError, ValueError, KeyError, TypeError):
                self._sent = 0
        self._pending = rows[self._sent :]
        self.flush()

    def finish(self, summary: dict) -> None:
        self.flush()
        if self.backend is not None and hasattr(self.backend, "experiment"):
            experiment = self.backend.experiment
            if hasattr(experiment, "summary"):
                experiment.summary.update(
                    {k: v for k, v in summary.items() if isinstance(v, (int, float, str))}
                )
            if hasattr(experiment, "finish"):
                experiment.finish()


def curve_rows(path: Path) -> list[tuple[int, str, float]]:
    """The ``(step, key, value)`` rows of a ``curves.csv`` whose writing finished: a last line
    without its newline (a write cut short by a kill or a full disk) and any line that does
    not read as a step, a key and a number are left out."""
    try:
        lines = path.read_text(errors="replace").split("\n")[1:-1]
    except FileNotFoundError:
        return []
    rows = []
    for row in csv.reader(lines):
        try:
            step, key, value = row
            rows.append((int(step), key, float(value)))
        except ValueError:
            continue
    return rows


def read_curves(run_dir: str | Path) -> dict[str, list[tuple[int, float]]]:
    """``curves.csv`` as ``{key: [(step, value), ...]}``."""
    curves: dict[str, list[tuple[int, float]]] = {}
    for step, key, value in curve_rows(Path(run_dir) / "curves.csv"):
        curves.setdefault(key, []).append((step, value))
    return curves


def drop_curves_after(run_dir: Path, frames: int, total_steps: int) -> None:
    """Forget what was logged after the checkpoint at ``frames``: those steps are trained
    again. A run resumed at its total (``total_steps``) only to end again (a new end-of-run
    choice) also forgets its final evaluation, which it logs again."""
    again = frames >= total_steps
    path = run_dir / "curves.csv"
    if not path.exists():
        return
    kept = [("step", "key", "value")] + [
        row
        for row in curve_rows(path)
        if row[0] < frames
        or (row[0] == frames and not (again and row[1].startswith("eval/final_")))
    ]

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="") as f:
            csv.writer(f).writerows(kept)

    atomic_write(path, write)


def plot_run(run_dir: str | Path) -> Path | None:
    """Learning curve of a run (Figures 6-8 style) from its ``curves.csv``."""
    from dockingrl.plots import plot_learning_curve

    run_dir = Path(run_dir)
    curves = read_curves(run_dir)
    if "eval/total_reward" not in curves:
        return None
    steps = [s for s, _ in curves["eval/total_reward"]]
    summary_path = run_dir / "summary.json"
    footer = ""
    if summary_path.exists():
        s = json.loads(summary_path.read_text())
        footer = (
            f"{s['command']}  |  {s['machine']}  |  train {s['train_wall_clock_s']:.0f} s, "
            f"final success {s['success_rate']:.1f} %"
        )
    return plot_learning_curve(
        steps,
        [v for _, v in curves["eval/total_reward"]],
        [v for _, v in curves["eval/episode_time_s"]],
        run_dir / "learning_curve.png",
        success=[v for _, v in curves["eval/success_rate"]],
        title=run_dir.name,
        footer=footer,
    )
