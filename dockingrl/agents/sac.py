"""SAC: TorchRL's ``SACLoss`` over a Tanh-Normal actor and twin Q-networks, one joint step of
actor, critics and (with ``learn_alpha``) temperature per update."""

from __future__ import annotations

from torchrl.objectives import SACLoss

from dockingrl.agents.base import adam
from dockingrl.agents.config import SACConfig
from dockingrl.agents.off_policy import OffPolicyAgent, vmap_ensembles
from dockingrl.agents.torchrl_adapter import TwinCriticSACLoss


class SACAgent(OffPolicyAgent):
    """Soft actor-critic (the paper's main algorithm)."""

    @classmethod
    def make_loss(cls, cfg: SACConfig, actor, qvalue, action_spec) -> SACLoss:
        return TwinCriticSACLoss(
            actor_network=actor,
            qvalue_network=qvalue,
            num_qvalue_nets=2,
            loss_function="l2",
            alpha_init=cfg.alpha,
            fixed_alpha=not cfg.learn_alpha,
            target_entropy=cfg.target_entropy,
            deactivate_vmap=not vmap_ensembles(cfg),
        )

    @classmethod
    def more_optimizers(cls, cfg: SACConfig, loss: SACLoss) -> dict:
        """The temperature's optimiser with ``learn_alpha``."""
        return {"alpha": adam([loss.log_alpha], cfg)} if cfg.learn_alpha else {}

    def _update(self, batch):
        for o in self.optimizers.values():
            o.zero_grad(set_to_none=True)
        logs = self._gradients("sac", batch)
        for o in self.optimizers.values():
            o.step()
        self.target_updater.step()
        self._average_actor()
        return logs

    def _grad_sac(self, batch):
        out = self.loss(batch)
        total = out["loss_actor"] + out["loss_qvalue"]
        if self.config.learn_alpha:
            total = total + out["loss_alpha"]
        total.backward()
        return {k: out[k].detach() for k in ("loss_actor", "loss_qvalue", "alpha", "entropy")}
