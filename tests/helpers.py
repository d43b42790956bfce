"""Small builders shared by the tests: an untrained actor, a training config sized for a smoke
run, an env step that restarts onboard policies, an onboard policy and its exported program
driven beside the env pipeline, a finished run's small files for the table and the grid, and
the repository's root for the files it commits."""

import json
from pathlib import Path

import torch

from dockingrl import make_env
from dockingrl.agents import build_actor
from dockingrl.agents.config import make_config

#: the repository's root, whatever folder pytest runs in
REPO = Path(__file__).resolve().parent.parent
#: a trained PPO compound policy (the first Table 6 grid's, at commit 8aa92b8), a fixture
PPO_COMPOUND_POLICY = REPO / "tests" / "data" / "ppo_policy" / "policy.pt"


def tiny_actor(obs_dim, algo="sac", seed=0):
    """An untrained ``algo`` actor with 2 x 32 hidden units reading ``obs_dim`` numbers."""
    torch.manual_seed(seed)
    env = make_env("noise", 1, seed=0)
    cfg = make_config(algo, "paper", scenario="compound", hidden=(32, 32))
    return build_actor(cfg, obs_dim, env.action_spec[0], 30.0).eval()


def step_onboard(env, td, command, *policies):
    """Step ``env`` from ``td`` with ``command`` and begin a new approach in each onboard
    policy of ``policies`` wherever an episode ended; returns ``(next td, done)``, ``done``
    ``(num_envs,)`` bool."""
    td["action"] = command
    out, td = env.step_and_maybe_reset(td)
    done = out["next", "done"].squeeze(-1)
    for policy in policies:
        policy.reset(done)
    return td, done


def drive_onboard_beside_env(env, actor, onboard, program, steps=50, plain=None):
    """Drive ``env`` (4 envs with ``sensor_age``, a filter compensating the latency) for
    ``steps`` steps with ``onboard``'s commands, asserting at each that they equal ``actor``
    on the env pipeline's observation and the exported ``program``'s, and restarting the
    onboard policies where an episode ends. Returns ``(resets, differs)``: how many episodes
    ended, and whether ``plain`` (another onboard policy fed the same readings) ever commanded
    otherwise."""
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    td = env.reset()
    state, resets, differs = onboard.initial_state(4), 0, False
    others = () if plain is None else (plain,)
    for _ in range(steps):
        z, current, ages = td["observation"][..., :6], td["ocean_current"], td["sensor_age"]
        command = onboard.act(z, current, ages)
        if plain is not None:
            differs |= bool((plain.act(z, current, ages) - command).abs().max() > 1e-4)
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            obs = TensorDict({"observation": td["observation"]}, batch_size=[4])
            torch.testing.assert_close(command, actor(obs)["action"], rtol=1e-5, atol=1e-6)
        exported, *rest = program(z, current, *state[:4], ages, state[4])
        torch.testing.assert_close(exported, command, rtol=1e-5, atol=1e-6)
        state = (rest[0], rest[1], exported, *rest[2:])
        td, done = step_onboard(env, td, command, onboard, *others)
        resets += int(done.sum())
        state = (*state[:3], torch.where(done.view(-1, 1), -1.0, state[3]), state[4])
    return resets, differs


def smoke_config(algo, scenario, tmp_path, run_name, **overrides):
    """The ``paper`` preset of ``algo`` cut down to a run of seconds on one thread (4 envs,
    batch 32, 2 x 32 hidden, no logger, no checkpoints), written under ``tmp_path``;
    ``overrides`` set the budget and anything else."""
    fields = dict(
        scenario=scenario,
        num_envs=4,
        batch_size=32,
        hidden=(32, 32),
        eval_episodes=2,
        final_eval_episodes=4,
        logger="none",
        checkpoint_every=0,
        threads=1,
        out=str(tmp_path),
        run_name=run_name,
    )
    fields.update(overrides)
    return make_config(algo, "paper", **fields)


#: episode length (steps) of the smoke runs of ``conftest.tiny_runs``: their untrained policies
#: time out, and 60 steps evaluate ten times faster than the paper's 600
SMOKE_EPISODE_STEPS = 60

#: budgets and sizes of a run of seconds per algorithm, and what every such run shares
TINY = {
    "sac": {
        "total_steps": 400,
        "num_envs": 4,
        "start_steps": 100,
        "frames_per_batch": 100,
        "batch_size": 32,
        "hidden": (32, 32),
        "updates_per_step": 0.5,
    },
    "ppo": {
        "total_steps": 512,
        "num_envs": 8,
        "steps_per_env": 32,
        "minibatch_size": 64,
        "epochs": 2,
        "hidden": (32, 32),
    },
}
TINY["td3"] = dict(TINY["sac"])
COMMON = {
    "eval_every": 200,
    "eval_episodes": 3,
    "final_eval_episodes": 6,
    "logger": "csv",
    "checkpoint_every": 200,
    "threads": 1,
}


def tiny_config(algo, scenario, tmp_path, **extra):
    """The smoke run of ``algo`` on ``scenario`` that test_training.py varies: ``TINY`` and
    ``COMMON``, a run named ``{algo}_{scenario}`` under ``tmp_path``; ``extra`` sets more."""
    return make_config(
        algo,
        "paper",
        scenario=scenario,
        out=str(tmp_path),
        run_name=f"{algo}_{scenario}",
        **{**TINY[algo], **COMMON, **extra},
    )


