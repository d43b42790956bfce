"""The ``ppo-fast`` recipe, ``ppo-fast-follow`` on it and the main job's ``ppo-fast-follow-lr8``
on that: what each sets, that ``main.sh`` trains the last with no other config option, a smoke
run of ``ppo-fast``, and that the committed main-job runs are the recipes'."""

import json
import re
from pathlib import Path

from helpers import differences_from_recipe, recipe_changes
from test_recipes import TINY, TINY_ALGO

from dockingrl.cli import main
from dockingrl.recipes import load_recipe, recipe_names

ROOT = Path(__file__).resolve().parents[1]
MAIN_JOB = ROOT / "results" / "agents" / "main_job"


def test_ppo_fast_is_shipped_and_sized_for_the_main_job():
    assert "ppo-fast" in recipe_names()
    recipe = load_recipe("ppo-fast")
    cfg = recipe.make_config()
    assert (recipe.algo, cfg.recipe, cfg.scenario) == ("ppo", "ppo-fast", "compound")
    # advantages once per rollout, and no periodic evaluation or end-of-run selection
    assert not cfg.advantage_every_epoch and cfg.fast_update
    assert cfg.eval_every > cfg.total_steps and not cfg.keep_best
    # the main job's bar is measured on 2,000 episodes, at the thread count of its probes
    assert cfg.final_eval_episodes == 2000 and cfg.threads == 1


def test_ppo_fast_follow_is_ppo_fast_with_following_currents_in_training():
    assert recipe_changes("ppo-fast-follow", "ppo-fast") == {"following_current_fraction": 0.9}


def test_ppo_fast_follow_lr8_is_ppo_fast_follow_at_a_higher_learning_rate():
    assert recipe_changes("ppo-fast-follow-lr8", "ppo-fast-follow") == {"lr": 0.0008}


def test_main_sh_trains_the_ppo_fast_follow_lr8_recipe_alone():
    script = (ROOT / "main.sh").read_text()
    calls = re.findall(r"-m dockingrl train ([^\n]*)", script)
    assert len(calls) == 1
    options = calls[0].split()
    assert options[:2] == ["--recipe", "ppo-fast-follow-lr8"]
    # no config field beyond the recipe's, except where the run folder goes
    assert [o for o in options if o.startswith("--")] == ["--recipe", "--out"]


def test_train_with_the_ppo_fast_recipe(tmp_path, short_episodes):
    argv = ["train", "--recipe", "ppo-fast", "--out", str(tmp_path), "--run-name", "r"]
    argv += [*TINY, *TINY_ALGO["ppo"], "--epochs", "2"]
    assert main(argv) == 0
    config = json.loads((tmp_path / "r" / "config.json").read_text())
    assert (config["recipe"], config["algo"], config["advantage_every_epoch"]) == (
        "ppo-fast",
        "ppo",
        False,
    )
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["frames"] >= 1600
    assert json.loads((tmp_path / "r" / "eval.json").read_text())["episodes"] == 4


def test_the_committed_main_job_runs_are_the_recipe():
    """``results/agents/main_job/`` (seed 0) and its ``seed1/`` are ``bash main.sh`` runs of
    ``ppo-fast-follow-lr8``, and ``results/agents/ppo_fast_follow/`` those of the main job before
    it: their configs are the recipes' at their seeds, and their summaries name the command."""
    ppo_fast_follow = MAIN_JOB.parent / "ppo_fast_follow"
    for folder, recipe, seed in [
        (MAIN_JOB, "ppo-fast-follow-lr8", 0),
        (MAIN_JOB / "seed1", "ppo-fast-follow-lr8", 1),
        (ppo_fast_follow, "ppo-fast-follow", 0),
        (ppo_fast_follow / "seed1", "ppo-fast-follow", 1),
    ]:
        assert differences_from_recipe(folder, recipe, seed=seed) == set()
        summary = json.loads((folder / "summary.json").read_text())
        assert summary["command"].startswith(f"dockingrl train --recipe {recipe} --out runs")
        assert summary["frames"] >= 3_000_000
        assert json.loads((folder / "eval.json").read_text())["episodes"] == 2000
