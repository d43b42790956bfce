"""The training config composed of field groups (issue #31): each config is its groups' fields
(and ``algo``, ``recipe``) in the order saved config.json files and ``--help`` list them, and
each group refuses its own bad values."""

from dataclasses import fields

import pytest

from dockingrl.agents.config import (
    TRAIN_GROUPS,
    OffPolicyConfig,
    PPOConfig,
    SACConfig,
    TD3Config,
    TrainConfig,
    in_order,
    make_config,
)
from dockingrl.agents.network_options import NetworkOptions
from dockingrl.agents.off_policy_options import OffPolicyOptions, SACOptions, TD3Options
from dockingrl.agents.ppo_options import PPOOptions
from dockingrl.agents.reward_shaping import RewardShaping
from dockingrl.agents.run_options import RunOptions
from dockingrl.agents.world_options import WorldOptions

#: the keys of a config.json saved before the split, in their order
SHARED = (
    "scenario total_steps num_envs seed eval_every eval_episodes final_eval_episodes "
    "checkpoint_every logger wandb_online out run_name threads device compile compile_update "
    "normalize_observation hidden range_noise_scale bearing_noise_scale filter_params "
    "contact_speed_penalty contact_speed_target success_bonus contact_speed_penalty_cap "
    "following_current_fraction lateral_current_fraction near_start_fraction train_level "
    "train_curriculum miss_penalty_floor passed_station_penalty time_budget_s keep_best "
    "keep_candidates select_episodes actor_average observe_current observe_command "
    "observe_filter_std mirror_symmetric action_repeat fast_update compensate_latency "
    "estimate_current filter_gate init_from init_replay algo recipe"
).split()
OFF_POLICY = (
    "batch_size gamma lr lr_schedule buffer_size start_steps tau updates_per_step "
    "frames_per_batch n_steps critic_layer_norm critic_dropout reset_every mirror_augment"
).split()
SAVED_ORDER = {
    SACConfig: SHARED + OFF_POLICY + "alpha learn_alpha target_entropy privileged_critic".split(),
    TD3Config: SHARED
    + OFF_POLICY
    + "policy_delay target_policy_noise target_noise_clip exploration_sigma".split(),
    PPOConfig: SHARED
    + (
        "lr lr_schedule steps_per_env minibatch_size epochs gamma gae_lambda clip "
        "normalize_advantage entropy_coef value_coef max_grad_norm reward_scale activation "
        "state_independent_scale orthogonal_init advantage_every_epoch"
    ).split(),
}
GROUPS = {
    SACConfig: (*TRAIN_GROUPS, OffPolicyOptions, SACOptions),
    TD3Config: (*TRAIN_GROUPS, OffPolicyOptions, TD3Options),
    PPOConfig: (*TRAIN_GROUPS, PPOOptions),
}


@pytest.mark.parametrize("cls", list(SAVED_ORDER))
def test_a_config_lists_its_groups_fields_in_the_saved_order(cls):
    names = [f.name for f in fields(cls)]
    assert names == SAVED_ORDER[cls]
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


def test_the_field_order_must_name_every_group_field():
    with pytest.raises(TypeError, match=r"not listed \['keep_best'"):
        in_order([f.name for f in fields(RunOptions) if f.name != "keep_best"], [RunOptions])
    with pytest.raises(TypeError, match=r"in no group \['extra'\]"):
        in_order([*(f.name for f in fields(RewardShaping)), "extra"], [RewardShaping])