def fake_run(
    root: Path,
    recipe: str,
    algo: str,
    scenario: str,
    seed: int,
    success: float,
    early: float = 50.0,
    by_current: list[tuple[int, float, int]] | None = None,
    config: dict | None = None,
    name: str = "",
) -> Path:
    """A finished run's small files in ``root/RECIPE__SCENARIO__sSEED`` (or ``root/name``):
    config, summary, a 500-episode evaluation at ``success`` %, periodic evaluations with
    ``early`` % at 210 k env steps, and a policy file."""
    run = root / (name or f"{recipe}__{scenario}__s{seed}")
    config = config or {}
    run.mkdir(parents=True)
    config = {"recipe": recipe, "algo": algo, "scenario": scenario, "seed": seed, **config}
    (run / "config.json").write_text(json.dumps(config))
    (run / "summary.json").write_text(
        json.dumps(
            {
                "frames": 500_000,
                "success_rate": success,
                "train_wall_clock_s": 3600.0,
                "machine": "m",
                "code": {"commit": "abc", "dirty": False},
            }
        )
    )
    docked = round(5 * success)
    (run / "eval.json").write_text(
        json.dumps(
            {
                "episodes": 500,
                "success_rate": success,
                # 20 contacts too fast besides the successes; they end sooner
                "time_s": {"n": docked + 20, "mean": 40.0 + seed, "std": 2.0},
                "time_success_s": {"n": docked, "mean": 42.0 + seed, "std": 2.0},
                "total_reward": {"n": 500, "mean": 10.0 * seed, "std": 1.0},
                **(
                    {}
                    if by_current is None
                    else {
                        "by_current_x": [
                            {
                                "oc_x": name,
                                "range": [-0.3 + 0.2 * k, -0.1 + 0.2 * k],
                                "episodes": n,
                                "success_rate": rate,
                                "failures": {"timeout": timeouts, "missed_funnel": 0},
                            }
                            for k, (name, (n, rate, timeouts)) in enumerate(
                                zip(("opposing", "weak", "following"), by_current, strict=True)
                            )
                        ]
                    }
                ),
            }
        )
    )
    steps = [100_000, 190_000, 210_000, 500_000]
    values = [10.0, 30.0, early, success]
    rows = ["step,key,value"] + [
        f"{s},{k},{v}"
        for s, v in zip(steps, values, strict=True)
        for k in ("eval/success_rate", "eval/total_reward", "eval/episode_time_s")
    ]
    (run / "curves.csv").write_text("\n".join(rows) + "\n")
    (run / "policy.pt").write_bytes(b"x")
    return run


def recipe_changes(name: str, base: str) -> dict:
    """The config fields (``recipe`` aside) in which recipe ``name`` differs from ``base``."""
    from dockingrl.recipes import load_recipe

    new, old = load_recipe(name).make_config().to_dict(), load_recipe(base).make_config().to_dict()
    return {k: v for k, v in new.items() if old[k] != v and k != "recipe"}


def recipe_config_json(recipe: str, **fields) -> dict:
    """Recipe ``recipe``'s config with ``fields`` set, as a run's ``config.json`` holds it
    (lists, not tuples)."""
    from dockingrl.recipes import load_recipe

    return json.loads(json.dumps(load_recipe(recipe).make_config(**fields).to_dict()))


def differences_from_recipe(run_dir: Path, recipe: str, **fields) -> set[str]:
    """The fields in which the ``config.json`` of ``run_dir`` differs from recipe's config with
    ``fields`` set (compared as config.json holds them). A field the run's file lacks (written
    before the field existed) counts as its default."""
    from dataclasses import MISSING
    from dataclasses import fields as config_fields

    from dockingrl.agents.config import CONFIGS

    run = json.loads((run_dir / "config.json").read_text())
    expected = recipe_config_json(recipe, **fields)
    defaults = {
        f.name: json.loads(json.dumps(f.default))
        for f in config_fields(CONFIGS[expected["algo"]])
        if f.default is not MISSING
    }
    run = {**{k: v for k, v in defaults.items() if k not in run}, **run}
    return {k for k in expected.keys() | run.keys() if expected.get(k) != run.get(k)}


def check_committed_run(run_dir: Path, recipe: str, allowed: set[str], **fields) -> dict:
    """Assert that the committed run ``run_dir`` is recipe ``recipe``'s config with ``fields``
    set, apart from the fields in ``allowed`` (where it went, what it logged to, the recipe
    named on its command line...), that it trained no more than the recipe's env steps (and
    the last batch), and that its summary's success rate is its ``eval.json``'s. Returns the
    run's ``config.json``."""
    from dockingrl.recipes import load_recipe

    differing = differences_from_recipe(run_dir, recipe, **fields)
    assert differing <= allowed, differing - allowed
    expected = load_recipe(recipe).make_config()
    summary = json.loads((run_dir / "summary.json").read_text())
    batch = expected.collected_transitions() * expected.action_repeat
    assert summary["frames"] <= expected.total_steps + batch
    final = json.loads((run_dir / "eval.json").read_text())
    assert summary["success_rate"] == final["success_rate"]
    return json.loads((run_dir / "config.json").read_text())


def ladder_policy(folder: Path) -> Path:
    """The policy whose committed ladder ``folder/stress.json`` is, after checking that the
    ladder covers every level, L0 to L5."""
    ladder = json.loads((folder / "stress.json").read_text())
    assert [row["name"] for row in ladder["levels"]] == ["L0", "L1", "L2", "L3", "L4", "L5"]
    return Path(ladder["policy"])
