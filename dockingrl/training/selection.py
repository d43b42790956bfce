"""Periodic evaluation of a run and the choice of the actor it ends with (``keep_best``)."""

from __future__ import annotations

import time

from dockingrl.evaluation import evaluate

#: seed of the validation episodes that pick among ``keep_candidates`` actors (plus the run's
#: seed); periodic evaluations use ``1_000_000 + frames``, the final one ``seed + 10_000``
SELECT_SEED = 1 << 40


class Selection:
    """The evaluations of one run's ``agent`` in the world of ``cfg`` and ``env_kwargs``:
    periodic ones, each a candidate for ``keep_best`` (the ``keep_candidates`` best so far in
    ``candidates``, best first, the earlier of equal scores first, each with the actor's
    weights then), the choice among them and the final one."""

    def __init__(self, agent, cfg, env_kwargs: dict) -> None:
        self.agent, self.cfg, self.env_kwargs = agent, cfg, env_kwargs
        self.candidates: list[dict] = []
        #: the last periodic evaluation's success (nan before the first)
        self.last_success = float("nan")

    def evaluate(self, episodes: int, seed: int, **kwargs) -> dict:
        """:func:`~dockingrl.evaluation.evaluate` of the policy the agent evaluates and saves,
        in the run's scenario and world."""
        return evaluate(
            self.agent.policy,
            self.cfg.scenario,
            episodes,
            seed=seed,
            device=self.cfg.device,
            **kwargs,
            **self.env_kwargs,
        )

    def periodic_eval(self, frames: int) -> dict[str, float]:
        """The periodic evaluation at ``frames`` env steps, as the metrics it logs."""
        m = self.evaluate(self.cfg.eval_episodes, 1_000_000 + frames)
        self.last_success = m["success_rate"]
        if self.cfg.keep_best:
            self.keep_candidate(m["success_rate"], frames)
        logs = {
            "eval/success_rate": m["success_rate"],
            "eval/total_reward": m["total_reward"]["mean"],
            "eval/episode_time_s": m["time_all_s"]["mean"],
        }
        # success per third of the along-axis current (eval/success_opposing, _weak,
        # _following): where a policy falls short of the paper, following currents decide it
        for third in m["by_current_x"]:
            if third["success_rate"] is not None:
                logs[f"eval/success_{third['oc_x']}"] = third["success_rate"]
        return logs

    @property
    def best(self) -> dict | None:
        """The best periodic evaluation kept so far (``keep_best``), or None."""
        return self.candidates[0] if self.candidates else None

    def keep_candidate(self, success: float, frames: int) -> None:
        if len(self.candidates) >= self.cfg.keep_candidates and not (
            success > self.candidates[-1]["success"]
        ):
            return
        actor = {k: v.detach().cpu().clone() for k, v in self.agent.policy.state_dict().items()}
        self.candidates.append({"success": success, "frames": frames, "actor": actor})
        self.candidates.sort(key=lambda c: -c["success"])  # stable: earlier first on ties
        del self.candidates[self.cfg.keep_candidates :]

    def select_candidate(self) -> dict:
        """Load the kept actor to end with into ``agent.policy``; returns what the summary and
        the policy file record of the choice. With several candidates, each is scored on the
        same ``select_episodes`` validation episodes (seed :data:`SELECT_SEED` + the run's
        seed) and the best success rate wins (the higher mean reward on a tie, then the
        better periodic evaluation)."""
        cfg, chosen = self.cfg, self.candidates[0]
        record = {}
        if len(self.candidates) > 1:
            start, scores = time.perf_counter(), []
            for candidate in self.candidates:
                self.agent.policy.load_state_dict(candidate["actor"])
                m = self.evaluate(cfg.select_episodes, SELECT_SEED + cfg.seed)
                scores.append((m["success_rate"], m["total_reward"]["mean"]))
            top = max(range(len(scores)), key=lambda i: (*scores[i], -i))
            chosen = self.candidates[top]
            record = {
                "policy_validation_success_rate": scores[top][0],
                "selection_wall_clock_s": time.perf_counter() - start,
                "selection": [
                    {
                        "frames": c["frames"],
                        "periodic_success_rate": c["success"],
                        "validation_success_rate": score[0],
                        "validation_total_reward": score[1],
                    }
                    for c, score in zip(self.candidates, scores, strict=True)
                ],
            }
        self.agent.policy.load_state_dict(chosen["actor"])
        return {
            "policy_from_frames": chosen["frames"],
            "policy_periodic_success_rate": chosen["success"],
            **record,
        }
