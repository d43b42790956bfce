"""The ``sac-200k-reset`` recipe: what it changes from ``sac-200k``, that the committed runs of
``results/agents/sac_200k_reset/`` are its config (its smoke run is ``test_recipes``'s, with
every recipe's)."""

import json
from pathlib import Path

import pytest
from helpers import check_committed_run, recipe_changes

from dockingrl.recipes import load_recipe, recipe_names

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "results" / "agents" / "sac_200k_reset"
#: where a run went and what it logged to, and the recipe named on its command line: the runs
#: were made with ``--recipe sac-200k --reset-every 50000``
RUN_FIELDS = {"out", "run_name", "logger", "recipe"}


def test_sac_200k_reset_is_sac_200k_with_resets_every_50k_env_steps():
    assert "sac-200k-reset" in recipe_names()
    assert recipe_changes("sac-200k-reset", "sac-200k") == {"reset_every": 50_000}
    cfg = load_recipe("sac-200k-reset").make_config()
    assert (cfg.algo, cfg.recipe, cfg.total_steps, cfg.actor_average) == (
        "sac",
        "sac-200k-reset",
        200_000,
        0.0,
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_the_committed_runs_are_the_recipe(seed):
    run = RUNS / f"seed{seed}"
    check_committed_run(run, "sac-200k-reset", RUN_FIELDS, scenario="compound", seed=seed)
    final = json.loads((run / "eval_2000" / "eval.json").read_text())
    assert final["episodes"] == 2000 and final["success_rate"] >= 99.0
