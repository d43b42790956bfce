import inspect
import json

import pytest
import torch
from tensordict.nn import TensorDictModule

from dockingrl import make_env
from dockingrl.agents.managed_surge import ManagedSurgePolicy
from dockingrl.cli import main as cli_main
from dockingrl.env import DockingConfig
from dockingrl.evaluation import (
    base_env,
    evaluate,
    run_episodes,
    success_map,
    summarize,
    trajectories,
)
from dockingrl.plots import plot_success_map, plot_trajectories


def constant_policy(surge, yaw_rate=0.0):
    def act(observation):
        action = torch.tensor([surge, yaw_rate], dtype=observation.dtype)
        return action.expand(*observation.shape[:-1], 2)

    return TensorDictModule(act, in_keys=["observation"], out_keys=["action"])


def test_a_policy_that_never_moves_always_times_out():
    # a pushing current could carry a still AUV into the funnel: no current here
    config = DockingConfig(ocean_current_range=(-1e-6, 1e-6))
    m = evaluate(constant_policy(0.0), "noise", 16, seed=0, config=config)
    assert m["success_rate"] == 0.0
    assert m["failures"] == {"timeout": 16, "missed_funnel": 0, "too_fast": 0}
    assert m["time_all_s"]["mean"] == pytest.approx(120.0)
    assert m["time_s"]["n"] == 0 and m["time_s"]["mean"] is None
    # 600 steps of r_dist only (no thrust at rest), rho within [25, 31.8] m
    assert -600 * 31.8 / 30 < m["total_reward"]["mean"] < -600 * 25 / 30


def test_forced_contacts_are_counted_with_their_score_and_speed():
    env = make_env("no_noise", 3, seed=0)
    base_env(env).set_initial_state(
        pose=torch.tensor([[-0.9, 0.0, 0.0], [-0.9, 0.0, 0.5], [-3.0, 0.0, 0.0]]),
        ocean_current=torch.tensor([[0.2, 0.0], [0.2, 0.0], [0.2, 0.0]]),
    )

    # envs 0 and 1 drift in with the current at 0.2 m/s; env 2 drives in at 0.8 + 0.2 m/s
    class Policy(torch.nn.Module):
        def forward(self, td):
            action = torch.tensor([[0.0, 0.0], [0.0, 0.0], [0.8, 0.0]])
            return td.set("action", action)

    m = evaluate(Policy(), env, seed=0)
    assert m["episodes"] == 3
    assert m["success_rate"] == pytest.approx(100 / 3)
    assert m["failures"] == {"timeout": 0, "missed_funnel": 1, "too_fast": 1}
    # env 0: g = 1; env 1: e_alpha = 0.5 against sign(y) = 0 -> w_2: g = 1 - 3.05 * 0.5
    # env 2: straight in, g = 1
    scores = sorted([1.0, 1 - 3.05 * 0.5, 1.0])
    assert m["contact_score"]["n"] == 3
    assert m["contact_score"]["mean"] == pytest.approx(sum(scores) / 3, abs=1e-5)
    assert m["time_s"]["n"] == 3 and m["time_success_s"]["n"] == 1
    # drifting at 0.04 m a step, x = -0.9 -> -0.86 -> -0.82 -> -0.78: contact at the 3rd step
    assert m["time_success_s"]["mean"] == pytest.approx(0.2 * 3)
    assert m["contact_speed"]["mean"] > (0.2 + 0.2 + 0.3) / 3


