"""The ``sac-200k`` recipe: what it changes from ``sac-ln``, that the committed runs of
``results/agents/sac_200k/`` are its config (its smoke run is ``test_recipes``'s, with every
recipe's)."""

import json
from pathlib import Path

import pytest
from helpers import check_committed_run, recipe_changes

from dockingrl.recipes import load_recipe, recipe_names

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "results" / "agents" / "sac_200k"
#: where a run went and what it logged to, and the recipe named on its command line: the runs
#: were made with ``--recipe sac-ln`` and the options ``sac-200k`` now sets
RUN_FIELDS = {"out", "run_name", "logger", "recipe"}


def test_sac_200k_is_sac_ln_with_two_updates_per_env_step_for_200k_env_steps():
    assert "sac-200k" in recipe_names()
    assert recipe_changes("sac-200k", "sac-ln") == {
        "total_steps": 200_000,
        "updates_per_step": 2.0,
        "fast_update": True,
    }
    cfg = load_recipe("sac-200k").make_config()
    assert (cfg.algo, cfg.recipe, cfg.critic_layer_norm) == ("sac", "sac-200k", True)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_committed_runs_are_the_recipe(seed):
    run = RUNS / f"seed{seed}"
    check_committed_run(run, "sac-200k", RUN_FIELDS, scenario="compound", seed=seed)
    assert json.loads((run / "eval_2000" / "eval.json").read_text())["episodes"] == 2000
