"""Same seed, same numbers: a short fixed-seed run of the sac, td3 and ppo recipes (compound
scenario, cut down to seconds) must reproduce, bit for bit, the curves, the final evaluation and
the policy's weights recorded in ``tests/golden/training.json``.

A change to training code that alters what a run computes fails here; a grid that runs while
the code changes keeps comparable numbers. When a change is meant to alter the numbers, it is a
new recipe (or a new format); regenerate the file with
``DOCKINGRL_UPDATE_GOLDEN=1 python -m pytest tests/test_golden.py`` and say why in the commit.

Bits depend on the CPU as well as the code (the math libraries pick kernels by CPU: an AMD EPYC
and an Intel Xeon differ in the sixth significant digit after 2,400 env steps), so the file
keeps one record per platform, the CPU's model name and torch's version. On a recorded platform
the run must match bit for bit; on another, its readable numbers (final success, reward, last
losses) must match a recorded platform's to 1e-3 relative, and
``DOCKINGRL_UPDATE_GOLDEN=1`` adds its exact record."""

import hashlib
import json
import math
import os
from pathlib import Path

import pytest
import torch

from dockingrl.evaluation.machine import cpu_model
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
    logger="none",
    checkpoint_every=0,
    threads=1,
)
TINY_ALGO = {
    "sac": dict(
        total_steps=2400,
        start_steps=800,
        batch_size=32,
        frames_per_batch=200,
        compile_update=False,
        select_episodes=4,
        keep_candidates=2,
    ),
    "td3": dict(
        total_steps=2400,
        start_steps=800,
        batch_size=32,
        frames_per_batch=200,
        select_episodes=4,
        keep_candidates=2,
    ),
    # the recipe's compiled env and filter steps would take most of the test's time to build
    "ppo": dict(total_steps=2400, steps_per_env=50, minibatch_size=100, epochs=2, compile=False),
}


def platform() -> str:
    """The CPU's model name and torch's version: what decides a run's bits besides the code."""
    return f"{cpu_model()}, torch {torch.__version__}"


def readable_numbers(fp: dict) -> dict[str, float]:
    """The numbers of a fingerprint that are not digests."""
    return {
        "final_success_rate": fp["final_success_rate"],
        "final_reward_mean": fp["final_reward_mean"],
        **fp["last_losses"],
    }


def close_to(got: dict, recorded: dict) -> list[str]:
    """The readable numbers of ``got`` that differ from ``recorded``'s by more than 1e-3
    relative (1e-6 absolute near zero), or that one of them lacks."""
    a, b = readable_numbers(got), readable_numbers(recorded)
    return sorted(
        k
        for k in a.keys() | b.keys()
        if k not in a or k not in b or not math.isclose(a[k], b[k], rel_tol=1e-3, abs_tol=1e-6)
    )


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
    here = platform()
    if os.environ.get("DOCKINGRL_UPDATE_GOLDEN") == "1":
        golden.setdefault(here, {})[recipe] = got
        GOLDEN.write_text(json.dumps(golden, indent=2, sort_keys=True) + "\n")
    if recipe in golden.get(here, {}):
        assert got == golden[here][recipe]
        return
    others = {name: records[recipe] for name, records in golden.items() if recipe in records}
    assert others, f"no recorded numbers for {recipe}: see this file's docstring"
    name, recorded = sorted(others.items())[0]
    assert not close_to(got, recorded), f"{recipe} differs from its record on {name}"


def test_the_loose_check_across_platforms_catches_a_changed_number():
    recorded = {
        "final_success_rate": 0.0,
        "final_reward_mean": -478.115,
        "last_losses": {"losses/loss_actor": 15.63715, "losses/kl": 4.350e-05},
    }
    rounding = json.loads(json.dumps(recorded))
    rounding["final_reward_mean"] = -478.11501
    rounding["last_losses"]["losses/kl"] = 4.3506e-05
    assert close_to(rounding, recorded) == []
    changed = json.loads(json.dumps(recorded))
    changed["last_losses"]["losses/loss_actor"] = 15.66
    del changed["last_losses"]["losses/kl"]
    assert close_to(changed, recorded) == ["losses/kl", "losses/loss_actor"]
