import pytest
import torch
from torchrl.envs import RewardSum
from torchrl.envs.utils import check_env_specs

from dockingrl import make_env
from dockingrl.agents.config import make_config
from dockingrl.evaluation import base_env
from dockingrl.training import training_transforms
from dockingrl.transforms import (
    ContactSpeedPenalty,
    MissPenaltyFloor,
    PassedStationEnd,
    SuccessBonus,
)

WEIGHT, TARGET = 2000.0, 0.27


def fast_contact_rollout(
    transforms, pose=(-2.3, 0.0, 0.0), current=(0.3, 0.0), surge=(0.8, 0.6), steps=40
):
    """Two envs start 1.5 m in front of the funnel with a following current and full surge:
    both touch the station within a few steps at well over 0.3 m/s."""
    env = make_env("compound", 2, seed=3, transforms=transforms)
    base_env(env).set_initial_state(pose=torch.tensor(pose), ocean_current=torch.tensor(current))
    action = torch.tensor([[surge[0], 0.0], [surge[1], 0.0]])
    td = env.reset()
    steps, limit = [], steps
    for _ in range(limit):
        td["action"] = action
        td = env.step(td)
        steps.append(td["next"].clone())
        if bool(td["next", "done"].all()):
            break
        td = td["next"].clone()
    return torch.stack(steps)


def test_penalty_applies_on_the_contact_step_only_and_leaves_episode_reward_alone():
    plain = fast_contact_rollout([RewardSum()])
    shaped = fast_contact_rollout([RewardSum(), ContactSpeedPenalty(WEIGHT, TARGET)])
    contact = plain["terminated"].squeeze(-1)
    assert bool(contact[-1].all())  # both envs docked, too fast
    speed = plain["contact_speed"].squeeze(-1)
    assert bool((speed[-1] > 0.35).all())
    difference = (shaped["reward"] - plain["reward"]).squeeze(-1)
    expected = -WEIGHT * (speed - TARGET).clamp_min(0.0)
    torch.testing.assert_close(difference, expected, rtol=1e-5, atol=1e-3)
    assert bool((difference[~contact] == 0).all())
    # RewardSum placed before the penalty keeps logging the paper's reward (eq. 12)
    torch.testing.assert_close(shaped["episode_reward"], plain["episode_reward"])


def test_capped_penalty_never_goes_below_a_miss():
    plain = fast_contact_rollout([RewardSum()])
    capped = fast_contact_rollout([RewardSum(), ContactSpeedPenalty(WEIGHT, TARGET, cap=200.0)])
    contact = plain["terminated"].squeeze(-1)
    speed = plain["contact_speed"].squeeze(-1)
    score = plain["contact_score"].squeeze(-1)
    difference = (capped["reward"] - plain["reward"]).squeeze(-1)
    uncapped = WEIGHT * (speed - TARGET).clamp_min(0.0)
    expected = -torch.minimum(uncapped, 200.0 * score.clamp_min(0.0))
    torch.testing.assert_close(difference, expected, rtol=1e-5, atol=1e-3)
    # at over 0.35 m/s the uncapped penalty exceeds the contact reward: the cap binds and the
    # contact step keeps only the dense terms, as a step that misses the station would
    assert bool((uncapped[-1] > 200.0 * score[-1]).all())
    contact_reward = plain["reward"][-1].squeeze(-1) - 200.0 * score[-1]
    torch.testing.assert_close(capped["reward"][-1].squeeze(-1), contact_reward, atol=1e-3, rtol=0)
    assert bool((difference[~contact] == 0).all())


