"""The ``td3-200k-robust-ft`` recipe: what it changes from its first stage ``td3-200k``, a smoke
run of the two stages, and that the committed runs of ``results/stress/td3_robust_ft/`` are the
two stages' configs, each fine-tune from the committed first stage of its seed."""

import json
from pathlib import Path

import pytest
from helpers import check_committed_run, recipe_changes
from test_recipes import TINY, TINY_ALGO

from dockingrl.cli import main
from dockingrl.recipes import load_recipe

RESULTS = Path(__file__).resolve().parents[1] / "results" / "stress" / "td3_robust_ft"
#: where a run went, what it logged to, the recipe named on its command line (seed 0's
#: fine-tune was made with ``--recipe td3-200k`` and the options the recipe now sets) and the
#: run it started from
RUN_FIELDS = {"out", "run_name", "logger", "recipe", "init_from"}
#: the seeds whose two stages and ladders are in ``RESULTS``
COMMITTED_SEEDS = sorted(int(p.name.rsplit("_s", 1)[1]) for p in RESULTS.glob("td3_robust_ft_s*"))


def test_it_fine_tunes_td3_200k_gently_at_l5_with_the_gated_estimating_filter():
    recipe = load_recipe("td3-200k-robust-ft")
    assert (recipe.algo, recipe.first_stage) == ("td3", "td3-200k")
    assert recipe_changes("td3-200k-robust-ft", "td3-200k") == {
        "total_steps": 150_000,
        "train_level": "L5",
        "compensate_latency": True,
        "estimate_current": True,
        "filter_gate": 13.816,
        "init_replay": True,
        "start_steps": 0,
        "updates_per_step": 0.5,
        "lr": 1e-4,
        "exploration_sigma": 0.1,
        "actor_average": 0.9995,
    }


def test_the_second_stage_fine_tunes_a_filtered_first_stage_at_l5(tmp_path, short_episodes):
    tiny = [*TINY, *TINY_ALGO["td3"], "--scenario", "filtered", "--out", str(tmp_path)]
    tiny[tiny.index("--checkpoint-every") + 1] = "800"
    assert main(["train", "--recipe", "td3-200k", "--run-name", "nominal", *tiny]) == 0
    assert main(["train", "--recipe", "td3", "--run-name", "other", *tiny]) == 0
    argv = ["train", "--recipe", "td3-200k-robust-ft", "--init-from"]
    # the td3 recipe's critics have no layer norm: not this recipe's networks
    with pytest.raises(SystemExit, match="not this run's .* or a run of recipe td3-200k$"):
        main([*argv, str(tmp_path / "other"), "--run-name", "x", *tiny])
    assert main([*argv, str(tmp_path / "nominal"), "--run-name", "ft", *tiny]) == 0
    config = json.loads((tmp_path / "ft" / "config.json").read_text())
    assert (config["train_level"], config["filter_gate"], config["actor_average"]) == (
        "L5",
        13.816,
        0.9995,
    )
    assert (tmp_path / "ft" / "policy.pt").is_file()


def test_seeds_0_to_2_are_committed():
    assert COMMITTED_SEEDS == [0, 1, 2]


@pytest.mark.parametrize("seed", COMMITTED_SEEDS)
def test_the_committed_stages_are_the_recipes(seed):
    first = RESULTS / f"td3_200k_filtered_s{seed}"
    check_committed_run(first, "td3-200k", RUN_FIELDS, scenario="filtered", seed=seed)
    fine = RESULTS / f"td3_robust_ft_s{seed}"
    run = check_committed_run(
        fine, "td3-200k-robust-ft", RUN_FIELDS, scenario="filtered", seed=seed
    )
    # each fine-tune started from the first stage of its seed beside it
    assert Path(run["init_from"]).name == first.name
    for folder in (first, fine):
        ladder = json.loads((folder / "stress.json").read_text())
        assert Path(ladder["policy"]).parent.name == folder.name
        assert [row["name"] for row in ladder["levels"]] == ["L0", "L1", "L2", "L3", "L4", "L5"]
