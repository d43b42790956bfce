"""PPO: TorchRL's ``ClipPPOLoss`` with ``GAE`` over a Tanh-Normal actor and a value network,
``epochs`` passes of shuffled minibatches over each collection, an optionally linear learning
rate."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from dockingrl.agents.base import Agent, adam, scalar, schedule_lr
from dockingrl.agents.config import PPOConfig
from dockingrl.agents.mirror import mirror_observation_signs, symmetric
from dockingrl.agents.networks import QValueModule, mlp, stochastic_actor
from dockingrl.agents.ppo_options import PPOOptions

#: rows of the value network's input per call while estimating advantages with
#: ``fast_update``: activations that stay in a CPU's cache
GAE_CHUNK_ROWS = 2048


def gae_chunks(cfg: PPOOptions) -> dict:
    """``GAE`` options that call the value network on chunks of whole envs, about
    ``GAE_CHUNK_ROWS`` rows each, observations and next observations apart, instead of once
    under ``vmap`` on both stacked: 0.36x the time for the ``ppo`` recipe's 256 x 64 steps on a
    1-thread CPU (other roundings: ``fast_update`` only)."""
    return {"value_chunk_size": max(1, GAE_CHUNK_ROWS // cfg.steps_per_env)}


class PPOAgent(Agent):
    """Proximal policy optimisation with the clipped objective."""

    @classmethod
    def build(cls, cfg: PPOConfig, actor, action_spec, obs_dim, scale, max_dist, device) -> Agent:
        value_net = mlp(
            obs_dim,
            1,
            cfg.hidden,
            scale,
            activation=cfg.activation,
            orthogonal_gain=1.0 if cfg.orthogonal_init else None,
        )
        value_net = symmetric(value_net, mirror_observation_signs(cfg, obs_dim, "critic"), (1.0,))
        critic = QValueModule(value_net, in_keys=["observation"]).to(device)
        advantage = GAE(
            gamma=cfg.gamma,
            lmbda=cfg.gae_lambda,
            value_network=critic,
            average_gae=False,
            **(gae_chunks(cfg) if cfg.fast_update else {}),
        )
        loss = ClipPPOLoss(
            actor_network=actor,
            critic_network=critic,
            clip_epsilon=cfg.clip,
            entropy_bonus=cfg.entropy_coef > 0,
            entropy_coeff=cfg.entropy_coef if cfg.entropy_coef > 0 else None,
            critic_coeff=cfg.value_coef,
            loss_critic_type="l2",
            normalize_advantage=cfg.normalize_advantage,
            # fast_update: the loss calls the modules with their own parameters instead of
            # swapping its copies in and out at each call (the same numbers; its state_dict
            # names them after the modules, another checkpoint layout, hence opt-in)
            functional=not cfg.fast_update,
        )
        generator = torch.Generator().manual_seed(cfg.seed)
        return cls(
            cfg,
            actor,
            actor,
            loss,
            {"all": adam(loss.parameters(), cfg)},
            advantage=advantage,
            extra={"generator": generator},
        )

    @classmethod
    def make_actor(cls, cfg: PPOConfig, obs_dim, action_spec, scale, mirror):
        """A Gaussian policy with its log-probabilities (the clipped objective's ratio)."""
        return stochastic_actor(
            obs_dim,
            action_spec,
            cfg.hidden,
            scale,
            mirror=mirror,
            log_prob=True,
            activation=cfg.activation,
            state_independent_scale=cfg.state_independent_scale,
            orthogonal_init=cfg.orthogonal_init,
        )

    def learn_batch(self, data: TensorDictBase, frames: int, batch_frames: int) -> dict:
        """PPO's epochs over the batch."""
        return self.learn(data, progress=(frames - batch_frames) / self.config.total_steps)

    def learn(
        self, data: TensorDictBase, num_updates: int | None = None, progress: float = 0.0
    ) -> dict[str, float]:
        """PPO's epochs over ``data`` (``(num_envs, T)``): ``epochs`` passes of its minibatches,
        so ``num_updates`` is refused; ``progress`` (the fraction of ``total_steps`` done before
        ``data``) sets the learning rate of ``lr_schedule``. Returns mean losses."""
        if num_updates is not None:
            raise ValueError("PPO's updates are its epochs over minibatches: no num_updates")
        cfg = self.config
        lr = schedule_lr(self.optimizers.values(), cfg, progress)
        frames = data.numel()
        if cfg.reward_scale != 1.0:
            data = data.clone(recurse=False)
            data["next"] = data["next"].clone(recurse=False)
            data["next", "reward"] = data["next", "reward"] * cfg.reward_scale
        logs: dict[str, list[float]] = {}
        for epoch in range(cfg.epochs):
            if epoch == 0 or cfg.advantage_every_epoch:
                with torch.no_grad():
                    self.advantage(data)
                flat = data.reshape(-1).select(*self._minibatch_keys(), strict=False)
            order = torch.randperm(frames, generator=self.extra["generator"])
            for start in range(0, frames, cfg.minibatch_size):
                out = self._minibatch_update(flat[order[start : start + cfg.minibatch_size]])
                for key, value in out.items():
                    logs.setdefault(key, []).append(scalar(value))
        logs["lr"] = [lr]
        return {k: sum(v) / len(v) for k, v in logs.items()}

    def _minibatch_update(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One gradient step on a minibatch: forward and backward of the loss, the gradient
        clipped to ``max_grad_norm``, Adam; returns the detached logged values."""
        optim = self.optimizers["all"]
        optim.zero_grad(set_to_none=True)
        out = self._gradients("ppo", batch)
        params = self.extra.get("params")
        if params is None:
            params = self.extra["params"] = list(self.loss.parameters())
        torch.nn.utils.clip_grad_norm_(params, self.config.max_grad_norm)
        optim.step()
        self._average_actor()
        self.updates += 1
        return out

    def _minibatch_keys(self) -> list:
        """What a minibatch carries: the loss's inputs and the advantage estimator's outputs
        (the rollout's other entries, filter state and logs, would be copied by each shuffled
        minibatch for nothing: 3.2 ms of a recipe minibatch of 2,048 against 0.6 ms)."""
        return [*self.loss.in_keys, "advantage", "value_target", "state_value"]

    def _grad_ppo(self, batch):
        out = self.loss(batch)
        total = out["loss_objective"] + out["loss_critic"]
        if "loss_entropy" in out.keys():
            total = total + out["loss_entropy"]
        total.backward()
        keys = ("loss_objective", "loss_critic", "clip_fraction", "kl_approx")
        return {k: out[k].detach() for k in keys if k in out.keys()}
