"""The previous command as an observation (``--observe-command``): the env transform, the
onboard policy, its exported program and training agree on what the actor reads."""

import pytest
import torch
from helpers import smoke_config, tiny_actor
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, check_env_specs, set_exploration_type, step_mdp

from dockingrl import make_env
from dockingrl.agents.layout import pipeline_options
from dockingrl.agents.saving import load_policy
from dockingrl.env import DockingConfig
from dockingrl.onboard import OnboardPolicy, export_onboard
from dockingrl.training import train
from dockingrl.transforms import PreviousAction


def test_previous_action_is_the_applied_command_and_zero_after_a_reset():
    n = 16
    config = DockingConfig(max_steps=7)  # episodes end (and auto-reset) every 7 steps
    env = make_env("compound", n, seed=2, config=config, observe_current=True, observe_command=True)
    plain = make_env("compound", n, seed=2, config=config, observe_current=True)
    assert env.observation_spec["observation"].shape == (n, 16)
    td, ref = env.reset(), plain.reset()
    assert torch.equal(td["observation"][:, :14], ref["observation"])
    assert torch.equal(td["observation"][:, 14:], torch.zeros(n, 2))
    g = torch.Generator().manual_seed(0)
    resets = 0
    for t in range(10):
        # beyond the bounds in half the rows: the observation holds the command as applied
        action = torch.rand(n, 2, generator=g) * torch.tensor([3.0, 1.5]) - torch.tensor(
            [1.0, 0.75]
        )
        td["action"], ref["action"] = action, action
        out, td = env.step_and_maybe_reset(td)
        ref_out, ref = plain.step_and_maybe_reset(ref)
        applied = action.clamp(torch.tensor([-0.4, -0.3]), torch.tensor([0.8, 0.3]))
        assert torch.equal(out["next", "observation"][:, 14:], applied)
        assert torch.equal(out["next", "observation"][:, :14], ref_out["next", "observation"])
        done = out["next", "done"].squeeze(-1)
        resets += int(done.sum())
        # envs that started over read zeros, the others still the command they just applied
        expected = torch.where(done.unsqueeze(-1), torch.zeros(n, 2), applied)
        assert torch.equal(td["observation"][:, 14:], expected), t
    assert resets == n  # every env ended once, at step 7
    check_env_specs(env)


def test_a_partial_reset_zeroes_the_reset_envs_only():
    env = make_env("noise", 4, seed=1, observe_command=True)
    td = env.reset()
    action = torch.tensor([[0.5, 0.1], [0.2, -0.2], [-0.3, 0.3], [0.7, 0.0]])
    td = step_mdp(env.step(td.set("action", action)))
    assert torch.equal(td["observation"][:, 6:], action)
    td["_reset"] = torch.tensor([True, False, True, False]).unsqueeze(-1)
    td = env.reset(td)
    expected = action.clone()
    expected[[0, 2]] = 0.0
    assert torch.equal(td["observation"][:, 6:], expected)


def test_previous_action_refuses_bad_bounds_and_standalone_use():
    with pytest.raises(ValueError, match="low < high"):
        PreviousAction([0.8, 0.3], [-0.4, -0.3])
    with pytest.raises(RuntimeError, match="TransformedEnv"):
        PreviousAction([-0.4, -0.3], [0.8, 0.3])(TensorDict({}, []))


@pytest.mark.parametrize(("scenario", "repeat"), [("noise", 1), ("compound", 1), ("compound", 3)])
def test_onboard_policy_reads_its_previous_command_as_the_training_env_gave_it(scenario, repeat):
    """The onboard policy, fed each 0.2 s reading, commands what the actor commands stepping
    the env with ``observe_command=True`` (and, with ``repeat``, the hold), across resets."""
    n = 8
    dim = (12 if scenario == "compound" else 6) + 2
    actor = tiny_actor(dim)
    onboard = OnboardPolicy(actor, scenario, observe_command=True, action_repeat=repeat)
    config = DockingConfig(max_steps=30)  # episodes end twice, at the end of a hold
    held = make_env(scenario, n, seed=5, config=config, observe_command=True, action_repeat=repeat)
    stepwise = make_env(scenario, n, seed=5, config=config)
    tdk, td1 = held.reset(), stepwise.reset()
    resets = 0
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(70 // repeat):
            action = actor(tdk.select("observation"))["action"]
            out, tdk = held.step_and_maybe_reset(tdk.set("action", action))
            for j in range(repeat):
                command = onboard.act(td1["observation"][..., :6], td1["ocean_current"])
                if j == 0:
                    torch.testing.assert_close(command, action, rtol=1e-5, atol=1e-6)
                step, td1 = stepwise.step_and_maybe_reset(td1.set("action", command))
                onboard.reset(step["next", "done"].squeeze(-1))
            done = out["next", "done"].squeeze(-1)
            resets += int(done.sum())
    assert resets == 2 * n


@pytest.mark.parametrize(("scenario", "dim"), [("noise", 8), ("compound", 14)])
def test_exported_onboard_program_reads_its_previous_command_too(tmp_path, scenario, dim):
    policy = OnboardPolicy(tiny_actor(dim), scenario, observe_command=True)
    program = torch.export.load(export_onboard(policy, tmp_path / "p.pt2")).module()
    reference = OnboardPolicy(tiny_actor(dim), scenario, observe_command=True)
    env = make_env("compound", 1, seed=7)
    td = env.reset()
    state = policy.initial_state(1)
    for _ in range(5):
        z, current = td["observation"][..., :6], td["ocean_current"]
        command, mean, cov, age = program(z, current, *state)
        torch.testing.assert_close(command, reference.act(z, current), rtol=1e-5, atol=1e-6)
        # the same step with another previous command decides otherwise: the actor reads it
        # (without a filter, "noise", nothing else in the step does)
        other = program(z, current, state[0], state[1], -state[2] + 0.1, state[3])[0]
        if state[3].item() >= 0:
            assert not torch.allclose(other, command)
        state = (mean, cov, command, age)
        td = step_mdp(env.step(td.set("action", command)))


def test_training_saves_observe_command_with_the_policy(tmp_path, short_episodes):
    cfg = smoke_config(
        "td3",
        "noise",
        tmp_path,
        "cmd",
        total_steps=256,
        start_steps=64,
        frames_per_batch=64,
        eval_every=256,
        observe_command=True,
    )
    train(cfg, progress=False)
    actor, info = load_policy(tmp_path / "cmd" / "policy.pt")
    assert pipeline_options(info["config"]) == {"observe_command": True}
    first = next(m for m in actor.modules() if isinstance(m, torch.nn.Linear))
    assert first.in_features == 8  # 6 noisy readings + the previous command
    assert OnboardPolicy.from_file(tmp_path / "cmd" / "policy.pt").step.observe_command