def test_failures_are_split_by_the_current_along_the_approach():
    env = make_env("no_noise", 4, seed=0)
    base_env(env).set_initial_state(
        pose=torch.tensor([[-0.9, 0.0, 0.0], [-0.9, 3.0, 0.0], [-10, 0.0, 0.0], [-10, 3.0, 0.0]]),
        ocean_current=torch.tensor([[0.25, 0.0], [0.25, 0.0], [-0.25, 0.0], [0.0, 0.1]]),
    )
    # a still AUV: env 0 drifts into the funnel, env 1 drifts past the station beside it (to
    # x = -0.9 + 0.25 * 120 s), envs 2 and 3 never arrive
    m = evaluate(constant_policy(0.0), env, seed=0)
    assert m["failures"]["timeout"] == 3
    assert m["timeouts_beyond_station"] == 1
    thirds = {t["oc_x"]: t for t in m["by_current_x"]}
    assert [t["oc_x"] for t in m["by_current_x"]] == ["opposing", "weak", "following"]
    assert thirds["opposing"]["range"] == [-0.3, -0.1]
    assert [thirds[k]["episodes"] for k in ("opposing", "weak", "following")] == [1, 1, 2]
    assert thirds["opposing"]["failures"]["timeout"] == 1
    assert thirds["weak"]["failures"]["timeout"] == 1
    assert thirds["following"]["failures"]["timeout"] == 1
    for key in ("timeout", "missed_funnel", "too_fast"):
        assert sum(t["failures"][key] for t in thirds.values()) == m["failures"][key]
    successes = sum(t["success_rate"] / 100 * t["episodes"] for t in thirds.values())
    assert successes == pytest.approx(m["success_rate"] / 100 * 4)


def test_currents_outside_the_range_count_in_the_outer_thirds():
    n = 4
    outcomes = {
        "success": torch.tensor([True, False, False, True]),
        "docked": torch.tensor([True, False, False, True]),
        "contact_score": torch.tensor([0.5, 0.0, 0.0, 0.9]),
        "contact_speed": torch.tensor([0.2, 0.0, 0.0, 0.1]),
        "steps": torch.full((n,), 100),
        "total_reward": torch.zeros(n),
        "ocean_current": torch.tensor([[-0.35, 0.0], [-0.3, 0.0], [0.0, 0.0], [0.35, 0.0]]),
        "end": torch.tensor([[-0.5, 0.0, 0.0], [0.2, 3.0, 0.0], [-9.0, 0.0, 0.0], [-0.1, 0, 0]]),
    }
    m = summarize(outcomes, 0.2, 0.3, (-0.3, 0.3), entrance_x=0.0)
    assert [t["episodes"] for t in m["by_current_x"]] == [2, 1, 1]
    assert [t["success_rate"] for t in m["by_current_x"]] == [50.0, 0.0, 100.0]
    assert m["timeouts_beyond_station"] == 1
    assert summarize(outcomes, 0.2, 0.3, entrance_x=0.5)["timeouts_beyond_station"] == 0


def test_episodes_are_split_by_the_strength_of_the_lateral_current():
    n = 5
    outcomes = {
        "success": torch.tensor([True, False, True, False, True]),
        "docked": torch.tensor([True, True, True, False, True]),
        "contact_score": torch.tensor([0.5, 0.4, 0.9, 0.0, 0.8]),
        "contact_speed": torch.tensor([0.2, 0.45, 0.1, 0.0, 0.25]),
        "steps": torch.full((n,), 100),
        "total_reward": torch.zeros(n),
        # |oc_y|: 0.05 weak; 0.15 moderate; -0.25, 0.2 and -0.35 (beyond the range) strong
        "ocean_current": torch.tensor(
            [[0.0, 0.05], [0.0, -0.25], [0.3, 0.15], [0, 0.2], [0, -0.35]]
        ),
        "end": torch.tensor([[-0.5, 0.0, 0.0]] * n),
    }
    split = summarize(outcomes, 0.2, 0.3, (-0.3, 0.3))["by_current_y"]
    assert [t["abs_oc_y"] for t in split] == ["weak", "moderate", "strong"]
    assert [t["range"] for t in split] == [[0.0, 0.1], [0.1, 0.2], [0.2, 0.3]]
    assert [t["episodes"] for t in split] == [1, 1, 3]
    assert [t["success_rate"] for t in split] == [100.0, 100.0, pytest.approx(100 / 3)]
    assert split[2]["failures"] == {"timeout": 1, "missed_funnel": 0, "too_fast": 1}
    # an asymmetric range splits |oc_y| up to its larger bound
    wide = summarize(outcomes, 0.2, 0.3, (-0.6, 0.3))["by_current_y"]
    assert [t["range"] for t in wide] == [[0.0, 0.2], [0.2, 0.4], [0.4, 0.6]]
    assert [t["episodes"] for t in wide] == [2, 3, 0]
    assert wide[2]["success_rate"] is None


