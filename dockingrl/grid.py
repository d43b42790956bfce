"""Grids of training runs (recipes x scenarios x seeds) on Ray, resumable from their run folders.

A grid file (YAML; ``table6`` is shipped, see :func:`load_grid`) names the trials. Each trial
trains into its own run folder ``out/RECIPE__SCENARIO__sSEED`` with the checkpoints of
:func:`dockingrl.training.train`. The grid's state is nothing but those folders (and the
``collect`` folder that keeps each finished trial's small files): running the same grid again
after any interruption skips the finished trials, resumes the unfinished ones from their last
checkpoint and starts the others. There is no experiment state of Ray's to lose or to agree
with the folders.

Trials run as Ray tasks, each reserving ``threads`` CPUs: on the embedded local Ray by default,
on an existing cluster with ``address`` (every node needs dockingrl installed and ``out`` on a
shared file system).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import sys
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from dockingrl.scenarios import SCENARIOS

#: a finished trial's files that ``collect`` keeps (small; the run folder keeps the rest)
COLLECTED = ("config.json", "summary.json", "eval.json", "curves.csv", "policy.pt")
#: fields a trial's saved config may differ in from the grid's without being another trial
_HOW_NOT_WHAT = ("threads", "device", "out", "run_name", "logger", "wandb_online", "compile")
_GRID_KEYS = ("name", "out", "collect", "threads", "scenarios", "overrides", "groups")
_GROUP_KEYS = ("recipes", "scenarios", "seeds", "overrides", "estimate_s")


@dataclass(frozen=True)
class Trial:
    """One training run of a grid."""

    recipe: str
    scenario: str
    seed: int
    overrides: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)
    estimate_s: float = 0.0

    @property
    def name(self) -> str:
        return f"{self.recipe}__{self.scenario}__s{self.seed}"

    def config(self, out: Path, threads: int):
        """The trial's validated training config."""
        from dockingrl.recipes import load_recipe

        return load_recipe(self.recipe).make_config(
            scenario=self.scenario,
            seed=self.seed,
            threads=threads,
            out=str(out),
            run_name=self.name,
            **self.overrides,
        )


@dataclass
class Grid:
    """A grid file, resolved: where its runs go and its trials in the order they start."""

    name: str
    out: Path
    collect: Path | None
    threads: int
    trials: list[Trial]

    def run_dir(self, trial: Trial) -> Path:
        return self.out / trial.name


def grid_names() -> list[str]:
    """The grid files shipped with dockingrl."""
    root = resources.files("dockingrl.grids")
    return sorted(p.name[: -len(".yaml")] for p in root.iterdir() if p.name.endswith(".yaml"))


