"""dockingrl: learning to dock an AUV into a funnel-shaped docking station under ocean currents
and noisy sensors, with deep reinforcement learning on TorchRL.

The public API, each name imported on first use (``import dockingrl`` loads torch only when
one is asked for):

- :func:`make_env`: a scenario's batched TorchRL env (``"compound"``, ...);
- :func:`load_recipe` and :func:`train`: a named recipe's config, and a run of it;
- :func:`load_policy` and :func:`evaluate`: a saved policy, and its success over episodes;
- :class:`OnboardPolicy`: the filter and the policy, one sensor reading at a time;
- :class:`DockingConfig` and :class:`DockingEnv`: the world and the bare env.

Importing the package also registers the Gymnasium env ``dockingrl/Docking-v0``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from dockingrl.imports import lazy_attributes

__version__ = "0.1.0"

#: each public name and the module that defines it
_EXPORTS = {
    "DockingConfig": "dockingrl.env.config",
    "DockingEnv": "dockingrl.env.docking",
    "OnboardPolicy": "dockingrl.onboard.policy",
    "SCENARIOS": "dockingrl.scenarios",
    "contact_score": "dockingrl.env.reward",
    "evaluate": "dockingrl.evaluation.runs",
    "load_policy": "dockingrl.agents.saving",
    "load_recipe": "dockingrl.recipes",
    "make_env": "dockingrl.scenarios",
    "train": "dockingrl.training.runs",
}

__all__ = [
    "SCENARIOS",
    "DockingConfig",
    "DockingEnv",
    "OnboardPolicy",
    "__version__",
    "contact_score",
    "evaluate",
    "load_policy",
    "load_recipe",
    "make_env",
    "train",
]

if TYPE_CHECKING:
    from dockingrl.agents.saving import load_policy
    from dockingrl.env.config import DockingConfig
    from dockingrl.env.docking import DockingEnv
    from dockingrl.env.reward import contact_score
    from dockingrl.evaluation.runs import evaluate
    from dockingrl.onboard.policy import OnboardPolicy
    from dockingrl.recipes import load_recipe
    from dockingrl.scenarios import SCENARIOS, make_env
    from dockingrl.training.runs import train


__getattr__, __dir__ = lazy_attributes(__name__, _EXPORTS)


def _register_gymnasium_env() -> None:
    """``gymnasium.make("dockingrl/Docking-v0")`` (entry points are strings: nothing more is
    imported until an env is made)."""
    import gymnasium

    if "dockingrl/Docking-v0" not in gymnasium.registry:
        gymnasium.register(
            id="dockingrl/Docking-v0",
            entry_point="dockingrl.gym.single:DockingScenarioEnv",
            vector_entry_point="dockingrl.gym.vector:DockingVectorEnv",
        )


_register_gymnasium_env()
