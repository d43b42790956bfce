"""The training config composed of field groups (issue #31): each config is its groups' fields
(and ``algo``, ``recipe``), and each group refuses its own bad values."""

from dataclasses import fields

import pytest

from dockingrl.agents.config import (
    TRAIN_GROUPS,
    OffPolicyConfig,
    PPOConfig,
    SACConfig,
    TD3Config,
    TrainConfig,
    make_config,
)
from dockingrl.agents.network_options import NetworkOptions
from dockingrl.agents.off_policy_options import OffPolicyOptions, SACOptions, TD3Options
from dockingrl.agents.ppo_options import PPOOptions
from dockingrl.agents.reward_shaping import RewardShaping
from dockingrl.agents.run_options import RunOptions
from dockingrl.agents.world_options import WorldOptions

GROUPS = {
    SACConfig: (*TRAIN_GROUPS, OffPolicyOptions, SACOptions),
    TD3Config: (*TRAIN_GROUPS, OffPolicyOptions, TD3Options),
    PPOConfig: (*TRAIN_GROUPS, PPOOptions),
}


@pytest.mark.parametrize("cls", list(GROUPS))
def test_a_config_is_its_groups_fields(cls):
    names = [f.name for f in fields(cls)]
    assert len(set(names)) == len(names)
    assert list(cls().to_dict()) == names
    assert all(issubclass(cls, group) for group in GROUPS[cls])
    from_groups = {f.name for group in GROUPS[cls] for f in fields(group)}
    assert set(names) == from_groups | {"algo", "recipe"}


def test_subclasses_keep_their_own_defaults_in_the_shared_places():
    assert (TD3Config().lr, TD3Config().hidden, TD3Config().start_steps) == (5e-4, (400, 300), 100)
    assert (PPOConfig().total_steps, PPOConfig().eval_every) == (2_500_000, 50_000)
    assert (SACConfig().total_steps, SACConfig().algo, TrainConfig().algo) == (500_000, "sac", "")
    assert issubclass(SACConfig, OffPolicyConfig) and issubclass(OffPolicyConfig, TrainConfig)


@pytest.mark.parametrize(
    "group, check, values, message",
    [
        (RunOptions, "_check_run", {"num_envs": 0}, "RunOptions.num_envs: must be >= 1 (got 0)"),
        (RunOptions, "_check_run", {"keep_candidates": 3}, "set keep_best (got 3)"),
        (WorldOptions, "_check_world", {"train_level": "L9"}, "unknown stress level"),
        (WorldOptions, "_check_world", {"near_start_fraction": 2.0}, "must lie in [0, 1]"),
        (RewardShaping, "_check_reward", {"success_bonus": -1.0}, "must be >= 0 (got -1.0)"),
        (NetworkOptions, "_check_network", {"hidden": (0,)}, "needs positive layer sizes"),
        (OffPolicyOptions, "_check_off_policy", {"tau": 0.0}, "tau: must lie in (0, 1]"),
        (TD3Options, "_check_td3", {"policy_delay": 0}, "policy_delay: must be >= 1"),
        (PPOOptions, "_check_ppo", {"activation": "gelu"}, "valid: relu, tanh (got 'gelu')"),
        (RunOptions, "_check_run", {"fast_update": 1}, "fast_update: must be true or false"),
        (WorldOptions, "_check_world", {"compensate_latency": "yes"}, "must be true or false"),
        (PPOOptions, "_check_ppo", {"advantage_every_epoch": None}, "true or false (got None)"),
    ],
)
def test_each_group_refuses_its_own_bad_values(group, check, values, message):
    getattr(group(), check)()  # its defaults pass
    with pytest.raises(ValueError, match="^" + group.__name__) as refused:
        getattr(group(**values), check)()
    assert message in str(refused.value)


def test_a_config_names_itself_in_its_groups_refusals():
    with pytest.raises(ValueError, match=r"^SACConfig\.num_envs: must be >= 1 \(got 0\)$"):
        make_config("sac", num_envs=0)
    with pytest.raises(ValueError, match=r"^PPOConfig\.contact_speed_target: must be > 0"):
        make_config("ppo", contact_speed_target=0.0)
