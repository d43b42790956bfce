import pytest
import torch
from tensordict.nn import TensorDictModule
from torchrl.envs import Compose, ObservationNorm, TransformedEnv
from torchrl.envs.utils import check_env_specs

from dockingrl import SCENARIOS, make_env
from dockingrl.env import DockingConfig, DockingEnv, observation_from_state, wrap_angle
from dockingrl.scenarios import OBSERVATION_PARTS, observation_layout
from dockingrl.transforms import CompoundObservation, EKFTransform
from dockingrl.upgrade import upgrade_file


def true_observation(td):
    x, y, alpha, u, v, r = td["true_state"].unbind(-1)
    return observation_from_state(x, y, alpha, u, v, r, td["ocean_current"])


def bearing_action(observation):
    """A smooth behaviour: cruise at 0.5 m/s, turn towards the measured bearing."""
    psi = observation[..., 1]
    return torch.stack((torch.full_like(psi, 0.5), (0.5 * psi).clamp(-0.3, 0.3)), -1)


def bearing_policy(td):
    return bearing_action(td["observation"])


BEARING = TensorDictModule(bearing_action, in_keys=["observation"], out_keys=["action"])


@pytest.mark.parametrize("scenario", list(SCENARIOS))
@pytest.mark.parametrize("num_envs", [1, 64])
def test_check_env_specs_all_scenarios(scenario, num_envs):
    env = make_env(scenario, num_envs, seed=0)
    check_env_specs(env)
    dims = {"no_noise": 6, "noise": 6, "filtered": 6, "compound": 12}
    assert env.observation_spec["observation"].shape == (num_envs, dims[scenario])


@pytest.mark.parametrize("scenario", ["noise", "compound"])
@pytest.mark.parametrize("current,command", [(True, False), (False, True), (True, True)])
def test_observation_follows_its_layout(scenario, current, command):
    """The scenario's own entries first (as without the options), then the current, then the
    previous command, at reset and after a step; the layout's widths give the spec's."""
    options = {"observe_current": current, "observe_command": command}
    env, plain = make_env(scenario, 16, seed=3, **options), make_env(scenario, 16, seed=3)
    layout = observation_layout(scenario, **options)
    assert layout[-1] == ("previous_action" if command else "ocean_current")
    widths = [len(OBSERVATION_PARTS[key]) for key in layout]
    assert env.observation_spec["observation"].shape == (16, sum(widths))
    td, ref = env.reset(), plain.reset()
    action = torch.tensor([[0.5, 0.1]]).expand(16, 2)
    for _ in range(2):
        pieces = td["observation"].split(widths, -1)
        torch.testing.assert_close(
            torch.cat(pieces[: len(layout) - current - command], -1), ref["observation"]
        )
        for key, piece in zip(layout, pieces, strict=True):
            if key in ("ocean_current", "previous_action"):
                torch.testing.assert_close(piece, td[key])
        td = env.step(td.set("action", action))["next"]
        ref = plain.step(ref.set("action", action))["next"]
    if command:
        torch.testing.assert_close(td["previous_action"], action)
    check_env_specs(env)


def test_observation_scale_leaves_the_current_alone():
    from dockingrl.agents import observation_scale

    scale = observation_scale(14, 30.0, True)
    expected = torch.ones(14)
    expected[[0, 6]] = 1 / 30.0
    assert torch.equal(scale, expected)
    expected = torch.ones(8)
    expected[0] = 1 / 30.0
    assert torch.equal(observation_scale(8, 30.0, True), expected)


def test_unknown_scenario_lists_the_valid_ones():
    with pytest.raises(ValueError, match="no_noise, noise, filtered, compound"):
        make_env("noisy")
    with pytest.raises(ValueError, match="no filter"):
        make_env("noise", ekf_kwargs={"learnable": True})


def test_scenario_observations():
    for scenario in ("no_noise", "noise"):
        td = make_env(scenario, 32, seed=1).rollout(5)
        error = (td["next", "observation"] - true_observation(td["next"])).abs().max()
        assert (error < 1e-5) == (scenario == "no_noise")
    td = make_env("filtered", 32, seed=1).rollout(5)
    torch.testing.assert_close(td["next", "observation"], td["next", "filtered_observation"])
    td = make_env("compound", 32, seed=1).rollout(5)
    obs = td["next", "observation"]
    torch.testing.assert_close(obs[..., 6:], td["next", "filtered_observation"])


def test_compound_raw_part_is_the_noisy_observation():
    noisy = make_env("noise", 16, seed=4)
    compound = make_env("compound", 16, seed=4)
    a, b = noisy.reset(), compound.reset()
    torch.testing.assert_close(b["observation"][:, :6], a["observation"])
    for _ in range(10):
        action = torch.tensor([[0.5, 0.1]]).expand(16, 2)
        a = noisy.step(a.set("action", action))["next"]
        b = compound.step(b.set("action", action))["next"]
        torch.testing.assert_close(b["observation"][:, :6], a["observation"])


