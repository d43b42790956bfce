"""A privileged planner: what the docking task allows when everything is known.

:class:`PlannerPolicy` reads the simulator's true state (pose, velocity, the PID's memory and
the ocean current) and chooses each command by model-predictive control: the cross-entropy
method over piecewise-constant command sequences, rolled through the env's own noise-free
dynamics (:meth:`~dockingrl.env.DockingEnv.simulate`). It is not a policy a vehicle could run
(it sees no sensor, it knows the model exactly); it measures the task. Each of its successes is
a command sequence within eq. 3's bounds that docks, as the env scores it, from that start in
that current: where it docks, the task can be done with full information. Where it fails, the
planner may be what falls short (a learner may still dock there), so its success over a cell
is a lower bound on what a full-information controller reaches, not on what a learner reaches
from noisy sensors.

Not in the paper. ``scripts/oracle_map.py`` runs it over current cells.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from torchrl.envs import Compose, EnvBase, TransformedEnv

from dockingrl.env import DockingEnv
from dockingrl.env.reward import distance_reward
from dockingrl.evaluation import base_env
from dockingrl.transforms import ActionRepeat


@dataclass(frozen=True)
class PlannerConfig:
    """Settings of :class:`PlannerPolicy` (cross-entropy MPC)."""

    #: commands per plan; each is held ``hold`` env steps (20 x 4 x 0.2 s = 16 s ahead)
    horizon: int = 20
    #: env steps one command is held
    hold: int = 4
    #: command sequences sampled per iteration, per episode
    samples: int = 256
    #: cross-entropy iterations per decision
    iterations: int = 3
    #: best sequences the next iteration's mean and spread are fitted to
    elites: int = 25
    #: starting spread of the samples, as a fraction of each command's half-range
    init_std: float = 0.5
    #: floor of that spread
    min_std: float = 0.05
    #: cost of each simulated step: ``rho / max_dist`` (eq. 4's distance term, sign flipped)
    #: times this
    distance_weight: float = 1.0
    #: cost of a plan still under way at its end, per metre of range left
    terminal_weight: float = 2.0
    #: cost of a successful contact: ``-success_bonus * (1 + g)``
    success_bonus: float = 1000.0
    #: cost of a failed contact: ``miss_penalty * (1 + excess speed / v_max + max(-g, 0))``;
    #: a rollout that reaches the episode's time limit (``max_steps``) costs ``miss_penalty``
    miss_penalty: float = 1000.0
    #: cost of passing the station's entrance plane (x > 0) beside the funnel; the rollout
    #: ends there (a vehicle carried past the station by a following current rarely recovers)
    passed_penalty: float = 1000.0
    #: margins a planned contact must keep to count as a success in the plan: its ground
    #: speed at most ``v_max - speed_margin``, its score ``g`` at least ``min_score``; room for
    #: the estimate's error when planning from the filter (0, 0: the env's own criterion)
    speed_margin: float = 0.0
    min_score: float = 0.0
    #: what the plans start from: ``"true"``, the simulator's state; ``"filter"``, the EKF's
    #: estimate of the pose, surge and yaw rate (``ekf_mean``, eq. 22; sway taken as 0) with
    #: what the vehicle knows itself (its PID's memory, the current the EKF assumes known):
    #: the information a vehicle has, in a ``filtered`` or ``compound`` env
    state: str = "true"
    #: seed of the planner's sampling
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("horizon", "hold", "samples", "iterations", "elites"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not 2 <= self.elites <= self.samples:
            raise ValueError(
                f"elites must lie in [2, samples={self.samples}] (their spread is fitted), "
                f"got {self.elites}"
            )
        if not (0.0 <= self.speed_margin < 0.3 and 0.0 <= self.min_score < 1.0):
            raise ValueError(
                f"need 0 <= speed_margin < 0.3 and 0 <= min_score < 1, got "
                f"{self.speed_margin} and {self.min_score}"
            )
        if self.state not in ("true", "filter"):
            raise ValueError(f"state must be 'true' or 'filter', got {self.state!r}")
        if not 0 < self.min_std <= self.init_std:
            raise ValueError(
                f"need 0 < min_std <= init_std, got {self.min_std} and {self.init_std}"
            )

    def replace(self, **changes) -> PlannerConfig:
        return dataclasses.replace(self, **changes)


class PlannerPolicy:
    """Cross-entropy MPC on the true state of a :class:`DockingEnv` (see the module's text).

    Used as a policy by :func:`dockingrl.evaluation.run_episodes` (and so by ``evaluate``,
    ``success_map`` and ``trajectories``), which hands it the env through :meth:`bind_env`
    before the first step. It replans every ``hold`` steps for the episodes that have not
    ended and holds the first command of its plan in between; the rest of the plan
    warm-starts the next one. It is called once per 0.2 s step, so it refuses an env that
    holds commands itself (``ActionRepeat``).
    """

    def __init__(self, config: PlannerConfig | None = None) -> None:
        self.config = config or PlannerConfig()
        self.sim: DockingEnv | None = None

    def bind_env(self, env: EnvBase) -> None:
        """Plan on the true state of the :class:`DockingEnv` under ``env``'s transforms, from
        its next reset on."""
        sim = base_env(env)
        while isinstance(env, TransformedEnv):
            transform = env.transform
            parts = transform.transforms if isinstance(transform, Compose) else [transform]
            if any(isinstance(t, ActionRepeat) for t in parts):
                raise ValueError(
                    "PlannerPolicy holds its commands itself (PlannerConfig.hold); "
                    "evaluate it on an env without action_repeat"
                )
            env = env.base_env
        self.sim = sim
        cfg, dev, dtype = self.config, sim.device, sim.dtype
        self._low = torch.tensor(sim.config.action_low, device=dev, dtype=dtype)
        self._high = torch.tensor(sim.config.action_high, device=dev, dtype=dtype)
        self._mean = torch.zeros(sim.num_envs, cfg.horizon, 2, device=dev, dtype=dtype)
        self._action = torch.zeros(sim.num_envs, 2, device=dev, dtype=dtype)
        self._rng = torch.Generator(device=dev)
        self._rng.manual_seed(cfg.seed)
        self._held = 0
        self._ended = torch.zeros(sim.num_envs, dtype=torch.bool, device=dev)

    def _command(self, unit: torch.Tensor) -> torch.Tensor:
        """Map ``[-1, 1]`` to the command bounds of eq. 3."""
        return self._low + (unit + 1.0) * 0.5 * (self._high - self._low)

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        if self.sim is None:
            raise RuntimeError("PlannerPolicy needs its env: call bind_env(env) first")
        sim = self.sim
        if td.batch_size != sim.batch_size:
            raise ValueError(f"expected a batch of {sim.num_envs}, got {tuple(td.batch_size)}")
        first = bool((td["step_count"] == 0).all())
        if first:
            self._mean.zero_()
            self._held = 0
            self._ended.zero_()
        done = td.get("done", None)
        if done is not None and not first:
            # sticky: an ended episode's env goes on stepping, and its ``done`` may drop again
            self._ended |= done.reshape(-1)
        if self._held % self.config.hold == 0:
            index = (~self._ended).nonzero().squeeze(-1)
            if index.numel():
                plan = self.plan(self._start_state(td)[index], self._mean[index])
                self._action[index] = self._command(plan[:, 0])
                # warm start: the rest of the plan, its last command repeated
                self._mean[index] = torch.cat((plan[:, 1:], plan[:, -1:]), dim=1)
        self._held += 1
        td.set("action", self._action.clone())
        return td

    def _start_state(self, td: TensorDictBase) -> TensorDictBase:
        """The state the plans start from (``PlannerConfig.state``)."""
        state = self.sim.get_state()
        if self.config.state == "filter":
            if "ekf_mean" not in td.keys():
                raise KeyError("PlannerConfig(state='filter') needs a filtered or compound env")
            estimate = td["ekf_mean"].to(state["pose"].dtype)  # [x, y, alpha, nu, w]
            state["pose"] = estimate[:, :3].clone()
            zero = torch.zeros_like(estimate[:, 3])
            state["velocity"] = torch.stack((estimate[:, 3], zero, estimate[:, 4]), dim=-1)
        return state

    @torch.no_grad()
    def plan(self, state: TensorDictBase, mean: torch.Tensor) -> torch.Tensor:
        """The best command sequence ``(b, horizon, 2)`` (in ``[-1, 1]`` units) from each of
        the ``b`` states, by the cross-entropy method started at ``mean``."""
        cfg = self.config
        b = state.batch_size[0]
        std = torch.full_like(mean, cfg.init_std)
        best = mean.clone()
        best_cost = torch.full((b,), float("inf"), device=mean.device, dtype=mean.dtype)
        for _ in range(cfg.iterations):
            noise = torch.randn(
                (b, cfg.samples, cfg.horizon, 2),
                generator=self._rng,
                device=mean.device,
                dtype=mean.dtype,
            )
            candidates = (mean.unsqueeze(1) + std.unsqueeze(1) * noise).clamp(-1.0, 1.0)
            candidates[:, 0] = mean  # the warm start itself is always a candidate
            candidates[:, 1] = best
            cost = self.rollout_cost(state, candidates)
            order = cost.argsort(dim=1)
            elite = torch.gather(
                candidates, 1, order[:, : cfg.elites, None, None].expand(-1, -1, cfg.horizon, 2)
            )
            lowest = torch.gather(cost, 1, order[:, :1]).squeeze(1)
            better = lowest < best_cost
            best = torch.where(better[:, None, None], elite[:, 0], best)
            best_cost = torch.minimum(lowest, best_cost)
            mean = elite.mean(dim=1)
            std = elite.std(dim=1).clamp_min(cfg.min_std)
        return best

    def rollout_cost(self, state: TensorDictBase, candidates: torch.Tensor) -> torch.Tensor:
        """Cost ``(b, k)`` of ``k`` command sequences ``(b, k, horizon, 2)`` from ``b`` states,
        rolled through the noise-free dynamics (see :class:`PlannerConfig`)."""
        cfg, sim = self.config, self.sim
        b, k = candidates.shape[:2]
        dock = sim.config
        state = state.unsqueeze(1).expand(b, k).reshape(b * k).clone()
        commands = self._command(candidates).reshape(b * k, cfg.horizon, 2)
        cost = torch.zeros(b * k, device=candidates.device, dtype=candidates.dtype)
        active = torch.ones(b * k, dtype=torch.bool, device=candidates.device)
        speed_max = dock.entry_speed_max + dock.contact_speed_tolerance - cfg.speed_margin
        for h in range(cfg.horizon):
            for _ in range(cfg.hold):
                state, out = sim.simulate(state, commands[:, h])
                x = state["pose"][:, 0]
                rho = out["observation"][:, 0]  # noise-free: eq. 2's range
                contact = out["terminated"].squeeze(-1) & active
                score = out["contact_score"].squeeze(-1)
                speed = out["contact_speed"].squeeze(-1)
                success = out["success"].squeeze(-1) & (speed <= speed_max)
                success = success & (score >= cfg.min_score)
                miss = cfg.miss_penalty * (
                    1.0
                    + (speed - speed_max).clamp_min(0.0) / speed_max
                    + (cfg.min_score - score).clamp_min(0)
                )
                outcome = torch.where(success, -cfg.success_bonus * (1.0 + score), miss)
                passed = active & ~contact & (x > dock.dock_x[1])
                # the episode's time limit (max_steps) ends a rollout as a failure
                timeout = active & ~contact & out["truncated"].squeeze(-1)
                step = -cfg.distance_weight * distance_reward(rho, dock.max_dist)
                step = torch.where(timeout, cfg.miss_penalty, step)
                step = torch.where(passed, cfg.passed_penalty, step)
                cost = cost + torch.where(contact, outcome, torch.where(active, step, 0.0))
                active = active & ~contact & ~passed & ~timeout
            if not bool(active.any()):
                break
        cost = cost + torch.where(active, cfg.terminal_weight * rho, 0.0)
        return cost.reshape(b, k)
