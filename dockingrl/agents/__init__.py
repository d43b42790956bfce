"""Policies: the managed surge controller baseline and the SAC / TD3 / PPO agents.

``networks`` (MLPs, critics, actors, their dropout and the actor's moving average), ``mirror``
(the mirror through the docking axis), ``nstep`` (n-step targets), ``base``
(the ``Agent``), ``off_policy`` (what SAC and TD3 share), one module per algorithm (``sac``,
``td3``, ``ppo``) and ``registry`` (``make_agent``, ``build_actor``)."""

from typing import TYPE_CHECKING

from dockingrl.imports import lazy_attributes

_EXPORTS = {
    "AGENTS": "dockingrl.agents.registry",
    "ActorAverage": "dockingrl.agents.networks",
    "Agent": "dockingrl.agents.base",
    "ManagedSurgeConstants": "dockingrl.agents.managed_surge",
    "ManagedSurgePolicy": "dockingrl.agents.managed_surge",
    "MirrorSymmetric": "dockingrl.agents.mirror",
    "MirroredPolicy": "dockingrl.agents.mirror",
    "NStepWindow": "dockingrl.agents.nstep",
    "ObservationScale": "dockingrl.agents.networks",
    "OffPolicyAgent": "dockingrl.agents.off_policy",
    "PPOAgent": "dockingrl.agents.ppo",
    "PRIVILEGED_DIM": "dockingrl.agents.networks",
    "PRIVILEGED_KEYS": "dockingrl.agents.networks",
    "QValueModule": "dockingrl.agents.networks",
    "SACAgent": "dockingrl.agents.sac",
    "TD3Agent": "dockingrl.agents.td3",
    "TRANSITION_KEYS": "dockingrl.agents.off_policy",
    "TensorModule": "dockingrl.agents.networks",
    "agent_class": "dockingrl.agents.registry",
    "build_actor": "dockingrl.agents.registry",
    "config_mirror_signs": "dockingrl.agents.mirror",
    "deterministic_actor": "dockingrl.agents.networks",
    "make_agent": "dockingrl.agents.registry",
    "make_critic": "dockingrl.agents.networks",
    "managed_surge_action": "dockingrl.agents.managed_surge",
    "mirror_observation_signs": "dockingrl.agents.mirror",
    "mirror_transitions": "dockingrl.agents.mirror",
    "mlp": "dockingrl.agents.networks",
    "n_step_transitions": "dockingrl.agents.nstep",
    "observation_scale": "dockingrl.agents.networks",
    "privileged_features": "dockingrl.agents.networks",
    "stochastic_actor": "dockingrl.agents.networks",
    "transition_keys": "dockingrl.agents.off_policy",
}

__all__ = [
    "AGENTS",
    "PRIVILEGED_DIM",
    "PRIVILEGED_KEYS",
    "TRANSITION_KEYS",
    "ActorAverage",
    "Agent",
    "ManagedSurgeConstants",
    "ManagedSurgePolicy",
    "MirrorSymmetric",
    "MirroredPolicy",
    "NStepWindow",
    "ObservationScale",
    "OffPolicyAgent",
    "PPOAgent",
    "QValueModule",
    "SACAgent",
    "TD3Agent",
    "TensorModule",
    "agent_class",
    "build_actor",
    "config_mirror_signs",
    "deterministic_actor",
    "make_agent",
    "make_critic",
    "managed_surge_action",
    "mirror_observation_signs",
    "mirror_transitions",
    "mlp",
    "n_step_transitions",
    "observation_scale",
    "privileged_features",
    "stochastic_actor",
    "transition_keys",
]

if TYPE_CHECKING:
    from dockingrl.agents.base import Agent
    from dockingrl.agents.managed_surge import (
        ManagedSurgeConstants,
        ManagedSurgePolicy,
        managed_surge_action,
    )
    from dockingrl.agents.mirror import (
        MirroredPolicy,
        MirrorSymmetric,
        config_mirror_signs,
        mirror_observation_signs,
        mirror_transitions,
    )
    from dockingrl.agents.networks import (
        PRIVILEGED_DIM,
        PRIVILEGED_KEYS,
        ActorAverage,
        ObservationScale,
        QValueModule,
        TensorModule,
        deterministic_actor,
        make_critic,
        mlp,
        observation_scale,
        privileged_features,
        stochastic_actor,
    )
    from dockingrl.agents.nstep import NStepWindow, n_step_transitions
    from dockingrl.agents.off_policy import TRANSITION_KEYS, OffPolicyAgent, transition_keys
    from dockingrl.agents.ppo import PPOAgent
    from dockingrl.agents.registry import AGENTS, agent_class, build_actor, make_agent
    from dockingrl.agents.sac import SACAgent
    from dockingrl.agents.td3 import TD3Agent

__getattr__, __dir__ = lazy_attributes(__name__, _EXPORTS)
