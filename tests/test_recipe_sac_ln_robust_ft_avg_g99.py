"""The ``sac-ln-750k`` and ``sac-ln-robust-ft-avg-g99`` recipes: what each changes from its
base, and that the committed runs of ``results/stress/robust_ft_ln_avg_g99/`` are their configs,
each fine-tune from the committed first stage of its seed (the smoke run of the two stages is
``sac-ln-robust-ft``'s, in ``test_recipe_sac_ln``; these recipes change one field each)."""

import json
from pathlib import Path

import pytest
from helpers import check_committed_run, ladder_policy, recipe_changes

from dockingrl.recipes import load_recipe

RESULTS = Path(__file__).resolve().parents[1] / "results" / "stress" / "robust_ft_ln_avg_g99"
#: where a run went and what it logged to, the run it started from, and the recipe named on its
#: command line: the first stages were made as ``sac-ln`` runs continued to 750 k env steps
#: (``--resume RUN --total-steps 750000``), the fine-tunes as ``--recipe sac-ln-robust-ft-avg
#: --gamma 0.99``
RUN_FIELDS = {"out", "run_name", "logger", "init_from", "recipe"}


def test_the_first_stage_is_sac_ln_for_750k_env_steps():
    assert recipe_changes("sac-ln-750k", "sac-ln") == {"total_steps": 750_000}


def test_the_fine_tune_is_sac_ln_robust_ft_avg_at_the_discount_0_99_from_sac_ln_750k():
    assert recipe_changes("sac-ln-robust-ft-avg-g99", "sac-ln-robust-ft-avg") == {"gamma": 0.99}
    assert load_recipe("sac-ln-robust-ft-avg-g99").first_stage == "sac-ln-750k"


@pytest.mark.parametrize(
    "seed", sorted(int(p.name.rsplit("_s", 1)[1]) for p in RESULTS.glob("sac_ln_750k_s*"))
)
def test_the_committed_runs_are_the_recipes(seed):
    folder = RESULTS / f"sac_ln_750k_s{seed}"
    first = check_committed_run(folder, "sac-ln-750k", RUN_FIELDS, scenario="filtered", seed=seed)
    assert first["recipe"] == "sac-ln"
    first_run = ladder_policy(folder).parent
    folder = RESULTS / f"sac_ln_robust_ft_avg_g99_s{seed}"
    fine = check_committed_run(
        folder, "sac-ln-robust-ft-avg-g99", RUN_FIELDS, scenario="filtered", seed=seed
    )
    assert fine["recipe"] == "sac-ln-robust-ft-avg"
    # the fine-tune started from that seed's first stage, and the ladder is the fine-tune's
    assert Path(fine["init_from"]).name == first_run.name
    assert ladder_policy(folder).parent.name == fine["run_name"]
    for draw in ("stress_l0_seed1.json", "stress_l5_seed1.json"):
        extra = json.loads((folder / draw).read_text())
        assert Path(extra["policy"]).parent.name == fine["run_name"]
        assert (extra["seed"], extra["episodes"]) == (1, 1000)
