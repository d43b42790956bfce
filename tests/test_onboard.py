"""The onboard policy (raw readings in, commands out) against the training env's pipeline."""

import subprocess
import sys

import pytest
import torch
from helpers import PPO_COMPOUND_POLICY, step_onboard, tiny_actor
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from dockingrl import make_env
from dockingrl.env import DockingConfig
from dockingrl.onboard import OnboardPolicy

SCENARIO_DIMS = {"noise": 6, "filtered": 6, "compound": 12}


def random_actor(algo, scenario, observe_current=False, seed=0):
    return tiny_actor(SCENARIO_DIMS[scenario] + (2 if observe_current else 0), algo, seed)


def expected_input(scenario, compound, current, observe_current):
    """What the training env of ``scenario`` gives the actor, cut from a compound env's
    observation (raw readings, then the EKF's filtered ones)."""
    raw, filtered = compound[..., :6], compound[..., 6:]
    obs = {"noise": raw, "filtered": filtered, "compound": compound}[scenario]
    return torch.cat((obs, current), -1) if observe_current else obs


@pytest.mark.parametrize("algo", ["sac", "td3"])
@pytest.mark.parametrize("scenario", ["noise", "filtered", "compound"])
def test_onboard_commands_match_the_env_pipeline_across_resets(algo, scenario):
    observe_current = scenario == "compound"
    actor = random_actor(algo, scenario, observe_current)
    onboard = OnboardPolicy(actor, scenario, observe_current=observe_current)
    # its EKF is the one the onboard policy runs; short episodes, so that envs reset mid-way
    env = make_env("compound", 16, seed=3, config=DockingConfig(max_steps=45))
    td = env.reset()
    resets = 0
    for _ in range(100):
        current = td["ocean_current"]
        command = onboard.act(td["observation"][..., :6], current)
        obs = expected_input(scenario, td["observation"], current, observe_current)
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            expected = actor(TensorDict({"observation": obs}, batch_size=[16]))["action"]
        torch.testing.assert_close(command, expected, rtol=1e-5, atol=1e-6)
        td, done = step_onboard(env, td, command, onboard)
        resets += int(done.sum())
    assert resets > 0  # episodes ended and the filter was re-initialised in those envs


def test_onboard_policy_loads_learned_filter_params_with_their_range_sigma(tmp_path):
    from dockingrl.scenarios import make_filter

    ekf = make_filter(DockingConfig(), range_noise_from="estimate")
    with torch.no_grad():
        ekf.measurement_noise.log_std[:2] += 0.7  # a learned USBL
    ekf.save_filter_params(tmp_path / "q_r.pt")
    actor = random_actor("sac", "filtered")
    onboard = OnboardPolicy(actor, "filtered", filter_params=tmp_path / "q_r.pt")
    assert onboard.step.ekf.range_noise_from == "estimate"
    env = make_env("compound", 8, seed=4, filter_params=tmp_path / "q_r.pt")
    td = env.reset()
    for _ in range(20):
        command = onboard.act(td["observation"][..., :6], td["ocean_current"])
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            obs = TensorDict({"observation": td["observation"][..., 6:]}, batch_size=[8])
            torch.testing.assert_close(command, actor(obs)["action"], rtol=1e-5, atol=1e-6)
        td["action"] = command
        td = env.step_and_maybe_reset(td)[1]


def test_onboard_policy_from_file_takes_the_training_filter_unless_told_none(tmp_path):
    """A policy file carries the learned filter it was trained with; ``filter_params="none"``
    runs Table 1's hand-tuned filter instead (``dockingrl export --filter-params none``)."""
    from dockingrl.agents.config import make_config
    from dockingrl.agents.saving import save_policy
    from dockingrl.scenarios import make_filter
    from dockingrl.transforms.params import read_filter_params

    ekf = make_filter(DockingConfig())
    table_1 = ekf.measurement_noise.log_std.detach().clone()
    with torch.no_grad():
        ekf.measurement_noise.log_std[:2] += 0.7  # a learned USBL
    ekf.save_filter_params(tmp_path / "q_r.pt")
    env = make_env("noise", 1, seed=0)
    cfg = make_config("sac", "paper", scenario="filtered", hidden=(32, 32))
    actor = random_actor("sac", "filtered")
    payload = read_filter_params(tmp_path / "q_r.pt")
    path = save_policy(tmp_path / "p.pt", actor, cfg, 6, env.action_spec, 30.0, payload)

    def usbl_log_std(**kwargs):
        policy = OnboardPolicy.from_file(path, **kwargs)
        return policy.step.ekf.measurement_noise.log_std.detach()

    torch.testing.assert_close(usbl_log_std()[:2], table_1[:2] + 0.7)
    torch.testing.assert_close(usbl_log_std(filter_params="none"), table_1)


