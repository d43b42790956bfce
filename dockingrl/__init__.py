"""dockingrl: learning to dock an AUV into a funnel-shaped docking station under ocean currents
and noisy sensors, with deep reinforcement learning on TorchRL."""

import gymnasium

from dockingrl.env import DockingConfig, DockingEnv, contact_score

__version__ = "0.1.0"

if "dockingrl/Docking-v0" not in gymnasium.registry:
    gymnasium.register(
        id="dockingrl/Docking-v0",
        entry_point="dockingrl.gym.single:DockingScenarioEnv",
        vector_entry_point="dockingrl.gym.vector:DockingVectorEnv",
    )

__all__ = ["DockingConfig", "DockingEnv", "contact_score", "__version__"]

from dockingrl.scenarios import SCENARIOS, make_env  # noqa: E402

__all__ += ["SCENARIOS", "make_env"]

from dockingrl.evaluation import evaluate  # noqa: E402

__all__ += ["evaluate"]

from dockingrl.onboard import OnboardPolicy  # noqa: E402

__all__ += ["OnboardPolicy"]
