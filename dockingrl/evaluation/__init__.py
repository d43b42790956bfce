"""Evaluation as in the paper's Tables 6-7 and Figures 9-10: success rate, time, reward, the
success map over ocean currents and chosen trajectories.

One module per concern: :mod:`~dockingrl.evaluation.episodes` runs a batch of episodes and
reads their outcomes, :mod:`~dockingrl.evaluation.metrics` turns outcomes into the tables'
metrics, :mod:`~dockingrl.evaluation.runs` holds the evaluations of the tables and figures and
:mod:`~dockingrl.evaluation.machine` names the machine they ran on.
"""

from dockingrl.evaluation.episodes import Policy, base_env, episode_record, run_episodes
from dockingrl.evaluation.machine import describe_machine
from dockingrl.evaluation.metrics import PAPER_RESULTS, summarize, table_row
from dockingrl.evaluation.runs import current_grid, evaluate, success_map, trajectories

__all__ = [
    "PAPER_RESULTS",
    "Policy",
    "base_env",
    "current_grid",
    "describe_machine",
    "episode_record",
    "evaluate",
    "run_episodes",
    "success_map",
    "summarize",
    "table_row",
    "trajectories",
]