def test_success_bonus_rewards_a_slow_entry_and_not_a_fast_one():
    """No current: one env creeps in at 0.1 m/s (a success), the other rams the station at
    0.85 m/s (too fast): only the first step of the success earns the bonus."""
    kwargs = dict(current=(0.0, 0.0), surge=(0.1, 0.8), steps=120)
    plain = fast_contact_rollout([RewardSum()], **kwargs)
    bonus = fast_contact_rollout([RewardSum(), SuccessBonus(150.0)], **kwargs)
    done = plain["done"].squeeze(-1)
    first = done.float().argmax(0)
    assert bool(done.any(0).all()) and first[1] < first[0]
    success = plain["success"].squeeze(-1)
    assert bool(success[first[0], 0]) and not bool(success[first[1], 1])
    difference = (bonus["reward"] - plain["reward"]).squeeze(-1)
    for env in (0, 1):
        upto = difference[: first[env] + 1, env]
        expected = torch.zeros_like(upto)
        expected[-1] = 150.0 if env == 0 else 0.0
        torch.testing.assert_close(upto, expected)
    torch.testing.assert_close(bonus["episode_reward"], plain["episode_reward"])
    names = [type(t).__name__ for t in training_transforms(make_config("sac", success_bonus=50))]
    assert names == ["RewardSum", "SuccessBonus"]
    with pytest.raises(ValueError, match="bonus"):
        SuccessBonus(0.0)
    with pytest.raises(ValueError, match="success_bonus"):
        make_config("sac", success_bonus=-1.0)


def test_env_specs_hold_with_the_penalty():
    check_env_specs(make_env("noise", 4, seed=0, transforms=[ContactSpeedPenalty(WEIGHT)]))


def test_training_transforms_follow_the_config():
    paper = training_transforms(make_config("ppo"))
    assert [type(t).__name__ for t in paper] == ["RewardSum"]
    shaped = training_transforms(make_config("ppo", contact_speed_penalty=500.0))
    assert isinstance(shaped[-1], ContactSpeedPenalty) and shaped[-1].weight == 500.0
    assert shaped[-1].cap is None
    capped = make_config("ppo", contact_speed_penalty=500.0, contact_speed_penalty_cap=True)
    assert training_transforms(capped)[-1].cap == 200.0


@pytest.mark.parametrize(
    ("kwargs", "says"),
    [
        ({"weight": -1.0}, "weight must be >= 0"),
        ({"weight": 1.0, "target_speed": 0.0}, "target_speed must be > 0"),
        ({"weight": 1.0, "cap": 0.0}, r"cap \(the contact weight\) must be > 0"),
    ],
)
def test_bad_penalty_arguments_are_refused(kwargs, says):
    with pytest.raises(ValueError, match=says):
        ContactSpeedPenalty(**kwargs)


def test_bad_penalty_config_is_refused():
    with pytest.raises(ValueError, match="contact_speed_penalty"):
        make_config("sac", contact_speed_penalty=-5.0)


def test_miss_floor_lifts_only_a_bad_miss():
    """Broadside into the side of the funnel (heading pi/2, pushed by a cross current): a miss
    with g far below 0; the floor bounds its contact reward at -floor and changes nothing else."""
    floor = 100.0
    side = dict(pose=(-0.4, -2.0, 1.5708), current=(0.0, 0.3))
    plain = fast_contact_rollout([RewardSum()], **side)
    floored = fast_contact_rollout([RewardSum(), MissPenaltyFloor(floor)], **side)
    contact = plain["terminated"].squeeze(-1)
    assert bool(contact[-1].all())
    score = plain["contact_score"].squeeze(-1)
    assert bool((200.0 * score[-1] < -floor).all())  # the paper's reward: a large penalty
    difference = (floored["reward"] - plain["reward"]).squeeze(-1)
    torch.testing.assert_close(difference[-1], -floor - 200.0 * score[-1], rtol=1e-5, atol=1e-4)
    assert bool((difference[~contact] == 0).all())
    torch.testing.assert_close(floored["episode_reward"], plain["episode_reward"])
    # a valid entry (g > 0) is left alone
    entry = fast_contact_rollout([RewardSum()])
    entry_floored = fast_contact_rollout([RewardSum(), MissPenaltyFloor(floor)])
    torch.testing.assert_close(entry_floored["reward"], entry["reward"])


