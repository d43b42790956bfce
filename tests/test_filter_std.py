"""``observe_filter_std``: the EKF's position uncertainty in the policy's observation, in the
TorchRL pipeline, the Gymnasium envs, a saved policy, the onboard policy and its export."""

from __future__ import annotations

import json

import pytest
import torch
from torchrl.envs.utils import step_mdp

from dockingrl.agents.config import make_config
from dockingrl.env.levels import level_config
from dockingrl.scenarios import make_env, mirror_signs, observation_layout
from dockingrl.training.checkpointing import network_differences
from dockingrl.transforms.observations import position_std


def test_it_is_the_filters_position_std_falling_at_each_fix_and_growing_between():
    """At L1 (a 1 Hz USBL) the two numbers are sqrt(P_xx), sqrt(P_yy) of the filter's
    covariance, appended last to the compound observation; they fall at every step a USBL fix
    arrives, and the along-track one grows over nearly every step without one (the lateral one
    also shrinks at some of those, through the heading's and velocities' updates)."""
    config = level_config("L1").replace(max_steps=200)
    env = make_env("compound", 8, seed=1, config=config, observe_filter_std=True)
    assert env.observation_spec["observation"].shape[-1] == 14
    td = env.reset()
    previous, arrivals, grew, quiet = td["filter_std"], 0, 0, 0
    for k in range(60):
        td = env.step(td.set("action", torch.tensor([[0.3, 0.0]]).expand(8, 2)))
        std, cov = td["next", "filter_std"], td["next", "ekf_cov"]
        torch.testing.assert_close(std, cov.diagonal(dim1=-2, dim2=-1)[:, :2].sqrt())
        assert torch.equal(td["next", "observation"][:, 12:], std)
        fix = td["next", "sensor_age"][:, 0] == 0
        if k > 0:
            assert (std[fix] < previous[fix]).all(), f"step {k}: a fix did not shrink it"
            arrivals += int(fix.sum())
            grew += int((std[~fix, 0] > previous[~fix, 0]).sum())
            quiet += int((~fix).sum())
        previous, td = std, step_mdp(td)
    assert arrivals >= 50 and grew >= 0.9 * quiet, (arrivals, grew, quiet)


def test_layout_mirror_and_refusals():
    layout = observation_layout("filtered", observe_filter_std=True, observe_command=True)
    assert layout == ("filtered_observation", "filter_std", "previous_action")
    signs = mirror_signs("compound", observe_filter_std=True)
    assert len(signs) == 14 and signs[12:].tolist() == [1.0, 1.0]  # the mirror keeps both
    with pytest.raises(ValueError, match="observe_filter_std needs a scenario with the EKF"):
        make_env("noise", 1, observe_filter_std=True)
    with pytest.raises(ValueError, match="observe_filter_std: scenario 'no_noise' has no filter"):
        make_config("sac", "paper", scenario="no_noise", observe_filter_std=True)
    assert position_std(torch.diag(torch.tensor([4.0, 9.0, 1.0]))).tolist() == [2.0, 3.0]


def test_a_warm_start_needs_the_same_observation():
    cfg = make_config("sac", "paper", scenario="compound", observe_filter_std=True)
    source = make_config("sac", "paper", scenario="compound").to_dict()
    assert network_differences(source, cfg) == ["observe_filter_std: False there, True here"]


def test_onboard_policy_and_its_export_read_it_as_the_env_pipeline_gives_it(tmp_path):
    from helpers import drive_onboard_beside_env, tiny_actor

    from dockingrl.onboard import OnboardPolicy, export_onboard

    config = level_config("L5").replace(max_steps=40)
    options = {"compensate_latency": True, "estimate_current": True, "gate": 13.816}
    actor = tiny_actor(14, "sac")
    onboard = OnboardPolicy(actor, "compound", config=config, observe_filter_std=True, **options)
    program = torch.export.load(
        export_onboard(onboard, tmp_path / "onboard.pt2", batch=4, sensor_age=True)
    ).module()
    env = make_env(
        "compound", 4, seed=3, config=config, ekf_kwargs=options, observe_filter_std=True
    )
    resets, _ = drive_onboard_beside_env(env, actor, onboard, program)
    assert resets > 0


def test_a_run_trained_with_it_carries_it_to_evaluation_and_the_onboard_policy(tmp_path):
    from helpers import smoke_config

    from dockingrl.agents.layout import pipeline_options
    from dockingrl.onboard import OnboardPolicy
    from dockingrl.policies import resolve_policy
    from dockingrl.stress import stress_ladder
    from dockingrl.training import train

    cfg = smoke_config(
        "sac",
        "compound",
        tmp_path,
        "std",
        total_steps=128,
        start_steps=64,
        frames_per_batch=64,
        eval_every=128,
        final_eval_episodes=2,
        observe_filter_std=True,
    )
    train(cfg, progress=False)
    saved = json.loads((tmp_path / "std" / "config.json").read_text())
    assert pipeline_options(saved) == {"observe_filter_std": True}
    path = tmp_path / "std" / "policy.pt"
    onboard = OnboardPolicy.from_file(path)
    assert onboard.step.layout == ("observation", "filtered_observation", "filter_std")
    assert onboard.act(
        torch.tensor([[30.0, 0.1, 0.0, 0.5, 0.0, 0.0]]), torch.zeros(1, 2)
    ).shape == (1, 2)
    policy, _, scenario, options, _ = resolve_policy(str(path))
    assert options["observe_filter_std"] is True
    ladder = stress_ladder(policy, scenario, episodes=2, levels=("L1",), **options)
    assert ladder["levels"][0]["episodes"] == 2


def test_the_networks_scale_the_ranges_only_whatever_the_options():
    """With every option on the compound observation is 18 numbers: the ranges are entries 0
    and 6, and the filter's standard deviations (12, 13) are left as they are."""
    from dockingrl.agents.networks import config_observation_scale

    options = {"observe_filter_std": True, "observe_current": True, "observe_command": True}
    for scenario, width, ranges in (("compound", 18, [0, 6]), ("filtered", 12, [0])):
        cfg = make_config("sac", "paper", scenario=scenario, normalize_observation=True, **options)
        scale = config_observation_scale(cfg, width, 30.0)
        assert (scale != 1).nonzero().flatten().tolist() == ranges
        assert torch.allclose(scale[ranges], torch.tensor(1 / 30.0))