def load_grid(spec: str | Path, out: str | Path | None = None, collect: str | None = None) -> Grid:
    """The shipped grid named ``spec`` or the grid file at path ``spec``::

        name: table6
        out: runs/table6              # run folders (relative to the working directory)
        collect: results/table6/trials  # optional: each finished trial's small files
        threads: 1                    # torch threads (and Ray CPUs) per trial
        scenarios: [no_noise, noise, filtered, compound]
        overrides: {eval_episodes: 100}  # config fields for every trial
        groups:
          - recipes: [sac]
            seeds: [0, 1, 2]
            overrides: {total_steps: 500000}
            estimate_s: 7000          # expected seconds of one trial on one core

    Trials start seed by seed (every cell's seed 0 first), in the groups' order within a seed.
    ``out`` and ``collect`` override the file's. Every trial's config is built and validated
    here, so a bad grid fails before anything runs. Raises ``ValueError`` (one line)."""
    import yaml

    spec = str(spec)
    if spec in grid_names():
        text = resources.files("dockingrl.grids").joinpath(f"{spec}.yaml").read_text()
    elif Path(spec).is_file():
        text = Path(spec).read_text()
    else:
        raise ValueError(
            f"unknown grid {spec!r}: neither a grid name ({', '.join(grid_names())}) nor a file"
        )
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"grid {spec}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict) or not isinstance(data.get("groups"), list):
        raise ValueError(f"grid {spec}: expected a mapping with a list of groups")
    extra = sorted(set(data) - set(_GRID_KEYS))
    if extra:
        raise ValueError(f"grid {spec}: unknown key(s) {', '.join(map(str, extra))}")
    threads = data.get("threads", 1)
    if not isinstance(threads, int) or threads < 1:
        raise ValueError(f"grid {spec}: threads must be an integer >= 1 (got {threads!r})")
    base = data.get("overrides") or {}
    trials: list[tuple[int, int, Trial]] = []
    for g, group in enumerate(data["groups"]):
        if not isinstance(group, dict) or set(group) - set(_GROUP_KEYS):
            raise ValueError(
                f"grid {spec}: group {g} must be a mapping of {', '.join(_GROUP_KEYS)}"
            )
        scenarios = group.get("scenarios", data.get("scenarios", list(SCENARIOS)))
        for scenario in scenarios:
            if scenario not in SCENARIOS:
                raise ValueError(f"grid {spec}: unknown scenario {scenario!r}")
        seeds = group.get("seeds", [0])
        if not seeds or not all(isinstance(s, int) and s >= 0 for s in seeds):
            raise ValueError(f"grid {spec}: group {g}: seeds must be integers >= 0")
        for recipe in group.get("recipes") or []:
            for seed in seeds:
                for scenario in scenarios:
                    trial = Trial(
                        str(recipe),
                        scenario,
                        seed,
                        {**base, **(group.get("overrides") or {})},
                        float(group.get("estimate_s", 0.0)),
                    )
                    trials.append((seed, g, trial))
    names = [t.name for _, _, t in trials]
    if len(set(names)) != len(names):
        raise ValueError(f"grid {spec}: a trial appears twice")
    if not trials:
        raise ValueError(f"grid {spec}: no trials")
    grid = Grid(
        str(data.get("name") or Path(spec).stem),
        Path(out or data.get("out") or f"runs/{Path(spec).stem}"),
        Path(collect) if collect else (Path(data["collect"]) if data.get("collect") else None),
        threads,
        [t for _, _, t in sorted(trials, key=lambda x: (x[0], x[1]))],
    )
    for trial in grid.trials:
        try:
            trial.config(grid.out, threads)
        except ValueError as exc:
            raise ValueError(f"grid {spec}: trial {trial.name}: {exc}") from None
    return grid


# -- the state of a trial, from its folders ---------------------------------------------------
def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def finished_summary(grid: Grid, trial: Trial) -> dict | None:
    """The ``summary.json`` of the trial if it finished (in its run folder or ``collect``)."""
    for folder in (grid.run_dir(trial), grid.collect and grid.collect / trial.name):
        if folder and (summary := _read_json(folder / "summary.json")) is not None:
            return summary
    return None


def config_mismatch(saved: dict, wanted: dict) -> list[str]:
    """The fields (beyond where and how fast it runs) in which a saved config differs from
    the one the grid asks for now."""
    keys = (set(saved) | set(wanted)) - set(_HOW_NOT_WHAT)
    norm = {k: (list(v) if isinstance(v, tuple) else v) for k, v in wanted.items()}
    return sorted(k for k in keys if saved.get(k) != norm.get(k))


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
    shutil.rmtree(dest, ignore_errors=True)
    tmp.rename(dest)


# -- one trial, in a Ray worker --------------------------------------------------------------
def run_trial(trial: Trial, out: str, threads: int) -> dict:
    """Train ``trial`` to its end in ``out/NAME``: resumed from its checkpoint if its folder
    holds a run, else started; a finished one is left as it is. Waits while another process
    trains in the folder (a trial left running by a driver that was killed). Returns
    ``{"name", "status": finished | interrupted | failed, "error"}``."""
    import contextlib
    import traceback

    import torch

    from dockingrl.training import RunInUse, TrainingInterrupted, train

    torch.set_num_threads(threads)
    run_dir = Path(out) / trial.name
    run_dir.mkdir(parents=True, exist_ok=True)
    result = {"name": trial.name, "status": "finished", "error": ""}
    with (run_dir / "train.log").open("a") as log:
        with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            while True:
                try:
                    if (run_dir / "summary.json").exists():
                        return result
                    cfg = trial.config(Path(out), threads)
                    saved = _read_json(run_dir / "config.json")
                    if saved is not None:
                        changed = config_mismatch(saved, cfg.to_dict())
                        if changed:
                            raise ValueError(
                                f"{run_dir} holds a run of another config ({', '.join(changed)} "
                                "differ): move it away or name the changed recipe anew"
                            )
                        train(None, resume=run_dir, progress=False, command=_command(trial))
                    else:
                        train(cfg, progress=False, command=_command(trial))
                    return result
                except RunInUse:
                    time.sleep(5.0)
                except TrainingInterrupted as exc:
                    return {**result, "status": "interrupted", "error": str(exc)}
                except Exception as exc:  # reported by the driver; the other trials go on
                    traceback.print_exc()
                    return {**result, "status": "failed", "error": f"{type(exc).__name__}: {exc}"}


