"""Policies: the managed surge controller baseline and the SAC / TD3 / PPO agents.

``networks`` (MLPs, critics, actors), ``mirror`` (the mirror through the
docking axis), ``averaging`` (the actor's moving average), ``nstep`` (n-step targets), ``base``
(the ``Agent``), ``off_policy`` (what SAC and TD3 share), one module per algorithm (``sac``,
``td3``, ``ppo``) and ``registry`` (``make_agent``, ``build_actor``)."""

from dockingrl.agents.averaging import ActorAverage
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
from dockingrl.agents.off_policy import (
    TRANSITION_KEYS,
    OffPolicyAgent,
    transition_keys,
)
from dockingrl.agents.ppo import PPOAgent
from dockingrl.agents.registry import AGENTS, agent_class, build_actor, make_agent
from dockingrl.agents.sac import SACAgent
from dockingrl.agents.td3 import TD3Agent

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
