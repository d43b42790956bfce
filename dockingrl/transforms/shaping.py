"""A training-time reward term that makes the safety limit on the contact speed part of what the
agent optimises (not in the paper).

The paper's reward (eqs. 4-12) penalises ground speed above ``v_max`` only through the dense
term of eq. 6, whose weight is small next to the contact reward ``200 g`` of eq. 11. In our env
a PPO agent that maximises it learns to enter the funnel at 0.5-0.6 m/s with an excellent
entry angle: +50 mean episode reward (more than the paper's successful agents) and almost no
successes, since success needs ``V <= v_max`` at contact (``docs/choices.md``). This transform
adds, on the contact step only, a hinge on the contact speed, so that the reward agrees with the
success criterion. It changes what the agent learns from, not the env: evaluation, logged
episode rewards (``RewardSum`` placed before it) and the paper's metrics are untouched.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase
from torchrl.envs import Transform


class ContactSpeedPenalty(Transform):
    """Adds ``-weight * max(V_contact - target_speed, 0)`` to ``reward`` on the contact step.

    ``V_contact`` is the env's ``contact_speed`` entry (ground speed at contact, 0 on every
    other step), so the term is zero except when the AUV touches the docking station too fast.

    Args:
        weight: penalty per m/s above ``target_speed`` (reward units per m/s); 0 disables it.
        target_speed: ground speed above which the penalty starts, m/s. A little below the
            success limit ``v_max = 0.3`` leaves room for sensor noise and the current.
        cap: the contact reward ``r_g = contact_weight * g`` (eq. 11) at most, and nothing when
            ``g <= 0``: a too-fast contact then never scores below missing the docking station
            (``None``: no cap). With a large ``weight`` and no cap, an agent that cannot yet
            dock slowly learns to avoid the station instead.

    Examples:
        >>> from dockingrl import make_env
        >>> from torchrl.envs import RewardSum
        >>> env = make_env("compound", 8, transforms=[RewardSum(), ContactSpeedPenalty(2000.0)])
    """

    def __init__(self, weight: float, target_speed: float = 0.27, cap: float | None = None) -> None:
        if not weight >= 0:
            raise ValueError(f"weight must be >= 0, got {weight!r}")
        if not target_speed > 0:
            raise ValueError(f"target_speed must be > 0, got {target_speed!r}")
        if cap is not None and not cap > 0:
            raise ValueError(f"cap (the contact weight) must be > 0 or None, got {cap!r}")
        super().__init__(in_keys=["reward", "contact_speed", "contact_score"], out_keys=["reward"])
        self.weight = float(weight)
        self.target_speed = float(target_speed)
        self.cap = None if cap is None else float(cap)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        excess = (next_tensordict.get("contact_speed") - self.target_speed).clamp_min(0.0)
        penalty = self.weight * excess
        if self.cap is not None:
            limit = self.cap * next_tensordict.get("contact_score").clamp_min(0.0)
            penalty = torch.minimum(penalty, limit)
        next_tensordict.set("reward", next_tensordict.get("reward") - penalty)
        return next_tensordict

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        return tensordict_reset


class MissPenaltyFloor(Transform):
    """Bounds the contact reward of a miss from below: ``r_g = max(contact_weight * g, -floor)``
    on the contact step (training only, not in the paper).

    Eq. 11 gives ``200 g`` on contact, and ``g`` of eq. 10 is unbounded below: a contact
    broadside or from behind the station scores ``g`` down to ``1 - 3.05 pi (1 + pi/2) =
    -23.6``, a reward of ``-4700``, against at most ``+200`` for a perfect entry and about
    ``-1`` per step for the distance term. Such
    outliers dominate the critic's targets and teach an agent that cannot yet dock under a
    strong following current to keep away from the station until the time limit. A floor keeps
    every miss below every valid entry (``g > 0`` scores ``> 0``) and the order among entries
    unchanged, and it touches nothing the evaluation reports.

    Args:
        floor: the most a miss may cost, in reward units (> 0).
        contact_weight: the weight of eq. 11 (the env's ``DockingConfig.contact_weight``).
    """

    def __init__(self, floor: float, contact_weight: float = 200.0) -> None:
        if not floor > 0:
            raise ValueError(f"floor must be > 0, got {floor!r}")
        if not contact_weight > 0:
            raise ValueError(f"contact_weight must be > 0, got {contact_weight!r}")
        super().__init__(in_keys=["reward", "contact_score"], out_keys=["reward"])
        self.floor = float(floor)
        self.contact_weight = float(contact_weight)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        r_g = self.contact_weight * next_tensordict.get("contact_score")
        lift = (-self.floor - r_g).clamp_min(0.0)
        next_tensordict.set("reward", next_tensordict.get("reward") + lift)
        return next_tensordict

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        return tensordict_reset


class SuccessBonus(Transform):
    """Adds ``bonus`` to ``reward`` on the step of a successful contact (training only, not in
    the paper).

    The contact reward of eq. 11 and :class:`ContactSpeedPenalty` are continuous in the contact
    speed: a contact at 0.31 m/s, a failure, earns almost what one at 0.29 m/s, a success, does.
    An agent that trades a few seconds against a few m/s of contact speed then settles close
    to the limit where a strong following current makes braking costly. A bonus on the
    ``success`` flag puts the success criterion's step into the reward, so that arriving with
    a margin pays.

    Args:
        bonus: reward units added on a successful contact (> 0).
    """

    def __init__(self, bonus: float) -> None:
        if not bonus > 0:
            raise ValueError(f"bonus must be > 0, got {bonus!r}")
        super().__init__(in_keys=["reward", "success"], out_keys=["reward"])
        self.bonus = float(bonus)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        reward = next_tensordict.get("reward")
        success = next_tensordict.get("success").to(reward.dtype).reshape(reward.shape)
        next_tensordict.set("reward", reward + self.bonus * success)
        return next_tensordict

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        return tensordict_reset


class PassedStationEnd(Transform):
    """Ends a training episode when the AUV passes the station's entrance plane beside the
    funnel, with a penalty (training only, not in the paper).

    The AUV starts at ``x < 0`` and docks moving in ``+x``; the contact box ends at the entrance
    plane ``x = dock_x[1]``. An AUV that a following current carries past the plane beside the
    box can only dock by turning back against the current and round to the mouth, which the
    trained agents do not do: in the paper's env it drifts on, at about ``-rho / 30`` a step,
    until the time limit. That cost is spread over hundreds of discounted steps and is smaller
    than a miss's; this transform charges it at once, as ``penalty`` on the step the plane is
    crossed, and ends the episode there (``terminated``: no bootstrap). Evaluation keeps the
    paper's episodes. The rewards ``RewardSum`` (placed before it) logs are eq. 12's step by
    step, but such a training episode is shorter than the paper's, so training curves of
    episode reward are not comparable with runs without it.

    The test is on ``x`` alone: an AUV cannot cross the plane inside the contact box without
    touching the station first, since the box is ``dock_x[1] - dock_x[0] = 0.8`` m deep and
    one step moves it at most about 0.3 m.

    Args:
        penalty: reward units subtracted on the crossing step (> 0).
        entrance_x: the plane, the env's ``DockingConfig.dock_x[1]``.
    """

    def __init__(self, penalty: float, entrance_x: float = 0.0) -> None:
        if not (math.isfinite(penalty) and penalty > 0):
            raise ValueError(f"penalty must be finite and > 0, got {penalty!r}")
        if not math.isfinite(entrance_x):
            raise ValueError(f"entrance_x must be finite, got {entrance_x!r}")
        super().__init__(
            in_keys=["reward", "true_state", "terminated"],
            out_keys=["reward", "terminated", "truncated", "done"],
        )
        self.penalty = float(penalty)
        self.entrance_x = float(entrance_x)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        terminated = next_tensordict.get("terminated")
        passed = (next_tensordict.get("true_state")[..., :1] > self.entrance_x) & ~terminated
        next_tensordict.set("reward", next_tensordict.get("reward") - self.penalty * passed)
        terminated = terminated | passed
        truncated = next_tensordict.get("truncated") & ~passed
        next_tensordict.set("terminated", terminated)
        next_tensordict.set("truncated", truncated)
        next_tensordict.set("done", terminated | truncated)
        return next_tensordict

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        return tensordict_reset