def _command(trial: Trial) -> str:
    return f"dockingrl grid (trial {trial.name})"


# -- the driver ------------------------------------------------------------------------------
@dataclass
class _Running:
    trial: Trial
    started: float


def _estimate(grid: Grid, trial: Trial) -> float:
    """Expected seconds of the trial: the mean of its recipe's finished trials of the grid
    with the same total (train and final evaluation), else the grid file's estimate."""
    seen = []
    for other in grid.trials:
        if other.recipe != trial.recipe or other.overrides != trial.overrides:
            continue
        s = finished_summary(grid, other)
        if s and "train_wall_clock_s" in s:
            seen.append(s["train_wall_clock_s"] + s.get("selection_wall_clock_s", 0.0))
    return 1.1 * sum(seen) / len(seen) if seen else trial.estimate_s


class GridView:
    """A few lines about the grid (counts, then one line per running or failed trial), printed
    when something changes and every ``every`` seconds; a terminal gets it redrawn in place."""

    def __init__(self, grid: Grid, every: float, stream=None) -> None:
        self.grid, self.every, self.stream = grid, every, stream or sys.stdout
        self.tty = self.stream.isatty()
        self._last, self._lines = 0.0, 0

    def show(self, states: dict[str, str], running: dict, notes: dict[str, str], force=False):
        now = time.time()
        if not force and now - self._last < self.every:
            return
        self._last = now
        counts: dict[str, int] = {}
        for s in states.values():
            counts[s] = counts.get(s, 0) + 1
        lines = [
            f"[{time.strftime('%H:%M:%S')}] grid {self.grid.name}: "
            + ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
        ]
        for r in running.values():
            p = progress(self.grid.run_dir(r.trial))
            total = r.trial.config(self.grid.out, self.grid.threads).total_steps
            success = "-" if p["success"] is None else f"{p['success']:.0f} %"
            lines.append(
                f"  running  {r.trial.name:<34} {p['steps']:>9,}/{total:,} steps  "
                f"success {success:>6}  {(now - r.started) / 60:5.1f} min"
            )
        shown = [n for n in notes if states.get(n) != "finished"]
        shown += [n for n in notes if states.get(n) == "finished"][-4:]
        for name in shown:
            note = notes[name]
            lines.append(f"  {states.get(name, ''):<8} {name:<34} {note}")
        if self.tty and self._lines:
            self.stream.write(f"\x1b[{self._lines}F\x1b[J")
        self.stream.write("\n".join(lines) + "\n")
        self.stream.flush()
        self._lines = len(lines) if self.tty else 0


