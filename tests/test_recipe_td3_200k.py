"""The ``td3-200k`` recipe: what it changes from ``td3``, that the committed runs of
``results/agents/td3_200k/`` are its config (its smoke run is ``test_recipes``'s, with every
recipe's)."""

from pathlib import Path

import pytest
from helpers import check_committed_run, recipe_changes

from dockingrl.recipes import load_recipe, recipe_names

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "results" / "agents" / "td3_200k"
#: where a run went and what it logged to, and the recipe named on its command line: the runs
#: were made with ``--recipe td3`` and the options ``td3-200k`` now sets
RUN_FIELDS = {"out", "run_name", "logger", "recipe"}


def test_td3_200k_is_td3_with_one_update_per_env_step_and_layer_normed_critics():
    assert "td3-200k" in recipe_names()
    assert recipe_changes("td3-200k", "td3") == {
        "total_steps": 200_000,
        "updates_per_step": 1.0,
        "critic_layer_norm": True,
        "fast_update": True,
        "eval_every": 10_000,
        "threads": 1,
    }
    fast = load_recipe("td3-200k").make_config()
    assert (fast.algo, fast.recipe) == ("td3", "td3-200k")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_committed_runs_are_the_recipe(seed):
    check_committed_run(
        RUNS / f"seed{seed}", "td3-200k", RUN_FIELDS, scenario="compound", seed=seed
    )
