"""TD3: TorchRL's ``TD3Loss`` over a deterministic actor and twin Q-networks, Gaussian
exploration noise, the critics stepped every update and the actor and the targets every
``policy_delay`` updates."""

from __future__ import annotations

from tensordict.nn import TensorDictSequential
from torchrl.modules import AdditiveGaussianModule
from torchrl.objectives import TD3Loss

from dockingrl.agents.config import TD3Config
from dockingrl.agents.networks import deterministic_actor
from dockingrl.agents.off_policy import OffPolicyAgent, vmap_ensembles
from dockingrl.agents.torchrl_adapter import TwinCriticTD3Loss


class TD3Agent(OffPolicyAgent):
    """Twin delayed DDPG."""

    @classmethod
    def make_actor(cls, cfg: TD3Config, obs_dim, action_spec, scale, mirror):
        """A deterministic policy squashed by tanh into the action bounds."""
        return deterministic_actor(obs_dim, action_spec, cfg.hidden, scale, mirror)

    @classmethod
    def make_exploration(cls, cfg: TD3Config, actor, action_spec, device):
        """The actor followed by Gaussian noise of ``exploration_sigma``."""
        return TensorDictSequential(
            actor,
            AdditiveGaussianModule(
                spec=action_spec,
                sigma_init=float(cfg.exploration_sigma),
                sigma_end=float(cfg.exploration_sigma),
                device=device,
            ),
        )

    @classmethod
    def make_loss(cls, cfg: TD3Config, actor, qvalue, action_spec) -> TD3Loss:
        return TwinCriticTD3Loss(
            actor_network=actor,
            qvalue_network=qvalue,
            action_spec=action_spec,
            num_qvalue_nets=2,
            policy_noise=cfg.target_policy_noise,
            noise_clip=cfg.target_noise_clip,
            loss_function="l2",
            deactivate_vmap=not vmap_ensembles(cfg),
        )

    def _update(self, batch):
        opt = self.optimizers
        opt["critic"].zero_grad(set_to_none=True)
        logs = self._gradients("critic", batch)
        opt["critic"].step()
        if self.updates % self.config.policy_delay == 0:
            opt["actor"].zero_grad(set_to_none=True)
            logs.update(self._gradients("actor", batch))
            opt["actor"].step()
            self.target_updater.step()
            self._average_actor()
        return logs

    def _grad_critic(self, batch):
        loss, _ = self.loss.value_loss(batch)
        loss.backward()
        return {"loss_qvalue": loss.detach()}

    def _grad_actor(self, batch):
        loss, _ = self.loss.actor_loss(batch)
        loss.backward()
        return {"loss_actor": loss.detach()}
