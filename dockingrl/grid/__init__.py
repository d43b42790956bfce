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

One module per concern: :mod:`~dockingrl.grid.files` reads a grid file,
:mod:`~dockingrl.grid.folders` reads a trial's state from its folders,
:mod:`~dockingrl.grid.trial` runs one trial in a Ray worker and :mod:`~dockingrl.grid.driver`
runs the grid on Ray and shows it while it runs.
"""

from dockingrl.grid.driver import run_grid
from dockingrl.grid.files import Grid, Trial, grid_names, load_grid, select_trials
from dockingrl.grid.folders import (
    collect_trial,
    finished_summary,
    finished_trial,
    progress,
)
from dockingrl.grid.trial import run_trial

__all__ = [
    "Grid",
    "Trial",
    "collect_trial",
    "finished_summary",
    "finished_trial",
    "grid_names",
    "load_grid",
    "progress",
    "run_grid",
    "run_trial",
    "select_trials",
]