def test_training_transforms_add_the_floor_before_the_penalty():
    cfg = make_config("ppo", miss_penalty_floor=200.0, contact_speed_penalty=500.0)
    names = [type(t).__name__ for t in training_transforms(cfg)]
    assert names == ["RewardSum", "MissPenaltyFloor", "ContactSpeedPenalty"]
    with pytest.raises(ValueError, match="miss_penalty_floor"):
        make_config("ppo", miss_penalty_floor=-1.0)
    with pytest.raises(ValueError, match="floor"):
        MissPenaltyFloor(0.0)


def test_passing_the_station_ends_the_episode_with_the_penalty():
    """Env 0 drifts past the entrance plane 2 m beside the funnel, env 1 into it: env 0's
    episode ends (terminated) on the crossing step with the penalty on top of eq. 12; env 1's
    contact is left alone; logged episode rewards are the paper's."""
    penalty = 150.0
    poses = ((-1.0, 2.0, 0.0), (-1.0, 0.0, 0.0))
    plain = fast_contact_rollout([RewardSum()], pose=poses)
    ended = fast_contact_rollout([RewardSum(), PassedStationEnd(penalty)], pose=poses)
    x = ended["true_state"][..., 0]
    crossed = int((x[:, 0] > 0).nonzero()[0])
    assert bool((x[:crossed, 0] <= 0).all())
    assert ended["terminated"][crossed, 0] and ended["done"][crossed, 0]
    assert not ended["truncated"][crossed, 0] and not ended["success"][crossed, 0]
    assert not plain["done"][crossed, 0]  # the paper's env goes on
    steps = min(len(plain), len(ended))  # the shaped rollout stops when both are done
    difference = (ended["reward"][:steps] - plain["reward"][:steps]).squeeze(-1)
    assert difference[crossed, 0] == pytest.approx(-penalty)
    assert bool((difference[:crossed, 0] == 0).all())
    docked = int(plain["done"][:, 1].squeeze(-1).nonzero()[0])  # later steps: past its end
    assert bool((difference[: docked + 1, 1] == 0).all())
    assert bool(ended["terminated"][docked, 1]) and float(ended["contact_score"][docked, 1]) > 0
    torch.testing.assert_close(
        ended["episode_reward"][crossed, 0], plain["episode_reward"][crossed, 0]
    )


def test_an_env_that_passed_the_station_is_reset_by_the_collector():
    env = make_env("noise", 2, seed=0, transforms=[PassedStationEnd(100.0)])
    check_env_specs(env)
    base_env(env).set_initial_state(
        pose=torch.tensor([[-0.3, 2.0, 0.0], [-20.0, 0.0, 0.0]]),
        ocean_current=torch.tensor([[0.3, 0.0], [0.0, 0.0]]),
    )
    td = env.reset()
    td["action"] = torch.zeros(2, 2)
    td, root = env.step_and_maybe_reset(td)
    for _ in range(20):  # 0.06 m a step: the plane is crossed at the 6th
        if bool(td["next", "done"][0]):
            break
        root["action"] = torch.zeros(2, 2)
        td, root = env.step_and_maybe_reset(root)
    assert bool(td["next", "done"][0]) and bool(td["next", "terminated"][0])
    # the next root is a fresh episode for env 0 (back at its pinned start), env 1 goes on
    assert float(td["next", "true_state"][0, 0]) > 0
    assert int(root["step_count"][0]) == 0
    assert float(root["true_state"][0, 0]) == pytest.approx(-0.3)
    assert int(root["step_count"][1]) > 0


def test_training_transforms_end_episodes_past_the_station_when_asked():
    cfg = make_config("sac", passed_station_penalty=200.0)
    last = training_transforms(cfg)[-1]
    assert isinstance(last, PassedStationEnd) and last.penalty == 200.0
    assert last.entrance_x == 0.0
    with pytest.raises(ValueError, match="passed_station_penalty"):
        make_config("sac", passed_station_penalty=-1.0)
    with pytest.raises(ValueError, match="penalty"):
        PassedStationEnd(0.0)
