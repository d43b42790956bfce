"""A run's folder: its lock, its default name and the code version it records."""

from __future__ import annotations

import os
import time
from pathlib import Path

from dockingrl.agents.config import TrainConfig


def default_run_name(cfg: TrainConfig) -> str:
    return f"dockingrl__{cfg.algo}__{cfg.scenario}__{cfg.seed}__{int(time.time())}"


class RunInUse(RuntimeError):
    """Another process is training in the run folder."""


class RunLock:
    """An exclusive lock on a run folder (``run.lock``, ``flock``) for as long as a process
    trains in it; the operating system releases it when the process dies, however it dies."""

    def __init__(self, run_dir: Path) -> None:
        self.path = Path(run_dir) / "run.lock"
        self._file = None

    def __enter__(self) -> RunLock:
        import fcntl

        self._file = self.path.open("a")
        try:
            fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._file.close()
            raise RunInUse(f"{self.path.parent} is in use by another training process") from None
        self._file.truncate(0)
        self._file.write(f"{os.getpid()}\n")
        self._file.flush()
        return self

    def __exit__(self, *exc) -> None:
        self._file.close()

    @staticmethod
    def holder(run_dir: Path) -> int | None:
        """The process that trains in ``run_dir`` now, or None: the PID in ``run.lock`` only
        while that lock is held (a free lock's PID is of a process that has ended, and the
        number may since name another)."""
        import fcntl

        try:
            with (Path(run_dir) / "run.lock").open() as f:
                try:
                    fcntl.flock(f, fcntl.LOCK_SH | fcntl.LOCK_NB)
                except BlockingIOError:
                    text = f.read().strip()
                    return int(text.splitlines()[-1]) if text else None
                return None  # nobody holds it (closing the file releases the shared lock)
        except (OSError, ValueError):
            return None


def code_version() -> dict:
    """The git commit of the dockingrl source that runs, and whether the package's tracked
    files differ from it (``dirty``; results and docs do not count); ``commit`` is None outside
    a git checkout."""
    import subprocess

    root = Path(__file__).resolve().parents[2]
    try:

        def git(*args: str) -> str:
            return subprocess.run(
                ["git", "-C", str(root), *args], capture_output=True, text=True, check=True
            ).stdout.strip()

        return {
            "commit": git("rev-parse", "HEAD"),
            "dirty": bool(git("status", "--porcelain", "-uno", "--", "dockingrl")),
        }
    except (OSError, subprocess.CalledProcessError):
        return {"commit": None, "dirty": None}