def test_onboard_policy_from_a_saved_policy_file():
    """It commands what the saved actor commands in the env of its scenario, read from the
    file, and starts over after a reset."""
    from dockingrl.agents.layout import pipeline_options
    from dockingrl.agents.saving import load_policy

    policy = OnboardPolicy.from_file(PPO_COMPOUND_POLICY)
    actor, info = load_policy(PPO_COMPOUND_POLICY)
    assert policy.scenario == info["scenario"] == "compound" and policy.uses_filter
    env = make_env("compound", 4, seed=2, **pipeline_options(info["config"]))
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(10):
            expected = actor(td.select("observation"))["action"]
            command = policy.act(td["observation"][..., :6], td["ocean_current"])
            torch.testing.assert_close(command, expected, rtol=1e-5, atol=1e-6)
            td = env.step(td.set("action", command))["next"]
    policy.reset()
    z = torch.tensor([25.0, 0.2, 0.1, 0.5, 0.0, 0.0])
    first = policy.act(z, torch.tensor([0.1, -0.1]))
    assert first.shape == (2,) and bool(torch.isfinite(first).all())
    policy.act(z, torch.tensor([0.1, -0.1]))  # a second step runs the filter
    policy.reset()
    torch.testing.assert_close(policy.act(z, torch.tensor([0.1, -0.1])), first)


def test_onboard_policy_refuses_bad_readings():
    policy = OnboardPolicy(random_actor("sac", "compound"), "compound")
    with pytest.raises(ValueError, match=r"\(vehicles, 6\)"):
        policy.act(torch.zeros(5), torch.zeros(2))
    with pytest.raises(ValueError, match="finite"):
        policy.act(torch.tensor([1.0, 0, 0, 0, 0, float("nan")]), torch.zeros(2))
    with pytest.raises(ValueError, match="z must be real numbers, got dtype torch.bool"):
        policy.act(torch.ones(6, dtype=torch.bool), torch.zeros(2))
    with pytest.raises(ValueError, match="current must be real numbers, got dtype torch.complex"):
        policy.act(torch.zeros(6), torch.zeros(2, dtype=torch.complex64))
    with pytest.raises(ValueError, match=r"z must be real numbers of shape \(6,\) .*, got str"):
        policy.act("abc", torch.zeros(2))
    with pytest.raises(ValueError, match=r"z's range .* must be >= 0 m"):
        policy.act(
            torch.tensor([[20.0, 0, 0, 0, 0, 0], [-10.0, 0.5, 0, 0.3, 0, 0]]), torch.zeros(2, 2)
        )
    assert policy.filter_state is None  # refused before the filter starts
    policy.act(torch.tensor([20.0, 0, 0, 0, 0, 0]), torch.zeros(2))
    with pytest.raises(ValueError, match="reset"):
        policy.act(torch.zeros(3, 6), torch.zeros(3, 2))
    with pytest.raises(ValueError, match="must hold the same vehicles"):
        policy.act(torch.zeros(2, 6), torch.zeros(3, 2))
    with pytest.raises(ValueError, match="must hold the same vehicles"):
        policy.act(torch.zeros(6), torch.zeros(3, 2))
    for mask in (torch.ones(3, dtype=torch.bool), torch.tensor([1])):
        with pytest.raises(ValueError, match=r"mask must be a bool tensor of shape \(1,\)"):
            policy.reset(mask)
    with pytest.raises(ValueError, match="unknown scenario"):
        OnboardPolicy(random_actor("sac", "noise"), "noisy")
    with pytest.raises(TypeError, match="load_policy returns the pair"):
        OnboardPolicy((random_actor("sac", "noise"), {}), "noise")
    with pytest.raises(TypeError, match="actor must be a module"):
        OnboardPolicy(None, "noise")
    with pytest.raises(ValueError, match="no filter"):
        OnboardPolicy(random_actor("sac", "noise"), "noise", filter_params="x.pt")


def test_a_loaded_actor_is_refused_by_an_env_that_does_not_give_its_observation(tmp_path):
    """The Python API checks a saved policy against the env it is given, as the command line
    does: a ``compound`` policy in a ``filtered`` or ``noise`` env, or without the options it
    was trained with, is refused in one line, never run on the wrong numbers."""
    from dockingrl import evaluate
    from dockingrl.agents.saving import load_policy
    from dockingrl.io import ArtifactError

    actor, info = load_policy(PPO_COMPOUND_POLICY)
    for scenario in ("filtered", "noise"):
        with pytest.raises(ArtifactError, match="was trained on scenario 'compound'") as said:
            evaluate(actor, scenario, 2, **info["env_options"])
        assert "\n" not in str(said.value)
        with pytest.raises(ArtifactError, match="but the env gives scenario"):
            OnboardPolicy(actor, scenario)
    assert 0 <= evaluate(actor, "compound", 2, **info["env_options"])["success_rate"] <= 100
    with pytest.raises(TypeError, match="config must be a DockingConfig, got dict"):
        OnboardPolicy.from_file(PPO_COMPOUND_POLICY, config={"dt": 0.1})
    with pytest.raises(ValueError, match="not a torch device: 'bogus'"):
        load_policy(PPO_COMPOUND_POLICY, device="bogus")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="CUDA is not available"):
            load_policy(PPO_COMPOUND_POLICY, device="cuda")


