"""How a run stops early: SIGTERM or SIGINT end it after its current batch and checkpoint."""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path


class TrainingInterrupted(Exception):
    """A run stopped by SIGTERM or SIGINT after checkpointing its last whole batch: nothing
    trained is lost, and ``--resume`` continues it."""

    def __init__(self, signum: int, frames: int, run_dir: Path) -> None:
        self.signum, self.frames, self.run_dir = signum, frames, run_dir
        super().__init__(
            f"stopped by {signal.Signals(signum).name} at {frames} env steps, checkpoint "
            f"written; continue with: dockingrl train --resume {run_dir}"
        )


class StopRequests:
    """While training (main thread only), SIGTERM and SIGINT ask the loop to stop after the
    current batch and checkpoint; a second signal interrupts at once (``KeyboardInterrupt``)."""

    SIGNALS = (signal.SIGTERM, signal.SIGINT)

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict = {}

    def _handler(self, signum, frame) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt(f"second {signal.Signals(signum).name}: stopping now")
        self.signum = signum
        print(
            f"\n{signal.Signals(signum).name}: stopping after this batch and its checkpoint "
            "(again to stop at once)",
            file=sys.stderr,
            flush=True,
        )

    def install(self) -> None:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handler)

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()