def test_filter_beats_the_raw_observation():
    """RMSE of h(EKF estimate) against the true observation, per component, over 512 envs x 300
    steps of a smooth behaviour policy. Measured ratios filtered/raw (seed 0): rho 0.23,
    psi 0.76, alpha 0.41, vx 0.49, vy 0.19, w 0.90; the bounds leave a margin."""
    env = make_env("compound", 512, seed=0)
    td = env.reset()
    raw, filtered, truth = [], [], []
    for _ in range(300):
        td["action"] = bearing_policy(td)
        out, td = env.step_and_maybe_reset(td)
        nxt = out["next"]
        raw.append(nxt["observation"][:, :6])
        filtered.append(nxt["filtered_observation"])
        truth.append(true_observation(nxt))
    truth = torch.stack(truth)

    def rmse(estimate):
        error = torch.stack(estimate) - truth
        error[..., 1:3] = wrap_angle(error[..., 1:3])
        return error.pow(2).mean((0, 1)).sqrt()

    ratio = rmse(filtered) / rmse(raw)
    bound = torch.tensor([0.35, 0.9, 0.55, 0.65, 0.3, 0.97])
    assert (ratio < bound).all(), ratio


def test_covariance_stays_symmetric_positive_definite_over_100000_env_steps():
    """Random actions circling around the docking station, 256 envs for 400 steps: the AUVs
    pass within centimetres of it (rho -> 0) and their headings wrap across +-pi hundreds of
    times. The contact box is moved away so that the filters run uninterrupted."""
    n, steps = 256, 400
    config = DockingConfig(
        init_x=(-3.0, -2.0),
        init_y=(-0.5, 0.5),
        ocean_current_range=(-0.02, 0.02),
        dock_y=(50.0, 50.5),
        max_steps=20_000,
    )
    env = make_env("compound", n, seed=2, config=config)
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    low, width = torch.tensor([0.2, 0.05]), torch.tensor([0.4, 0.25])
    covs, states, filtered = [], [td["true_state"]], []
    for _ in range(steps):
        td["action"] = low + torch.rand(n, 2, generator=gen) * width
        td = env.step(td)["next"]
        covs.append(td["ekf_cov"])
        states.append(td["true_state"])
        filtered.append(td["filtered_observation"])
    assert not td["done"].any()
    cov, state = torch.stack(covs), torch.stack(states)
    assert torch.isfinite(torch.stack(filtered)).all()
    heading = state[..., 2]
    wraps = int(((heading[1:] - heading[:-1]).abs() > 3.0).sum())
    rho = state[1:, :, :2].norm(dim=-1)
    assert float(rho.min()) < 0.02 and int((rho < 0.1).sum()) > 10 and wraps > 300
    assert float(torch.linalg.eigvalsh(cov.double()).min()) > 0
    assert float((cov - cov.transpose(-1, -2)).abs().max()) == 0.0


def test_partial_reset_leaves_other_filters_untouched():
    env = make_env("compound", 6, seed=3)
    td = env.reset()
    for _ in range(5):
        td = env.step(td.set("action", torch.tensor([[0.4, 0.1]]).expand(6, 2)))["next"]
    before = td.clone()
    mask = torch.tensor([True, False, False, True, False, False]).unsqueeze(-1)
    after = env.reset(td.set("_reset", mask))
    keep = ~mask.squeeze(-1)
    for key in ("ekf_mean", "ekf_cov", "filtered_observation", "observation"):
        assert torch.equal(after[key][keep], before[key][keep]), key
        assert not torch.equal(after[key][~keep], before[key][~keep]), key
    # the reset filters start from the new first observation (eq. 26 inverted); vy is not
    # invertible (the state has no sway), it is predicted from the current alone
    explained = [0, 1, 2, 3, 5]
    torch.testing.assert_close(
        after["filtered_observation"][~keep][:, explained],
        after["observation"][~keep][:, explained],
    )


def test_gradients_reach_q_and_r():
    env = make_env("filtered", 8, seed=5, ekf_kwargs={"learnable": True})
    ekf = env.transform[0]
    with torch.enable_grad():
        td = env.rollout(40, policy=BEARING)
        error = td["next", "filtered_observation"] - true_observation(td["next"])
        loss = error.pow(2).mean()
        loss.backward()
    for name, p in ekf.named_parameters():
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, name
    frozen = make_env("filtered", 2, seed=5).transform[0]
    assert not any(p.requires_grad for p in frozen.parameters())