def test_success_map_and_plots(tmp_path):
    result = success_map(ManagedSurgePolicy(), "noise", cells=3, trials=2, seed=1)
    grid = [-0.3, 0.0, 0.3]
    assert result["oc_x"] == pytest.approx(grid) and result["oc_y"] == pytest.approx(grid)
    # the same 18 episodes by hand: trial t of cell (oc_y[i], oc_x[j]) is episode 6 i + 2 j + t
    env = make_env("noise", 18, seed=1)
    currents = [(grid[j], grid[i]) for i in range(3) for j in range(3) for _ in range(2)]
    base_env(env).set_initial_state(ocean_current=torch.tensor(currents, dtype=torch.float64))
    success = run_episodes(ManagedSurgePolicy(), env)["success"].double()
    expected = [
        [100.0 * float(success[6 * i + 2 * j : 6 * i + 2 * j + 2].mean()) for j in range(3)]
        for i in range(3)
    ]
    assert result["success_rate"] == expected
    transposed = [[expected[j][i] for j in range(3)] for i in range(3)]
    assert expected != transposed, "a transposed map would pass"
    assert result["mean_success_rate"] == pytest.approx(sum(map(sum, expected)) / 9)
    png = plot_success_map(result, tmp_path / "map.png")
    assert png.stat().st_size > 10_000
    cases = trajectories(
        ManagedSurgePolicy(),
        [{"start": (-26.0, 3.0, 0.0), "ocean_current": (0.0, 0.0)}],
        "noise",
    )
    assert len(cases[0]["path"]) == round(cases[0]["time_s"] / 0.2) + 1
    assert cases[0]["path"][0] == pytest.approx([-26.0, 3.0, 0.0], abs=1e-6)
    png = plot_trajectories(cases, tmp_path / "traj.png")
    assert png.stat().st_size > 10_000


def test_a_long_footer_wraps_under_the_axes_and_inside_the_figure():
    """A figure's footer (its command, often 400 characters) neither runs off the right edge
    nor over the axes' tick labels: the figure grows by its lines."""
    import matplotlib.pyplot as plt

    from dockingrl.plots import add_footer

    fig, axes = plt.subplots(2, 1, figsize=(7, 4))
    axes[1].set_xlabel("env steps")
    fig.suptitle("title")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    renderer = fig.canvas.get_renderer()
    sizes = [ax.get_tightbbox(renderer).height for ax in axes]
    command = "dockingrl train " + "--filter-params results/filter_ablation/a_long_name.pt " * 8
    lines = add_footer(fig, command + " | AMD EPYC, 2 cores")
    assert lines >= 3 and tuple(fig.get_size_inches()) > (7, 4)
    fig.canvas.draw()
    footer = fig.texts[-1].get_window_extent(renderer)
    width, height = fig.canvas.get_width_height()
    assert footer.x0 >= 0 and footer.x1 <= width and footer.y0 >= 0
    boxes = [ax.get_tightbbox(renderer) for ax in axes]
    assert footer.y1 < min(box.y0 for box in boxes)  # below the lowest tick label
    assert [box.height for box in boxes] == pytest.approx(sizes)  # the axes keep their size
    assert fig.texts[0].get_window_extent(renderer).y1 <= height  # the title stays inside
    plt.close(fig)


