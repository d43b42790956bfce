"""``filter_gate`` and ``filter_response_rate``: the EKF's chi-square innovation gate and the
rates of its motion model as training options, carried by the saved policy to evaluation, the
stress ladder and the onboard policy and its export."""

from __future__ import annotations

import json

import pytest
import torch

from dockingrl.agents.config import make_config
from dockingrl.env.levels import level_config
from dockingrl.scenarios import make_env

GATE = 13.816
RATE = 1.0


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"scenario": "filtered", "filter_gate": -1.0}, "filter_gate: must be a chi-square"),
        ({"scenario": "filtered", "filter_gate": float("inf")}, "filter_gate: must be finite"),
        ({"scenario": "noise", "filter_gate": GATE}, "filter_gate: scenario 'noise' has no filter"),
        ({"scenario": "filtered", "filter_response_rate": 0.0}, "filter_response_rate: must be"),
        ({"scenario": "filtered", "filter_response_rate": float("nan")}, "filter_response_rate"),
        (
            {"scenario": "noise", "filter_response_rate": RATE},
            "filter_response_rate: scenario 'noise' has no filter",
        ),
    ],
)
def test_bad_gates_are_refused(fields, message):
    with pytest.raises(ValueError, match=message):
        make_config("sac", "paper", **fields)


def test_onboard_policy_and_its_export_gate_as_the_env_pipeline_does(tmp_path):
    from helpers import drive_onboard_beside_env, tiny_actor

    from dockingrl.onboard import OnboardPolicy, export_onboard

    # every other fix an outlier, so that the gate has work to do
    config = level_config("L5").replace(max_steps=40, usbl_outlier_probability=0.5)
    options = {"compensate_latency": True, "estimate_current": True}
    actor = tiny_actor(12, "sac")
    onboard = OnboardPolicy(actor, "compound", config=config, gate=GATE, **options)
    ungated = OnboardPolicy(actor, "compound", config=config, **options)
    program = torch.export.load(
        export_onboard(onboard, tmp_path / "onboard.pt2", batch=4, sensor_age=True)
    ).module()
    env = make_env("compound", 4, seed=3, config=config, ekf_kwargs={**options, "gate": GATE})
    resets, differs = drive_onboard_beside_env(env, actor, onboard, program, plain=ungated)
    assert resets > 0
    assert differs, "the gate never changed a command: the test cannot tell it is applied"


def test_a_run_trained_with_it_carries_it_everywhere(tmp_path):
    from helpers import smoke_config

    from dockingrl.agents.layout import pipeline_options
    from dockingrl.onboard import OnboardPolicy
    from dockingrl.policies import resolve_policy
    from dockingrl.stress import stress_ladder
    from dockingrl.training import env_kwargs, train

    cfg = smoke_config(
        "sac",
        "filtered",
        tmp_path,
        "gated",
        total_steps=128,
        start_steps=64,
        frames_per_batch=64,
        eval_every=128,
        final_eval_episodes=2,
        train_level="L1",
        filter_gate=GATE,
        filter_response_rate=RATE,
    )
    expected = {"gate": GATE, "k_v": RATE, "k_w": RATE}
    kwargs = env_kwargs(cfg)
    assert kwargs["ekf_kwargs"] == expected
    env = make_env("filtered", 2, seed=0, **kwargs)
    ekf = next(t for t in env.transform if hasattr(t, "gate"))
    assert (ekf.gate, ekf.k_v, ekf.k_w) == (GATE, RATE, RATE)
    train(cfg, progress=False)
    saved = json.loads((tmp_path / "gated" / "config.json").read_text())
    assert (saved["filter_gate"], saved["filter_response_rate"]) == (GATE, RATE)
    assert pipeline_options(saved)["ekf_kwargs"] == expected
    path = tmp_path / "gated" / "policy.pt"
    onboard = OnboardPolicy.from_file(path).step.ekf
    assert (onboard.gate, onboard.k_v, onboard.k_w) == (GATE, RATE, RATE)
    policy, _, scenario, options, _ = resolve_policy(str(path))
    assert stress_ladder(policy, scenario, episodes=2, levels=("L1",), **options)["gate"] == GATE
    ungated = make_config("sac", "paper", scenario="filtered").to_dict()
    assert "ekf_kwargs" not in pipeline_options(ungated)
