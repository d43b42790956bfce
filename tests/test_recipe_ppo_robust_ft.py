"""The ``ppo-robust-ft`` recipe: what it changes from its first stage ``ppo-fast-follow``, a
smoke run of the two stages, and that the committed runs of ``results/stress/ppo_robust_ft/``
are the two stages' configs, each fine-tune from the committed first stage of its seed."""

import json
from pathlib import Path

import pytest
from helpers import check_committed_run, recipe_changes
from test_recipes import TINY, TINY_ALGO

from dockingrl.cli import main
from dockingrl.recipes import load_recipe

RESULTS = Path(__file__).resolve().parents[1] / "results" / "stress" / "ppo_robust_ft"
#: where a run went and the run it started from
RUN_FIELDS = {"out", "run_name", "init_from"}


def test_it_fine_tunes_ppo_fast_follow_at_l5_with_the_gated_estimating_filter():
    recipe = load_recipe("ppo-robust-ft")
    assert (recipe.algo, recipe.first_stage) == ("ppo", "ppo-fast-follow")
    assert recipe_changes("ppo-robust-ft", "ppo-fast-follow") == {
        "total_steps": 1_500_000,
        "lr": 1e-4,
        "train_level": "L5",
        "compensate_latency": True,
        "estimate_current": True,
        "filter_gate": 13.816,
    }


def test_the_second_stage_fine_tunes_a_filtered_first_stage_at_l5(tmp_path, short_episodes):
    tiny = [*TINY, *TINY_ALGO["ppo"], "--out", str(tmp_path)]
    tiny[tiny.index("--checkpoint-every") + 1] = "800"
    for scenario in ("filtered", "compound"):
        argv = ["train", "--recipe", "ppo-fast-follow", "--scenario", scenario]
        assert main([*argv, "--run-name", scenario, *tiny]) == 0
    argv = ["train", "--recipe", "ppo-robust-ft", "--scenario", "filtered", "--init-from"]
    # a first stage that observed another scenario has other networks
    with pytest.raises(SystemExit, match="not this run's .* or a run of recipe ppo-fast-follow$"):
        main([*argv, str(tmp_path / "compound"), "--run-name", "x", *tiny])
    assert main([*argv, str(tmp_path / "filtered"), "--run-name", "ft", *tiny]) == 0
    config = json.loads((tmp_path / "ft" / "config.json").read_text())
    assert (config["train_level"], config["filter_gate"]) == ("L5", 13.816)
    assert (tmp_path / "ft" / "policy.pt").is_file()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_committed_stages_are_the_recipes(seed):
    first = RESULTS / f"ppo_ff_filtered_s{seed}"
    check_committed_run(first, "ppo-fast-follow", RUN_FIELDS, scenario="filtered", seed=seed)
    fine = RESULTS / f"ppo_robust_ft_s{seed}"
    run = check_committed_run(fine, "ppo-robust-ft", RUN_FIELDS, scenario="filtered", seed=seed)
    # each fine-tune started from the first stage of its seed beside it
    assert Path(run["init_from"]).name == first.name
    for folder in (first, fine):
        ladder = json.loads((folder / "stress.json").read_text())
        assert Path(ladder["policy"]).parent.name == folder.name
        assert [row["name"] for row in ladder["levels"]] == ["L0", "L1", "L2", "L3", "L4", "L5"]