def test_hand_built_pipeline_equals_make_env_and_stacks():
    config = DockingConfig()
    by_hand = TransformedEnv(
        DockingEnv(8, config=config, seed=6),
        Compose(
            EKFTransform(action_low=config.action_low, action_high=config.action_high),
            CompoundObservation(["observation", "filtered_observation"]),
        ),
    )
    ready = make_env("compound", 8, seed=6)
    a, b = by_hand.rollout(20, BEARING), ready.rollout(20, BEARING)
    assert torch.equal(a["next", "observation"], b["next", "observation"])
    norm = ObservationNorm(
        loc=torch.zeros(12), scale=torch.full((12,), 2.0), in_keys=["observation"]
    )
    check_env_specs(make_env("compound", 8, seed=6, transforms=[norm.clone()]))
    stacked = make_env("compound", 8, seed=6, transforms=[norm])

    def on_halved(observation):
        return bearing_action(observation / 2.0)

    halved = TensorDictModule(on_halved, in_keys=["observation"], out_keys=["action"])
    c = stacked.rollout(20, halved)
    torch.testing.assert_close(c["next", "observation"], b["next", "observation"] * 2.0)


def test_compiled_pipeline_matches_eager():
    eager = make_env("compound", 8, seed=7)
    compiled = make_env("compound", 8, seed=7, compile=True)
    a, b = eager.rollout(30, BEARING), compiled.rollout(30, BEARING)
    torch.testing.assert_close(
        b["next", "observation"], a["next", "observation"], rtol=1e-4, atol=1e-4
    )
    torch.testing.assert_close(b["next", "reward"], a["next", "reward"], rtol=1e-4, atol=1e-4)


def test_compiling_without_a_cpp_compiler_is_refused_in_one_line(monkeypatch):
    """torch.compile builds CPU kernels from C++: with no compiler, the env and the filter
    refuse ``compile=True`` at construction, naming the way out, instead of failing later."""
    import dockingrl.env.checks as checks

    monkeypatch.delenv("CXX", raising=False)
    monkeypatch.setattr(checks.shutil, "which", lambda name: None)
    from dockingrl.gym.bare import DockingGymEnv

    for build in (
        lambda: make_env("compound", 2, seed=0, compile=True),
        lambda: EKFTransform(compile=True),
        lambda: DockingGymEnv(compile=True),
        lambda: checks.compiled(lambda: None, "cpu"),  # the gradient step's way in
    ):
        with pytest.raises(ValueError, match="needs a C\\+\\+ compiler.*--no-compile"):
            build()
    make_env("compound", 2, seed=0)  # the eager pipeline needs none
    monkeypatch.setenv("CXX", "/opt/my/c++")  # a compiler named by CXX is taken as it is
    checks.check_can_compile("cpu")


def test_filter_parameters_round_trip_through_a_file(tmp_path):
    ekf = EKFTransform(learnable=True)
    with torch.no_grad():
        ekf.process_noise.log_diag.add_(0.3)
        ekf.process_noise.off_diag.fill_(0.01)
        ekf.measurement_noise.log_std.sub_(0.2)
    ekf.save_filter_params(tmp_path / "filter.pt")
    fresh = EKFTransform().load_filter_params(tmp_path / "filter.pt")
    torch.testing.assert_close(fresh.process_noise(), ekf.process_noise())
    torch.testing.assert_close(fresh.measurement_noise.std(), ekf.measurement_noise.std())
    assert torch.linalg.eigvalsh(fresh.process_noise().double()).min() > 0
    env = make_env("filtered", 2, seed=0, filter_params=tmp_path / "filter.pt")
    torch.testing.assert_close(env.transform[0].process_noise(), ekf.process_noise())
    (tmp_path / "bad.pt").write_bytes(b"not a filter file")
    with pytest.raises(ValueError, match="not a"):
        EKFTransform().load_filter_params(tmp_path / "bad.pt")


def test_version_1_filter_files_load_to_the_same_q(tmp_path):
    """Version 1 stored Q's Cholesky factor with absolute off-diagonal entries."""
    log_diag = torch.tensor([-4.0, -4.5, -3.0, -4.4, -5.3])
    off_abs = torch.linspace(-0.02, 0.03, 10)
    rows, cols = torch.tril_indices(5, 5, -1)
    L = torch.diag(log_diag.exp()).index_put((rows, cols), off_abs)
    payload = {
        "format": "dockingrl.filter_params/1",
        "process_noise": {"log_diag": log_diag, "off_diag": off_abs},
        "measurement_noise": {"log_std": EKFTransform().measurement_noise.log_std.detach()},
    }
    torch.save(payload, tmp_path / "v1.pt")
    with pytest.raises(
        ValueError, match="older format dockingrl.filter_params/1.*dockingrl upgrade"
    ):
        EKFTransform().load_filter_params(tmp_path / "v1.pt")
    upgrade_file(tmp_path / "v1.pt")
    ekf = EKFTransform().load_filter_params(tmp_path / "v1.pt")
    expected = L @ L.T + 1e-10 * torch.eye(5)
    torch.testing.assert_close(ekf.process_noise(), expected, rtol=1e-5, atol=1e-9)