def run_grid(
    grid: Grid,
    *,
    address: str | None = None,
    max_concurrent: int | None = None,
    hours: float = 0.0,
    view_every: float = 60.0,
    stop_after: int = 0,
) -> dict[str, str]:
    """Run the grid's unfinished trials on Ray and return each trial's state (``finished``,
    ``failed``, ``interrupted``, ``pending``).

    Args:
        address: an existing Ray cluster (``ray.init(address=...)``); None starts a local one.
        max_concurrent: trials at once (default: the cluster's CPUs // ``grid.threads``).
        hours: if > 0, start only trials expected to end within this many hours of the grid's
            start (:func:`_estimate`); the others stay pending for the next run.
        view_every: seconds between two views of the grid.
        stop_after: if > 0, start no more trials after this many have ended in this call.
    """
    import ray

    grid.out.mkdir(parents=True, exist_ok=True)
    states = {t.name: ("finished" if finished_summary(grid, t) else "pending") for t in grid.trials}
    for trial in grid.trials:  # finished in a run folder, not yet collected
        if states[trial.name] == "finished" and grid.collect:
            dest = grid.collect / trial.name
            if (
                not (dest / "summary.json").exists()
                and (grid.run_dir(trial) / "summary.json").exists()
            ):
                collect_trial(grid.run_dir(trial), dest)
    todo = [t for t in grid.trials if states[t.name] != "finished"]
    view = GridView(grid, view_every)
    notes: dict[str, str] = {}
    if not todo:
        view.show(states, {}, notes, force=True)
        return states
    started_at = time.time()
    if address:
        ray.init(address=address, log_to_driver=False, configure_logging=False)
    else:
        ray.init(
            num_cpus=os.cpu_count(),
            include_dashboard=False,
            log_to_driver=False,
            configure_logging=False,
        )
    cpus = int(ray.cluster_resources().get("CPU", 1))
    limit = max_concurrent or max(1, cpus // grid.threads)
    # one process per trial: it runs (and its summary records) the code of its own start
    task = ray.remote(num_cpus=grid.threads, max_retries=0, max_calls=1)(run_trial)
    running: dict[Any, _Running] = {}
    ended = 0
    stop = {"signum": None, "stopping": False}

    def on_signal(signum, frame):
        if stop["stopping"]:
            raise KeyboardInterrupt(f"second {signal.Signals(signum).name}: stopping now")
        stop["signum"] = signum

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        while todo or running:
            while not stop["signum"] and todo and len(running) < limit:
                if stop_after and ended + len(running) >= stop_after:
                    break
                left = hours * 3600 - (time.time() - started_at) if hours > 0 else float("inf")
                fits = [t for t in todo if _estimate(grid, t) <= left]
                if not fits:
                    break
                trial = fits[0]
                todo.remove(trial)
                ref = task.remote(trial, str(grid.out), grid.threads)
                running[ref] = _Running(trial, time.time())
                states[trial.name] = "running"
                notes.pop(trial.name, None)
                view.show(states, running, notes, force=True)
            if not running:
                break
            if stop["signum"] and not stop["stopping"]:
                stop["stopping"] = True
                print(
                    f"{signal.Signals(stop['signum']).name}: the running trials checkpoint and "
                    "stop (again to stop at once); run the same command to resume",
                    file=sys.stderr,
                    flush=True,
                )
                _stop_trials(grid, running, local=not address)
                todo.clear()
            ready, _ = ray.wait(list(running), num_returns=1, timeout=min(view_every, 5.0))
            for ref in ready:
                r = running.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:  # the worker died
                    result = {"status": "failed", "error": f"{type(exc).__name__}: {exc}"}
                states[r.trial.name] = result["status"]
                ended += 1
                if result["status"] == "finished":
                    if grid.collect:
                        collect_trial(grid.run_dir(r.trial), grid.collect / r.trial.name)
                    s = finished_summary(grid, r.trial) or {}
                    notes[r.trial.name] = f"success {s.get('success_rate', float('nan')):.1f} %"
                else:
                    notes[r.trial.name] = result["error"].splitlines()[0][:160]
                view.show(states, running, notes, force=True)
            view.show(states, running, notes)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        ray.shutdown()
    return states


def _stop_trials(grid: Grid, running: dict, local: bool) -> None:
    """Ask the running trials to checkpoint and stop: SIGTERM to the process named in each run
    folder's lock (local trials); trials elsewhere are cancelled by Ray."""
    import ray

    for ref, r in running.items():
        pid = _lock_pid(grid.run_dir(r.trial)) if local else None
        if pid is not None:
            try:
                os.kill(pid, signal.SIGTERM)
                continue
            except OSError:
                pass
        ray.cancel(ref, force=True)


def _lock_pid(run_dir: Path) -> int | None:
    try:
        text = (run_dir / "run.lock").read_text().strip()
        return int(text.splitlines()[-1]) if text else None
    except (OSError, ValueError):
        return None


__all__ = [
    "Grid",
    "Trial",
    "collect_trial",
    "finished_summary",
    "grid_names",
    "load_grid",
    "progress",
    "run_grid",
    "run_trial",
]
