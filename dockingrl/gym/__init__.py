"""dockingrl for Gymnasium and stable-baselines3 users: the paper's four scenarios as a
``gymnasium.Env`` (``gymnasium.make("dockingrl/Docking-v0", scenario=...)``), the batched env as a
native ``gymnasium.vector.VectorEnv`` (``gymnasium.make_vec``), and adapters for
stable-baselines3's ``VecEnv`` and for evaluating its models with :func:`dockingrl.evaluate`."""

from dockingrl.gym.single import DockingScenarioEnv, observation_space, scenario_pipeline
from dockingrl.gym.vector import DockingVectorEnv

__all__ = ["DockingScenarioEnv", "DockingVectorEnv", "observation_space", "scenario_pipeline"]
