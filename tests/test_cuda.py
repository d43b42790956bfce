"""The env, the filter and training on a CUDA device (skipped where there is none).

Each test compares with the CPU where the two can be compared: the dynamics without noise,
one EKF step on the same inputs, the recorded-data filter on the same recordings.
"""

import pytest
import torch
from test_recipes import TINY, TINY_ALGO
from test_training import tiny_config

from dockingrl import make_env
from dockingrl.agents.saving import load_policy
from dockingrl.env import DockingConfig, DockingEnv
from dockingrl.filter_learning import FilterFit, fit_filter, record_rollouts, run_filter
from dockingrl.recipes import load_recipe, recipe_names
from dockingrl.scenarios import make_filter
from dockingrl.training import train

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
CUDA = torch.device("cuda")


def scripted_actions(steps: int, n: int) -> torch.Tensor:
    t = torch.arange(steps, dtype=torch.float64)[:, None]
    k = torch.arange(n, dtype=torch.float64)[None, :]
    surge = 0.3 + 0.3 * torch.sin(0.05 * t + k)
    yaw = 0.2 * torch.cos(0.07 * t + 0.5 * k)
    return torch.stack([surge, yaw], -1)


def test_noise_free_dynamics_match_the_cpu():
    n, steps = 16, 150
    poses = torch.stack(
        [torch.linspace(-30, -10, n), torch.linspace(-8, 8, n), torch.linspace(-1, 1, n)], -1
    )
    currents = torch.stack([torch.linspace(-0.3, 0.3, n), torch.linspace(0.2, -0.2, n)], -1)
    actions = scripted_actions(steps, n)
    traces = {}
    for key, device in (("cpu", "cpu"), ("cuda", "cuda")):
        cfg = DockingConfig(noise=False)
        env = DockingEnv(n, config=cfg, device=device, seed=0, dtype=torch.float64)
        env.set_initial_state(poses, currents)
        td = env.reset()
        rows = []
        for a in actions:
            td["action"] = a.to(device)
            out, td = env.step_and_maybe_reset(td)
            assert out.device.type == torch.device(device).type
            rows.append(out["next", "true_state"].cpu())
        traces[key] = torch.stack(rows)
    torch.testing.assert_close(traces["cuda"], traces["cpu"], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("scenario", ["no_noise", "noise", "filtered", "compound"])
def test_every_scenario_steps_thousands_of_envs_on_cuda(scenario):
    env = make_env(scenario, 4096, seed=0, device="cuda")
    data = env.rollout(60, break_when_any_done=False)
    assert data.device.type == "cuda" and data.batch_size == (4096, 60)
    obs = data["next", "observation"]
    assert obs.is_cuda and bool(torch.isfinite(obs).all())
    assert obs.shape[-1] == (12 if scenario == "compound" else 6)
    assert int(data["next", "step_count"].max()) == 60


def test_recorded_data_filter_matches_the_cpu():
    data = record_rollouts(32, 40, seed=3)
    ekf = make_filter(DockingConfig())
    ekf_cuda = make_filter(DockingConfig()).to(CUDA)
    mean, cov = run_filter(ekf.double(), data.double())[:2]
    mean_c, cov_c = run_filter(ekf_cuda.double(), data.double().to(CUDA))[:2]
    assert mean_c.is_cuda
    torch.testing.assert_close(mean_c.cpu(), mean, rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(cov_c.cpu(), cov, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("objective", ["nll", "supervised"])
def test_filter_learning_runs_on_cuda(objective):
    data = record_rollouts(64, 120, seed=1).to(CUDA)
    ekf = make_filter(DockingConfig()).to(CUDA)
    fit = FilterFit(objective=objective, window=20, epochs=3, lr=0.05, num_envs=64, steps=120)
    history = fit_filter(ekf, fit, data=data)
    assert all(torch.isfinite(torch.tensor(history)))
    first, last = sum(history[:6]) / 6, sum(history[-6:]) / 6
    assert last < first
    assert next(iter(ekf.noise_parameters())).is_cuda


@pytest.mark.parametrize("algo", ["sac", "td3", "ppo"])
def test_training_on_cuda_and_evaluating_the_policy_on_the_cpu(algo, tmp_path):
    cfg = tiny_config(algo, "compound", tmp_path, device="cuda")
    result = train(cfg, progress=False)
    assert result["summary"]["updates"] > 0
    assert "GPU" in result["summary"]["machine"]
    policy, info = load_policy(tmp_path / f"{algo}_compound" / "policy.pt", device="cpu")
    assert info["algo"] == algo
    assert all(p.device.type == "cpu" for p in policy.parameters())
    resumed = train(None, resume=tmp_path / f"{algo}_compound", progress=False)
    assert resumed["summary"]["frames"] == result["summary"]["frames"]


def test_eval_cli_on_cuda(tmp_path):
    import json

    from dockingrl.cli import main as cli_main

    args = ["eval", "--policy", "managed_surge", "--scenario", "compound", "--use-filter"]
    args += ["--episodes", "64", "--map", "--map-trials", "2", "--trajectories", "--quiet"]
    assert cli_main([*args, "--device", "cuda", "--out", str(tmp_path)]) == 0
    metrics = json.loads((tmp_path / "eval.json").read_text())
    assert metrics["episodes"] == 64 and "GPU" in metrics["machine"]
    for name in ("success_map.json", "success_map.png", "trajectories.json", "trajectories.png"):
        assert (tmp_path / name).stat().st_size > 0


def test_the_harshest_stress_level_with_the_estimating_filter_steps_on_cuda():
    from dockingrl.env.levels import level_config

    env = make_env(
        "compound",
        256,
        seed=0,
        device="cuda",
        config=level_config("L5"),
        ekf_kwargs={"compensate_latency": True, "estimate_current": True},
    )
    data = env.rollout(60, break_when_any_done=False)
    obs = data["next", "observation"]
    assert obs.is_cuda and bool(torch.isfinite(obs).all())
    assert bool((data["next", "sensor_age"] > 0).any())


@pytest.mark.parametrize("name", recipe_names())
def test_every_recipe_trains_on_cuda(name, tmp_path, short_episodes):
    import json

    from dockingrl.cli import main as cli_main

    algo = load_recipe(name).algo

    def train_args(recipe: str, run_name: str) -> list[str]:
        argv = ["train", "--recipe", recipe, "--scenario", "compound", "--out", str(tmp_path)]
        return [*argv, "--run-name", run_name, *TINY, *TINY_ALGO[algo], "--device", "cuda"]

    argv = train_args(name, "r")
    first_stage = load_recipe(name).first_stage
    if first_stage:  # a fine-tune: first the run it starts from
        assert cli_main([*train_args(first_stage, "base"), "--checkpoint-every", "800"]) == 0
        argv += ["--init-from", str(tmp_path / "base")]
    assert cli_main(argv) == 0
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["updates"] > 0 and "GPU" in summary["machine"]
    policy, info = load_policy(tmp_path / "r" / "policy.pt", device="cpu")
    assert info["algo"] == algo
