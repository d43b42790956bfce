"""The fast single Gymnasium env (``fast=True``): the same step and filter functions as the
batched env, run on Python floats."""

import math
import warnings

import gymnasium
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import dockingrl  # noqa: F401  (registers the gymnasium id)
from dockingrl import DockingConfig
from dockingrl.env import DockingEnv
from dockingrl.env.transition import SimulatorState, paper_step
from dockingrl.transforms import ekf

ID = "dockingrl/Docking-v0"


def test_paper_step_on_tensors_is_the_batched_envs_step_bit_for_bit():
    n = 64
    env = DockingEnv(n, seed=0)
    starts = torch.zeros(n, 3)  # half of them start close to the funnel: contacts happen
    starts[:, 0] = torch.linspace(-2.0, -12.0, n)
    starts[:, 1] = torch.linspace(-0.6, 0.6, n)
    env.set_initial_state(starts, None)
    env.reset()
    generator = torch.Generator().manual_seed(1)

    def per_axis(values):  # (n,) entries, not 0-d tensors: the same kernels as (n, k) ones
        return tuple(values.expand(n, -1).unbind(-1))

    gains = tuple(per_axis(g) for g in (env._kp, env._ki, env._kd, env._inertia))
    contacts = 0
    for k in range(60):
        action = torch.rand(n, 2, generator=generator) * torch.tensor([1.2, 0.6])
        action = action - torch.tensor([0.4, 0.3])
        noise = env._sample_noise()
        args = (env._pose, env._velocity, env._current, env._integral, env._previous_error)
        entries = [t for a in args for t in a.unbind(-1)]
        state = SimulatorState(*entries, env._step_count[:, 0])
        new, out = paper_step(
            env.config, gains, state, action.unbind(-1), env.step_reward, noise, env._noise_std
        )
        pose, velocity, integral, error, step_count, ref = env._transition(
            *args, env._step_count, action, noise
        )
        assert torch.equal(torch.stack(new[:6], -1), torch.cat((pose, velocity), -1)), k
        assert torch.equal(torch.stack(new[8:12], -1), torch.cat((integral, error), -1)), k
        assert torch.equal(new.step_count, step_count[:, 0])
        assert torch.equal(out.observation, ref["observation"]), k
        assert torch.equal(out.reward, ref["reward"][:, 0]), k
        for key in ("terminated", "truncated", "success", "contact_score", "contact_speed"):
            assert torch.equal(getattr(out, key), ref[key][:, 0]), (k, key)
        contacts += int(out.terminated.sum())
        env._pose, env._velocity, env._integral, env._previous_error = (
            pose,
            velocity,
            integral,
            error,
        )
        env._step_count = step_count
    assert contacts > 0