def test_cli_eval_writes_a_results_folder(tmp_path, capsys):
    out = tmp_path / "ms"
    code = cli_main(
        [
            "eval",
            "--episodes",
            "20",
            "--out",
            str(out),
            "--map",
            "--map-trials",
            "1",
            "--trajectories",
            "--quiet",
        ]
    )
    assert code == 0
    printed = capsys.readouterr().out
    metrics = json.loads((out / "eval.json").read_text())
    assert metrics["episodes"] == 20 and "dockingrl eval" in metrics["command"]
    # the command's defaults: seed 0, the paper's speed limit; its row, then the paper's
    expected = evaluate(ManagedSurgePolicy(), "noise", 20, seed=0)
    for key in ("success_rate", "total_reward", "time_s", "failures"):
        assert metrics[key] == expected[key], key
    row = f"| managed_surge | noise | {expected['success_rate']:.1f} |"
    assert printed.index(row) < printed.index("| managed_surge (paper) | noise | 73.7 |")
    for name in ("success_map.json", "success_map.png", "trajectories.json", "trajectories.png"):
        assert (out / name).stat().st_size > 0, name


def test_bad_evaluation_arguments(capsys):
    with pytest.raises(ValueError, match="num_episodes"):
        evaluate(ManagedSurgePolicy(), "noise", 0)
    with pytest.raises(ValueError, match="unknown scenario"):
        evaluate(ManagedSurgePolicy(), "calm", 5)
    with pytest.raises(SystemExit) as exit_:
        cli_main(["eval", "--policy", "/nonexistent/policy.pt", "--quiet"])
    assert exit_.value.code == 1
    assert "neither 'managed_surge' nor a file" in capsys.readouterr().err


def test_stochastic_evaluation_samples_the_policy_and_says_so():
    """The policy sees ExplorationType.RANDOM only when asked; the metrics name the mode."""
    from torchrl.envs.utils import ExplorationType, exploration_type

    seen = []

    def act(observation):
        seen.append(exploration_type())
        return torch.zeros(*observation.shape[:-1], 2, dtype=observation.dtype)

    policy = TensorDictModule(act, in_keys=["observation"], out_keys=["action"])
    config = DockingConfig(max_steps=3)
    deterministic = evaluate(policy, "noise", 4, seed=0, config=config)
    assert set(seen) == {ExplorationType.DETERMINISTIC}
    assert deterministic["policy_mode"] == "deterministic"
    seen.clear()
    stochastic = evaluate(policy, "noise", 4, seed=0, config=config, stochastic=True)
    assert set(seen) == {ExplorationType.RANDOM}
    assert stochastic["policy_mode"] == "stochastic"


def test_a_trained_policy_is_named_by_its_recipe_else_its_algorithm(monkeypatch):
    """``dockingrl eval`` and ``stress`` title a policy by the recipe it was trained with (a
    ``sac-robust`` ladder is not "sac"); a file without one, by its algorithm."""
    from pathlib import Path

    import dockingrl.agents.saving as saving
    from dockingrl.policies import resolve_policy

    root = Path(__file__).resolve().parents[1]
    path = root / "results" / "robust" / "trials" / "sac-robust__filtered__s102" / "policy.pt"
    _, name, scenario, _, meta = resolve_policy(str(path))
    assert (name, scenario, meta["algo"]) == ("sac-robust", "filtered", "sac")
    loaded = saving.load_policy(str(path))
    without = {
        **loaded[1],
        "config": {k: v for k, v in loaded[1]["config"].items() if k != "recipe"},
    }
    monkeypatch.setattr(saving, "load_policy", lambda spec, device="cpu": (loaded[0], without))
    assert resolve_policy(str(path))[1] == "sac"


def test_eval_takes_noise_free_usbl_readings_as_training_does(tmp_path):
    """A noise scale of 0 (the USBL's readings exact) is accepted by eval as by training."""
    out = tmp_path / "exact"
    argv = ["eval", "--range-noise-scale", "0", "--bearing-noise-scale", "0", "--episodes", "8"]
    assert cli_main([*argv, "--seed", "3", "--out", str(out), "--quiet"]) == 0
    assert json.loads((out / "eval.json").read_text())["episodes"] == 8


def test_eval_help_states_success_map_s_own_default_trials(capsys):
    with pytest.raises(SystemExit):
        cli_main(["eval", "--help"])
    default = inspect.signature(success_map).parameters["trials"].default
    assert f"default {default}, success_map's" in " ".join(capsys.readouterr().out.split())
