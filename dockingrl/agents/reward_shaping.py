"""The reward-shaping fields of the training config: the terms the training env adds to the
paper's reward (eq. 12), all off by default; evaluations score the paper's reward alone."""

from __future__ import annotations

from dataclasses import dataclass

from dockingrl.agents.option_fields import check_ranges, documented


@dataclass
class RewardShaping:
    """What the agent learns from beside eq. 12 (``training.training_transforms`` builds it)."""

    contact_speed_penalty: float = documented(
        "training reward - this x (contact speed - contact_speed_target)+, per m/s "
        "(0: the paper's reward; not in the paper)",
        default=0.0,
    )
    contact_speed_target: float = documented(
        "ground speed (m/s) above which contact_speed_penalty applies", default=0.27
    )
    success_bonus: float = documented(
        "training reward + this on a successful contact (0: the paper's reward; not in the paper)",
        default=0.0,
    )
    contact_speed_penalty_cap: bool = documented(
        "cap the contact-speed penalty at the contact reward 200 max(g, 0), so a too-fast "
        "contact never scores below a miss",
        default=False,
    )
    miss_penalty_floor: float = documented(
        "training reward: a miss (g <= 0) costs at most this on contact instead of 200 |g| "
        "(0: off; not in the paper)",
        default=0.0,
    )
    passed_station_penalty: float = documented(
        "training envs: an episode ends, with this penalty, when the AUV passes the "
        "station's entrance plane (x > 0) beside the funnel; evaluation keeps the paper's "
        "episodes (0: off; not in the paper)",
        default=0.0,
    )

    def _check_reward(self) -> None:
        """Refuse a shaping term out of its range, naming it."""
        check_ranges(
            self,
            positive=("contact_speed_target",),
            non_negative=(
                "contact_speed_penalty",
                "success_bonus",
                "miss_penalty_floor",
                "passed_station_penalty",
            ),
        )
