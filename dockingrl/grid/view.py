"""The live view of a running grid."""

from __future__ import annotations

import sys
import time

from dockingrl.grid.files import Grid
from dockingrl.grid.folders import progress


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
