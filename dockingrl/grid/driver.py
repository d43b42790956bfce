"""The Ray driver of a grid: starts the unfinished trials as Ray tasks, as many at once as the
CPUs allow, collects the finished ones, starts again the ones whose worker died (after a pause
that lets the machine recover) and stops the running ones on SIGTERM or SIGINT."""

from __future__ import annotations

import math
import os
import signal
import sys
import time
from dataclasses import dataclass
from typing import Any

from dockingrl.grid.files import Grid, Trial
from dockingrl.grid.folders import (
    collect_trial,
    finished_summary,
    finished_trial,
    progress,
    success_rate_text,
)
from dockingrl.grid.trial import run_trial

#: times a trial is started again after its worker process died (killed for memory, crashed,
#: its node lost); it resumes from its last checkpoint
WORKER_RETRIES = 3
#: seconds without starting any trial after a worker died, doubled at each further death
RETRY_PAUSE_S = 120.0
#: the longest such pause
MAX_RETRY_PAUSE_S = 3600.0


@dataclass
class _Running:
    trial: Trial
    started: float


def task_cpus(cpus: int, threads: int, limit: int) -> float:
    """Ray CPUs each of ``limit`` trials at once declares on ``cpus`` CPUs: its ``threads``,
    or, when more trials are asked for than the CPUs hold at that many threads each, an equal
    share of the CPUs (a fraction below one, whole CPUs above, as Ray takes them), so that
    they all run at once, sharing the cores."""
    if limit * threads <= cpus:
        return float(threads)
    share = cpus / limit
    return math.floor(share * 1000) / 1000 if share < 1 else float(math.floor(share))


def _estimate(trial: Trial, trials: list[Trial], summaries: dict[str, dict]) -> float:
    """Expected seconds of the trial: the mean of its recipe's finished trials of the grid
    with the same total (train and final evaluation; ``summaries`` by trial name), else the
    grid file's estimate."""
    seen = []
    for other in trials:
        if other.recipe != trial.recipe or other.overrides != trial.overrides:
            continue
        s = summaries.get(other.name)
        if s and "train_wall_clock_s" in s:
            seen.append(s["train_wall_clock_s"] + s.get("selection_wall_clock_s", 0.0))
    return 1.1 * sum(seen) / len(seen) if seen else trial.estimate_s


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
        max_concurrent: trials at once (default: the cluster's CPUs // ``grid.threads``); more
            than that share the CPUs (:func:`task_cpus`), each slower, and ``hours`` counts
            each trial's estimate that much longer.
        hours: if > 0, start only trials expected to end within this many hours of the grid's
            start (:func:`_estimate`); the others stay pending for the next run.
        view_every: seconds between two views of the grid.
        stop_after: if > 0, start no more trials after this many have ended in this call.
    """
    import ray

    grid.out.mkdir(parents=True, exist_ok=True)
    states: dict[str, str] = {}
    notes: dict[str, str] = {}
    summaries: dict[str, dict] = {}  # of the trials finished with the grid's config
    for trial in grid.trials:
        summary, refusal = finished_trial(grid, trial)
        if summary is not None and not refusal:
            summaries[trial.name] = summary
        states[trial.name] = "pending" if summary is None else "failed" if refusal else "finished"
        if refusal:  # a result of another config is neither counted nor overwritten
            notes[trial.name] = refusal
    for trial in grid.trials:  # finished in a run folder, not yet collected
        if states[trial.name] == "finished" and grid.collect:
            dest = grid.collect / trial.name
            if (
                not (dest / "summary.json").exists()
                and (grid.run_dir(trial) / "summary.json").exists()
            ):
                collect_trial(grid.run_dir(trial), dest)
    todo = [t for t in grid.trials if states[t.name] == "pending"]
    view = GridView(grid, view_every)
    if not todo:
        view.show(states, {}, notes, force=True)
        return states
    started_at = time.time()
    if address:
        ray.init(address=address, log_to_driver=False, configure_logging=False)
    else:
        # a local Ray's memory monitor kills Ray's own workers (the trials) when any process of
        # the machine uses most of its memory; leave such choices to the kernel's OOM killer,
        # which kills the process that takes the memory
        os.environ.setdefault("RAY_memory_monitor_refresh_ms", "0")
        ray.init(
            num_cpus=os.cpu_count(),
            include_dashboard=False,
            log_to_driver=False,
            configure_logging=False,
        )
    cpus = int(ray.cluster_resources().get("CPU", 1))
    limit = max_concurrent or max(1, cpus // grid.threads)
    # more trials at once than the CPUs hold share the cores, each slower by this factor
    slower = max(1.0, limit * grid.threads / cpus)
    # one process per trial: it runs (and its summary records) the code of its own start
    task = ray.remote(num_cpus=task_cpus(cpus, grid.threads, limit), max_retries=0, max_calls=1)(
        run_trial
    )
    running: dict[Any, _Running] = {}
    ended = 0
    deaths: dict[str, int] = {}
    hold_until = 0.0  # no trial starts before this time (a worker died)
    stop = {"signum": None, "stopping": False}

    def on_signal(signum, frame):
        if stop["stopping"]:
            raise KeyboardInterrupt(f"second {signal.Signals(signum).name}: stopping now")
        stop["signum"] = signum

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        while todo or running:
            while not stop["signum"] and todo and len(running) < limit:
                if time.time() < hold_until:
                    break
                if stop_after and ended + len(running) >= stop_after:
                    break
                left = hours * 3600 - (time.time() - started_at) if hours > 0 else float("inf")
                fits = [t for t in todo if slower * _estimate(t, grid.trials, summaries) <= left]
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
                if todo and not stop["signum"] and time.time() < hold_until:
                    time.sleep(min(hold_until - time.time(), 5.0))
                    continue
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
                    error = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
                    name = r.trial.name
                    deaths[name] = deaths.get(name, 0) + 1
                    if deaths[name] <= WORKER_RETRIES and not stop["signum"]:
                        pause = RETRY_PAUSE_S * 2 ** (sum(deaths.values()) - 1)
                        pause = min(pause, MAX_RETRY_PAUSE_S)
                        hold_until = max(hold_until, time.time() + pause)
                        todo.insert(0, r.trial)
                        states[name] = "pending"
                        notes[name] = (
                            f"worker died ({error[:100]}); again in {pause:.0f} s "
                            f"({deaths[name]}/{WORKER_RETRIES})"
                        )
                        view.show(states, running, notes, force=True)
                        continue
                    result = {"status": "failed", "error": error}
                states[r.trial.name] = result["status"]
                ended += 1
                if result["status"] == "finished":
                    if grid.collect:
                        collect_trial(grid.run_dir(r.trial), grid.collect / r.trial.name)
                    s = finished_summary(grid, r.trial) or {}
                    summaries[r.trial.name] = s
                    notes[r.trial.name] = f"success {success_rate_text(s)}"
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
    """Ask the running trials to checkpoint and stop: SIGTERM to the process that holds each
    run folder's lock (local trials); the others, and trials elsewhere, are cancelled by Ray."""
    import ray

    from dockingrl.training.run_folder import RunLock

    for ref, r in running.items():
        pid = RunLock.holder(grid.run_dir(r.trial)) if local else None
        if pid is not None:
            try:
                os.kill(pid, signal.SIGTERM)
                continue
            except OSError:
                pass
        ray.cancel(ref, force=True)


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