@pytest.mark.parametrize("bad", [float("nan"), 0.0, -50.0, float("inf")])
def test_a_filter_response_rate_that_is_not_a_positive_number_is_refused(bad):
    with pytest.raises(ValueError, match="k_v must be a positive number"):
        make_env("filtered", 2, ekf_kwargs={"k_v": bad})
    with pytest.raises(ValueError, match="k_w must be a positive number"):
        OnboardPolicy(random_actor("sac", "filtered"), "filtered", k_w=bad)


def test_onboard_policy_never_returns_a_non_finite_command():
    policy = OnboardPolicy(random_actor("sac", "compound"), "compound")
    z, current = torch.tensor([20.0, 0.1, 0, 0.5, 0, 0]), torch.zeros(2)
    policy.act(z, current)
    state = policy._state
    with torch.no_grad():  # weights gone bad after loading (a file's are checked on load)
        next(policy.step.actor.parameters()).fill_(float("nan"))
    with pytest.raises(RuntimeError, match="non-finite command"):
        policy.act(z, current)
    assert policy._state is state  # the filter's state is not advanced by a refused step


def test_exported_onboard_program_runs_with_torch_alone(tmp_path):
    from dockingrl.onboard import export_onboard

    policy = OnboardPolicy.from_file(PPO_COMPOUND_POLICY)
    path = export_onboard(policy, tmp_path / "onboard.pt2", batch=2)
    program = torch.export.load(path).module()
    env = make_env("compound", 2, seed=11, config=DockingConfig(max_steps=40))
    td = env.reset()
    state = policy.initial_state(2)
    for _ in range(60):
        z, current = td["observation"][..., :6], td["ocean_current"]
        command, *filter_state = program(z, current, *state)
        torch.testing.assert_close(command, policy.act(z, current), rtol=1e-5, atol=1e-6)
        state = (filter_state[0], filter_state[1], command, filter_state[2])
        td, done = step_onboard(env, td, command, policy)
        state = (*state[:3], torch.where(done.view(-1, 1), -1.0, state[3]))

    # the program needs torch alone: load and run it where dockingrl, TorchRL and tensordict
    # cannot be imported
    script = f"""
import sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('torchrl', 'tensordict', 'dockingrl'):
            raise ImportError(name)
sys.meta_path.insert(0, Block())
import torch
step = torch.export.load({str(path)!r}).module()
z = torch.tensor([[20.0, 0.3, 0.1, 0.5, 0.0, 0.0]] * 2)
state = (torch.zeros(2, 5), torch.eye(5).repeat(2, 1, 1), torch.zeros(2, 2), -torch.ones(2, 1))
command = step(z, torch.zeros(2, 2), *state)[0]
assert command.shape == (2, 2) and not command.requires_grad
print('ok')
"""
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert run.returncode == 0 and run.stdout.strip() == "ok", run.stderr[-2000:]


def test_export_cli(tmp_path, capsys):
    from dockingrl.cli import main as cli_main

    out = tmp_path / "onboard.pt2"
    policy = str(PPO_COMPOUND_POLICY)
    assert cli_main(["export", "--policy", policy, "--out", str(out), "--batch", "3"]) == 0
    assert out.stat().st_size > 0 and "3 vehicle(s)" in capsys.readouterr().out
    for bad, code, says in (
        (["--batch", "0"], 2, "argument --batch: must be an integer >= 1"),
        (["--policy", str(tmp_path / "none.pt")], 1, "none.pt: no such file"),
    ):
        with pytest.raises(SystemExit) as exit_:
            cli_main(["export", "--policy", policy, "--out", str(out), *bad])
        assert exit_.value.code == code and says in capsys.readouterr().err


def test_onboard_command_is_clipped_to_the_bounds_as_the_env_applies_it():
    """An actor's command beyond the bounds (eq. 3) comes out clipped, as the env applies it
    and as ``PreviousAction`` reports it."""

    class Reckless(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.command = torch.nn.Parameter(torch.tensor([2.0, -1.0]))

        def forward(self, td):
            td["action"] = self.command.expand(td.shape[0], 2)
            return td

    policy = OnboardPolicy(Reckless(), "noise")
    command = policy.act(torch.tensor([[20.0, 0.1, 0.0, 0.3, 0.0, 0.0]]), torch.zeros(1, 2))
    config = DockingConfig()
    expected = torch.tensor([[config.surge_command_max, -config.yaw_rate_command_max]])
    assert torch.equal(command, expected)
