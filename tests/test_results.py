"""The committed results: at most 20 MB in all, every JSON file whole, and every trial of a
grid trained with its recipe as the recipe file now gives it."""

import json
from pathlib import Path

import pytest

from dockingrl.agents.layout import saved_config
from dockingrl.recipes import load_recipe, recipe_names

RESULTS = Path(__file__).resolve().parents[1] / "results"
MAX_BYTES = 20 * 2**20


def test_the_results_fit_in_20_mb():
    size = sum(p.stat().st_size for p in RESULTS.rglob("*") if p.is_file())
    assert size <= MAX_BYTES, f"results/ holds {size / 2**20:.1f} MB"


def test_there_are_results_to_check():
    """The parametrised checks below would only be skipped over an empty results/."""
    assert any(RESULTS.rglob("*.json"))
    assert any(RESULTS.glob("*/trials/*/config.json"))


@pytest.mark.parametrize(
    "path", sorted(RESULTS.rglob("*.json")), ids=lambda p: str(p.relative_to(RESULTS))
)
def test_a_result_file_is_whole_json(path):
    json.loads(path.read_text())


#: fields a grid sets for all its trials (how a run is carried out, not what it learns)
RUN_FIELDS = {"threads", "logger", "final_eval_episodes", "eval_episodes", "out", "run_name"}

TRIALS = sorted(p for p in RESULTS.glob("*/trials/*") if (p / "config.json").is_file())


@pytest.mark.parametrize("trial", TRIALS, ids=lambda p: str(p.relative_to(RESULTS)))
def test_a_trial_agrees_with_its_recipe(trial):
    config = json.loads((trial / "config.json").read_text())
    recipe_name, scenario, seed = trial.name.split("__")
    assert config["recipe"] == recipe_name in recipe_names()
    assert (config["scenario"], f"s{config['seed']}") == (scenario, seed)
    recipe = load_recipe(recipe_name)
    # a field newer than the trial is read as its default, as loading its policy does
    config = {**saved_config(config).to_dict(), **config}
    made = json.loads(
        json.dumps(recipe.make_config(scenario=scenario, seed=config["seed"]).to_dict())
    )
    differ = {
        k: (config.get(k), made[k])
        for k in made
        if k not in RUN_FIELDS and config.get(k) != made[k]
    }
    assert not differ, differ