def test_filter_entries_on_floats_is_ekf_step():
    """The float filter against the tensor one in float64, from states across the task."""
    generator = torch.Generator().manual_seed(0)
    n = 32
    mean = torch.randn(n, 5, generator=generator, dtype=torch.float64)
    mean[:, :2] *= 10.0
    A = torch.randn(n, 5, 5, generator=generator, dtype=torch.float64) * 0.1
    cov = A @ A.transpose(-1, -2) + 0.01 * torch.eye(5, dtype=torch.float64)
    action = torch.rand(n, 2, generator=generator, dtype=torch.float64) - 0.3
    current = 0.6 * torch.rand(n, 2, generator=generator, dtype=torch.float64) - 0.3
    z = ekf.measurement_function(mean, current) + 0.05 * torch.randn(
        n, 6, generator=generator, dtype=torch.float64
    )
    Q = ekf.process_covariance(dtype=torch.float64)
    R = ekf.measurement_noise_std(z[:, 0]) ** 2
    ref_mean, ref_cov, ref_filtered = ekf.ekf_step(
        mean, cov, action, z, current, Q, R, 0.2, diagonal=True
    )
    for i in range(n):
        sigma = ekf.measurement_noise_std(float(z[i, 0]))
        assert sigma == pytest.approx(torch.sqrt(R[i]).tolist(), rel=1e-15)
        m, P, filtered = ekf.filter_entries(
            mean[i].tolist(),
            cov[i].tolist(),
            action[i].tolist(),
            z[i].tolist(),
            current[i].tolist(),
            Q.tolist(),
            sigma,
            0.2,
        )
        np.testing.assert_allclose(m, ref_mean[i].numpy(), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(P, ref_cov[i].numpy(), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(filtered, ref_filtered[i].numpy(), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("scenario", ["no_noise", "noise", "filtered", "compound"])
def test_fast_env_follows_the_tensor_env_step_for_step(scenario):
    """The same seed and actions: the same noise draws, the numbers equal to float32 rounding."""
    short = DockingConfig(max_steps=60)
    options = {}
    if scenario == "filtered":  # and R's range from the estimate, not the measurement
        options = {
            "observe_command": True,
            "observe_filter_std": True,
            "ekf_kwargs": {"range_noise_from": "estimate"},
        }
    env = gymnasium.make(ID, scenario=scenario, config=short, fast=True, **options)
    reference = gymnasium.make(ID, scenario=scenario, config=short, **options)
    obs, info = env.reset(seed=7)
    ref_obs, ref_info = reference.reset(seed=7)
    np.testing.assert_array_equal(obs, ref_obs)
    rng = np.random.default_rng(7)
    ends = 0
    for k in range(200):
        action = rng.uniform([-0.6, -0.5], [1.0, 0.5]).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        ref_obs, ref_reward, *ref_flags, ref_info = reference.step(action)
        assert obs.dtype == np.float32 and obs in env.observation_space
        np.testing.assert_allclose(obs, ref_obs, rtol=1e-4, atol=1e-4, err_msg=f"step {k}")
        assert reward == pytest.approx(ref_reward, rel=1e-4, abs=1e-4)
        assert [terminated, truncated] == ref_flags
        np.testing.assert_allclose(info["true_state"], ref_info["true_state"], atol=1e-4)
        assert info["step_count"] == ref_info["step_count"]
        assert info["success"] == ref_info["success"]
        if terminated or truncated:
            ends += 1
            obs, _ = env.reset()
            ref_obs, _ = reference.reset()
            np.testing.assert_array_equal(obs, ref_obs)
    assert ends >= 3


def test_fast_env_docks_and_passes_the_checker():
    env = gymnasium.make(ID, scenario="compound", fast=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env.unwrapped)
    env = gymnasium.make(ID, scenario="noise", fast=True).unwrapped
    env.reset(seed=0, options={"pose": (-1.5, 0.0, 0.0), "ocean_current": (0.0, 0.0)})
    for _ in range(30):
        obs, reward, terminated, truncated, info = env.step(np.array([0.25, 0.0]))
        if terminated:
            break
    assert terminated and info["success"] and 0 < info["contact_score"] <= 1
    assert math.isfinite(reward) and reward > 100  # the contact reward of eq. 11


def test_fast_refusals_are_one_clear_line():
    with pytest.raises(ValueError, match="compile=True compiles the tensor step, fast=True"):
        gymnasium.make(ID, fast=True, compile=True)
    with pytest.raises(ValueError, match="fast=True filters with a constant Q"):
        gymnasium.make(ID, scenario="compound", fast=True, ekf_kwargs={"gate": 13.8})


def test_fast_is_the_default_where_the_fast_path_can_run():
    assert gymnasium.make(ID, scenario="compound").unwrapped.fast
    assert gymnasium.make(ID, scenario="noise").unwrapped.fast
    # a gated filter and a compiled step stay on tensors instead of failing
    assert not gymnasium.make(ID, scenario="compound", ekf_kwargs={"gate": 13.8}).unwrapped.fast
    assert not gymnasium.make(ID, scenario="noise", compile=True).unwrapped.fast
