"""The ``sac-ln-robust-ft-avg`` recipe: what it changes from ``sac-ln-robust-ft``, and that the
committed fine-tunes of ``results/stress/robust_ft_ln_avg/`` are its config, each from the
committed first stage of its seed (the smoke run of the two stages is ``sac-ln-robust-ft``'s, in
``test_recipe_sac_ln``; this recipe adds one field to it)."""

import json
from pathlib import Path

import pytest
from helpers import check_committed_run, ladder_policy, recipe_changes

from dockingrl.recipes import load_recipe

RESULTS = Path(__file__).resolve().parents[1] / "results" / "stress" / "robust_ft_ln_avg"
#: where a run went and what it logged to, the recipe named on its command line and the run it
#: started from: the runs were made with ``--recipe sac-ln-robust-ft --actor-average 0.9995``
RUN_FIELDS = {"out", "run_name", "logger", "recipe", "init_from"}


def test_it_is_sac_ln_robust_ft_with_the_actor_averaged():
    assert recipe_changes("sac-ln-robust-ft-avg", "sac-ln-robust-ft") == {"actor_average": 0.9995}
    cfg = load_recipe("sac-ln-robust-ft-avg").make_config()
    assert (cfg.recipe, cfg.critic_layer_norm, cfg.train_level) == (
        "sac-ln-robust-ft-avg",
        True,
        "L5",
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_committed_fine_tunes_are_the_recipe(seed):
    folder = RESULTS / f"sac_ln_robust_ft_avg_s{seed}"
    run = check_committed_run(
        folder, "sac-ln-robust-ft-avg", RUN_FIELDS, scenario="filtered", seed=seed
    )
    # each fine-tune started from the first stage of its seed in ../robust_ft_ln/
    assert Path(run["init_from"]).name == f"sac_filtered_ln_s{seed}"
    ladder = json.loads((folder / "stress.json").read_text())
    assert Path(ladder["policy"]).parent.name == f"sac_ln_robust_ft_avg9995_s{seed}"
    assert [row["name"] for row in ladder["levels"]] == ["L0", "L1", "L2", "L3", "L4", "L5"]


AMD = RESULTS.parent / "robust_ft_ln_avg_amd"
#: the reruns on the AMD EPYC were made with the recipes' names; only where they went differs
AMD_FIELDS = {"out", "run_name", "logger", "init_from"}


def check_ladder(folder: Path, run: dict) -> None:
    """``folder``'s ladder covers every level and is of the policy of ``run``, beside it."""
    assert ladder_policy(folder).parent.name == run["run_name"]


@pytest.mark.parametrize(
    "seed", sorted(int(p.name[-1]) for p in AMD.glob("sac_ln_robust_ft_avg_s*"))
)
def test_the_reruns_on_another_cpu_are_the_recipes(seed):
    first = check_committed_run(
        AMD / f"sac_ln_s{seed}", "sac-ln", AMD_FIELDS, scenario="filtered", seed=seed
    )
    check_ladder(AMD / f"sac_ln_s{seed}", first)
    folder = AMD / f"sac_ln_robust_ft_avg_s{seed}"
    fine = check_committed_run(
        folder, "sac-ln-robust-ft-avg", AMD_FIELDS, scenario="filtered", seed=seed
    )
    # the fine-tune started from that seed's first stage
    assert Path(fine["init_from"]).name == first["run_name"]
    check_ladder(folder, fine)
