"""Same seed, same numbers: a short fixed-seed run of the sac, td3 and ppo recipes (compound
scenario, cut down to seconds) must reproduce, bit for bit, the curves, the final evaluation and
the policy's weights recorded in ``tests/golden/training.json``.

A change to training code that alters what a run computes fails here; a grid that runs while
the code changes keeps comparable numbers. When a change is meant to alter the numbers, it is a
new recipe (or a new format); regenerate the file with
``DOCKINGRL_UPDATE_GOLDEN=1 python -m pytest tests/test_golden.py`` and say why in the commit."""

import hashlib
import json
import os
from pathlib import Path

import pytest
import torch

from dockingrl.recipes import load_recipe
from dockingrl.training import read_curves, train

GOLDEN = Path(__file__).resolve().parent / "golden" / "training.json"
TINY = dict(
    scenario="compound",
    seed=3,
    num_envs=4,
    hidden=(32, 32),
    eval_every=800,
    eval_episodes=3,
    final_eval_episodes=6,
    select_episodes=4,
    keep_candidates=2,
    logger="none",
    checkpoint_every=0,
    threads=1,
)
TINY_ALGO = {
    "sac": dict(
        total_steps=2400, start_steps=800, batch_size=32, frames_per_batch=200, compile_update=False
    ),
    "td3": dict(
        total_steps=2400, start_steps=800, batch_size=32, frames_per_batch=200, updates_per_step=0.5
    ),
    "ppo": dict(total_steps=2400, steps_per_env=100, minibatch_size=100, epochs=2),
}


def fingerprint(run_dir: Path) -> dict:
    """What a run computed: its curves (timings left out), its final evaluation and its
    policy's weights, as digests, with a few readable numbers beside them."""
    curves = read_curves(run_dir)
    rows = sorted(
        (key, step, value)
        for key, points in curves.items()
        if not key.startswith("time/")
        for step, value in points
    )
    policy = torch.load(run_dir / "policy.pt", map_location="cpu", weights_only=False)
    weights = hashlib.sha256()
    for name, tensor in sorted(policy["state_dict"].items()):
        weights.update(name.encode())
        weights.update(tensor.detach().contiguous().numpy().tobytes())
    final = json.loads((run_dir / "eval.json").read_text())
    return {
        "curves_sha256": hashlib.sha256(repr(rows).encode()).hexdigest(),
        "policy_sha256": weights.hexdigest(),
        "final_success_rate": final["success_rate"],
        "final_reward_mean": final["total_reward"]["mean"],
        "last_losses": {k: v[-1][1] for k, v in sorted(curves.items()) if k.startswith("losses/")},
    }


@pytest.mark.parametrize("recipe", ["sac", "td3", "ppo"])
def test_a_fixed_seed_run_reproduces_its_recorded_numbers(recipe, tmp_path):
    algo = load_recipe(recipe).algo
    cfg = load_recipe(recipe).make_config(
        **TINY, **TINY_ALGO[algo], out=str(tmp_path), run_name=recipe
    )
    train(cfg, progress=False)
    got = fingerprint(tmp_path / recipe)
    golden = json.loads(GOLDEN.read_text()) if GOLDEN.exists() else {}
    if os.environ.get("DOCKINGRL_UPDATE_GOLDEN") == "1":
        golden[recipe] = got
        GOLDEN.write_text(json.dumps(golden, indent=2, sort_keys=True) + "\n")
    assert recipe in golden, f"no recorded numbers for {recipe}: see this file's docstring"
    assert got == golden[recipe]
