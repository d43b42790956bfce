"""The task's mirror symmetry (``y -> -y``) and the replay augmentation built on it
(``--mirror-augment``)."""

import json

import pytest
import torch
from helpers import smoke_config
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from dockingrl import make_env
from dockingrl.agents import mirror_transitions
from dockingrl.agents.config import make_config
from dockingrl.env import DockingConfig
from dockingrl.scenarios import (
    MIRROR_PAIR,
    MIRROR_STATE,
    check_mirror_symmetric,
    make_filter,
    mirror_signs,
)
from dockingrl.training import train
from dockingrl.transforms.ekf import ekf_step

STATE_SIGNS = torch.tensor(MIRROR_STATE)  # EKF state [x, y, alpha, nu, w]
PAIR = torch.tensor(MIRROR_PAIR)


def test_the_env_is_symmetric_under_the_mirror_and_mirror_transitions_maps_one_onto_the_other():
    """A noise-free env started at the mirrored pose and current and driven with the mirrored
    commands gives the mirrored observations (current and previous command included) and
    the same rewards and ends: mirror_transitions of one rollout is the other rollout."""
    n, steps = 8, 150
    g = torch.Generator().manual_seed(0)
    pose = torch.stack(
        (
            -5.0 - 3.0 * torch.rand(n, generator=g),
            2.0 * torch.rand(n, generator=g) - 1.0,
            0.5 * torch.rand(n, generator=g) - 0.25,
        ),
        -1,
    )
    current = 0.2 * torch.rand(n, 2, generator=g) - 0.1  # near the station, weak currents
    options = {"observe_current": True, "observe_command": True}
    env, mirrored = (
        make_env("no_noise", n, seed=0, **options),
        make_env("no_noise", n, seed=0, **options),
    )
    env.base_env.set_initial_state(pose, current)
    mirrored.base_env.set_initial_state(pose * torch.tensor([1.0, -1.0, -1.0]), current * PAIR)
    # a steering behaviour, so that episodes dock; the mirrored env gets the mirrored command
    td_a, td_b, steps_a, steps_b = env.reset(), mirrored.reset(), [], []
    for _ in range(steps):
        psi = td_a["observation"][:, 1]
        action = torch.stack((torch.full_like(psi, 0.5), (0.8 * psi).clamp(-0.3, 0.3)), -1)
        steps_a.append(env.step(td_a.set("action", action)).clone())
        steps_b.append(mirrored.step(td_b.set("action", action * PAIR)).clone())
        td_a, td_b = step_mdp(steps_a[-1]), step_mdp(steps_b[-1])
    a, b = torch.stack(steps_a, dim=-1), torch.stack(steps_b, dim=-1)
    signs = mirror_signs("no_noise", **options)
    assert signs.tolist() == [1, -1, -1, 1, -1, -1, 1, -1, 1, -1]
    m = mirror_transitions(a.select("observation", "action", "next"), signs)
    torch.testing.assert_close(m["observation"], b["observation"], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(
        m["next", "observation"], b["next", "observation"], rtol=1e-4, atol=1e-4
    )
    torch.testing.assert_close(m["action"], b["action"])
    torch.testing.assert_close(a["next", "reward"], b["next", "reward"], rtol=1e-4, atol=1e-4)
    assert torch.equal(a["next", "done"], b["next", "done"])
    assert bool(a["next", "terminated"].any())  # some contacts, whose reward is eq. 12's
    # the unmirrored rollout is not already symmetric: the check can fail
    assert not torch.allclose(a["observation"], b["observation"], atol=1e-3)


def test_the_ekf_is_symmetric_under_the_mirror():
    ekf = make_filter(DockingConfig())
    g = torch.Generator().manual_seed(1)
    n = 64
    mean = torch.cat(
        (
            torch.rand(n, 2, generator=g) * 20 - torch.tensor([25.0, 10.0]),
            torch.rand(n, 3, generator=g) - 0.5,
        ),
        -1,
    )
    a = torch.randn(n, 5, 5, generator=g)
    cov = a @ a.transpose(-1, -2) * 0.01 + torch.eye(5) * 0.01
    action = torch.rand(n, 2, generator=g) * torch.tensor([1.2, 0.6]) - torch.tensor([0.4, 0.3])
    current = torch.rand(n, 2, generator=g) * 0.6 - 0.3
    from dockingrl.transforms.ekf import measurement_function

    z = measurement_function(mean, current) + 0.01 * torch.randn(n, 6, generator=g)
    Q, R = ekf.noise_covariances(mean, action, z, torch.zeros(n))
    out = ekf_step(mean, cov, action, z, current, Q, R, 0.2, diagonal=True)
    S = torch.diag(STATE_SIGNS)
    obs_signs = mirror_signs("noise")
    mirrored = ekf_step(
        mean * STATE_SIGNS,
        S @ cov @ S,
        action * PAIR,
        z * obs_signs,
        current * PAIR,
        Q,
        R,
        0.2,
        diagonal=True,
    )
    torch.testing.assert_close(mirrored[0], out[0] * STATE_SIGNS, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(mirrored[1], S @ out[1] @ S, rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(mirrored[2], out[2] * obs_signs, rtol=1e-4, atol=1e-5)


def test_mirror_signs_follow_the_observation_layout():
    assert mirror_signs("compound").tolist() == [1, -1, -1, 1, -1, -1] * 2
    assert len(mirror_signs("compound", observe_current=True, observe_command=True)) == 16
    with pytest.raises(ValueError, match="unknown scenario"):
        mirror_signs("noisy")
    with pytest.raises(ValueError, match="mirror signs"):
        td = make_env("compound", 2, seed=0).rollout(3)
        mirror_transitions(td, mirror_signs("noise"))


def test_mirror_augment_stores_each_transition_twice(tmp_path):
    from dockingrl.agents import make_agent

    env = make_env("compound", 4, seed=0, observe_command=True)
    cfg = make_config(
        "sac", "paper", hidden=(32, 32), batch_size=16, observe_command=True, mirror_augment=True
    )
    agent = make_agent(cfg, 14, env.action_spec[0], 30.0)
    data = env.rollout(10, break_when_any_done=False)  # (4, 10)
    agent.learn(data, num_updates=2)
    assert len(agent.replay_buffer) == 80
    stored = agent.replay_buffer.storage[:80]
    signs = mirror_signs("compound", observe_command=True)
    torch.testing.assert_close(stored["observation"][40:], stored["observation"][:40] * signs)
    torch.testing.assert_close(stored["action"][40:], stored["action"][:40] * PAIR)
    assert torch.equal(stored["next", "reward"][40:], stored["next", "reward"][:40])


def test_training_with_mirror_augment(tmp_path, short_episodes):
    cfg = smoke_config(
        "td3",
        "noise",
        tmp_path,
        "mirror",
        total_steps=256,
        start_steps=64,
        frames_per_batch=64,
        eval_every=256,
        mirror_augment=True,
    )
    assert train(cfg, progress=False)["summary"]["frames"] == 256
    with pytest.raises(ValueError, match="privileged_critic"):
        make_config("sac", "paper", mirror_augment=True, privileged_critic=True)


def test_mirror_augment_refuses_a_filter_that_breaks_the_symmetry(tmp_path):
    """A learned Q with a y-x cross term is not mirror-symmetric: training refuses to
    mirror with it, and accepts the same file with the cross term removed."""
    from dockingrl.training import Trainer

    ekf = make_filter(DockingConfig())
    with torch.no_grad():
        ekf.process_noise.off_diag[0] = 0.5  # the (y, x) entry of Q's Cholesky factor
    ekf.save_filter_params(tmp_path / "coupled.pt")
    with torch.no_grad():
        ekf.process_noise.off_diag.zero_()
        ekf.process_noise.log_diag.add_(0.3)
    ekf.save_filter_params(tmp_path / "diagonal.pt")
    for name, refused in (("coupled", True), ("diagonal", False)):
        cfg = smoke_config(
            "sac",
            "compound",
            tmp_path,
            name,
            filter_params=str(tmp_path / f"{name}.pt"),
            total_steps=64,
            mirror_augment=True,
        )
        if refused:
            with pytest.raises(ValueError, match="Q couples"):
                Trainer(cfg, tmp_path / name, progress=False)
        else:
            Trainer(cfg, tmp_path / name, progress=False)
    config = DockingConfig(init_y=(-7.5, 5.0))
    with pytest.raises(ValueError, match="init_y"):
        check_mirror_symmetric(make_env("noise", 1, config=config))


@pytest.mark.parametrize("algo", ["sac", "td3", "ppo"])
def test_mirror_symmetric_networks_are_exactly_equivariant(algo):
    """With ``mirror_symmetric`` the actor commands the mirrored command for the mirrored
    observation and the critic values both alike, at any weights; without it they do not."""
    from dockingrl.agents import make_agent

    options = {"observe_current": True, "observe_command": True}
    env = make_env("compound", 1, seed=0, **options)
    signs = mirror_signs("compound", **options)
    obs = torch.randn(64, 16) * 2
    mirrored = TensorDict({"observation": obs * signs}, [64])
    for which in ("all", "actor", "none"):
        cfg = make_config(algo, "paper", hidden=(32, 32), mirror_symmetric=which, **options)
        agent = make_agent(cfg, 16, env.action_spec[0], 30.0)
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            action = agent.actor(TensorDict({"observation": obs}, [64]))["action"]
            action_m = agent.actor(mirrored.clone())["action"]
        same = torch.allclose(action_m, action * PAIR, atol=1e-6)
        assert same == (which != "none")
        if algo == "ppo":
            critic = agent.loss.critic_network
            value = critic(TensorDict({"observation": obs}, [64]))["state_value"]
            value_m = critic(mirrored.clone())["state_value"]
        else:
            critic = agent.loss.qvalue_network
            td = TensorDict({"observation": obs, "action": action}, [64])
            value = critic(td)["state_action_value"]
            td_m = TensorDict({"observation": obs * signs, "action": action * PAIR}, [64])
            value_m = critic(td_m)["state_action_value"]
        assert torch.allclose(value_m, value, atol=1e-6) == (which == "all")
    with pytest.raises(ValueError, match="privileged_critic"):
        make_config("sac", "paper", mirror_symmetric="all", privileged_critic=True)
    make_config("sac", "paper", mirror_symmetric="actor", privileged_critic=True)
    with pytest.raises(
        ValueError, match=r"mirror_symmetric: valid: none, actor, all \(got 'both'\)$"
    ):
        make_config("sac", "paper", mirror_symmetric="both")


def test_a_trained_mirror_symmetric_policy_loads_equivariant(tmp_path, short_episodes):
    from dockingrl.agents.saving import load_policy

    cfg = smoke_config(
        "sac",
        "compound",
        tmp_path,
        "sym",
        total_steps=128,
        start_steps=64,
        frames_per_batch=64,
        eval_every=128,
        mirror_symmetric="actor",
        observe_command=True,
    )
    train(cfg, progress=False)
    actor, info = load_policy(tmp_path / "sym" / "policy.pt")
    assert info["config"]["mirror_symmetric"] == "actor"
    obs = torch.randn(32, 14)
    signs = mirror_signs("compound", observe_command=True)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        action = actor(TensorDict({"observation": obs}, [32]))["action"]
        action_m = actor(TensorDict({"observation": obs * signs}, [32]))["action"]
    torch.testing.assert_close(action_m, action * PAIR, atol=1e-6, rtol=0)
    # its mirror commands the same: dockingrl eval --mirrored scores it the same
    from dockingrl.cli import main as cli_main

    policy = str(tmp_path / "sym" / "policy.pt")
    for extra in ((), ("--mirrored",)):
        out = tmp_path / f"eval{len(extra)}"
        assert (
            cli_main(
                [
                    "eval",
                    "--policy",
                    policy,
                    "--episodes",
                    "4",
                    "--quiet",
                    "--out",
                    str(out),
                    *extra,
                ]
            )
            == 0
        )
    plain, mirrored = (
        json.loads((tmp_path / f"eval{i}" / "eval.json").read_text()) for i in (0, 1)
    )
    assert plain["total_reward"] == mirrored["total_reward"]
    # the onboard program exported from it commands what the actor commands
    from dockingrl.onboard import OnboardPolicy, export_onboard

    onboard = OnboardPolicy.from_file(tmp_path / "sym" / "policy.pt")
    program = torch.export.load(export_onboard(onboard, tmp_path / "sym.pt2", batch=2)).module()
    z, current = torch.randn(2, 6).abs() + 1.0, torch.zeros(2, 2)
    state = onboard.initial_state(2)
    torch.testing.assert_close(program(z, current, *state)[0], onboard.step(z, current, *state)[0])


def test_mirrored_policy(tmp_path):
    """Mirroring twice gives the policy back; a plain actor's mirror is another policy; a
    mirror-symmetric actor is its own mirror; ``dockingrl eval --mirrored`` needs an agent."""
    from dockingrl.agents import MirroredPolicy, build_actor
    from dockingrl.cli import main as cli_main

    env = make_env("compound", 1, seed=0)
    signs = mirror_signs("compound")
    obs = TensorDict({"observation": torch.randn(64, 12)}, [64])
    for which in ("none", "actor"):
        torch.manual_seed(0)
        cfg = make_config("sac", "paper", hidden=(32, 32), mirror_symmetric=which)
        actor = build_actor(cfg, 12, env.action_spec[0], 30.0)
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            action = actor(obs.clone())["action"]
            once = MirroredPolicy(actor, signs)(obs.clone())["action"]
            twice = MirroredPolicy(MirroredPolicy(actor, signs), signs)(obs.clone())["action"]
        torch.testing.assert_close(twice, action)
        assert torch.equal(once, action) == (which == "actor")
    with pytest.raises(SystemExit, match="saved agent"):
        cli_main(["eval", "--mirrored", "--episodes", "2", "--quiet"])
