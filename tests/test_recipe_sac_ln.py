"""The ``sac-ln`` and ``sac-ln-robust-ft`` recipes: what each changes from the recipe it
extends, and that the second stage takes the first stage's run where ``sac-robust-ft`` refuses
it."""

import json
from pathlib import Path

import pytest
from helpers import check_committed_run, recipe_changes
from test_recipes import TINY, TINY_ALGO

from dockingrl.cli import main
from dockingrl.recipes import load_recipe


@pytest.mark.parametrize(
    ("name", "base"), [("sac-ln", "sac"), ("sac-ln-robust-ft", "sac-robust-ft")]
)
def test_each_is_its_base_with_layer_normed_critics_on_one_thread(name, base):
    assert recipe_changes(name, base) == {"critic_layer_norm": True, "threads": 1}
    assert load_recipe(name).make_config().recipe == name


def test_the_second_stage_fine_tunes_the_first_at_l5(tmp_path, short_episodes):
    tiny = [*TINY, *TINY_ALGO["sac"], "--scenario", "filtered", "--out", str(tmp_path)]
    tiny[tiny.index("--checkpoint-every") + 1] = "800"
    assert main(["train", "--recipe", "sac-ln", "--run-name", "nominal", *tiny]) == 0
    nominal = str(tmp_path / "nominal")
    with pytest.raises(SystemExit, match="not this run's .* or a run of recipe sac$"):
        main(
            ["train", "--recipe", "sac-robust-ft", "--init-from", nominal, "--run-name", "x", *tiny]
        )
    argv = ["train", "--recipe", "sac-ln-robust-ft", "--init-from", nominal, "--run-name", "ft"]
    assert main([*argv, *tiny]) == 0
    assert (tmp_path / "ft" / "policy.pt").is_file()


RESULTS = Path(__file__).resolve().parents[1] / "results" / "stress" / "robust_ft_ln"
#: where a run went and what it logged to, the recipe named on its command line and the run it
#: started from: the runs were made with ``--recipe sac`` / ``sac-robust-ft`` and the options
#: the ``sac-ln`` recipes now set
RUN_FIELDS = {"out", "run_name", "logger", "recipe", "init_from"}
#: the seeds whose two stages and ladders are in ``RESULTS``
COMMITTED_SEEDS = [0, 1, 2]


@pytest.mark.parametrize("seed", COMMITTED_SEEDS)
@pytest.mark.parametrize(
    ("stage", "recipe"), [("sac_ln", "sac-ln"), ("sac_ln_robust_ft", "sac-ln-robust-ft")]
)
def test_the_committed_runs_are_the_recipes(seed, stage, recipe):
    folder = RESULTS / f"{stage}_s{seed}"
    run = check_committed_run(folder, recipe, RUN_FIELDS, scenario="filtered", seed=seed)
    if stage == "sac_ln_robust_ft":
        # the fine-tune started from the committed first stage of the same seed
        assert Path(run["init_from"]).name == f"sac_filtered_ln_s{seed}"
    ladder = json.loads((folder / "stress.json").read_text())
    assert Path(ladder["policy"]).parent.name in {
        f"sac_filtered_ln_s{seed}",
        f"sac_robust_ft_ln_s{seed}",
    }
