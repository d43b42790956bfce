"""``dockingrl.agents.torchrl_adapter`` holds every TorchRL private name dockingrl uses: each one
still exists in the installed TorchRL (a release that moves one fails here, not in a run), and
no other module names one."""

import re
from pathlib import Path

import pytest
from tensordict.nn import TensorDictParams
from torchrl.objectives import SACLoss, TD3Loss

from dockingrl.agents import make_agent
from dockingrl.agents.config import make_config
from dockingrl.agents.torchrl_adapter import PRIVATE_NAMES
from dockingrl.scenarios import make_env

PACKAGE = Path(__file__).resolve().parents[1] / "dockingrl"


@pytest.fixture(scope="module")
def agents():
    spec = make_env("noise", 2, seed=0).action_spec[0]
    sizes = {"hidden": (8,), "batch_size": 4, "buffer_size": 100, "fast_update": True}
    return {
        algo: make_agent(make_config(algo, "paper", **sizes), 6, spec, 30.0)
        for algo in ("sac", "td3")
    }


def test_the_private_names_exist_in_the_installed_torchrl(agents):
    sac, td3 = agents["sac"].loss, agents["td3"].loss
    updater = agents["sac"].target_updater
    for name in ("_sources", "_targets"):
        assert hasattr(updater, name), name
    assert callable(SACLoss._make_vmap) and callable(TD3Loss._make_vmap)
    assert hasattr(sac, "_vmap_qnetworkN0") and hasattr(td3, "_vmap_qvalue_network00")
    for name in ("_maybe_get_priority_weight", "_reduce_loss", "_clear_weakrefs"):
        assert callable(getattr(td3, name)), name
    assert hasattr(td3, "_cached_detach_qvalue_network_params")
    params = sac.actor_network_params
    assert isinstance(params, TensorDictParams) and hasattr(params, "_parameters")


def test_no_other_module_names_them():
    pattern = re.compile(r"\b(" + "|".join(PRIVATE_NAMES) + r"|_get_reset|_pseudo_vmap)\b")
    users = []
    for path in PACKAGE.rglob("*.py"):
        if path.name == "torchrl_adapter.py":
            continue
        code = "\n".join(line for line in path.read_text().splitlines() if "``" not in line)
        if pattern.search(code):
            users.append(str(path.relative_to(PACKAGE)))
    assert users == []
    imports = re.compile(r"from (torchrl|tensordict)[\w.]* import .*\b_\w+")
    assert [p.name for p in PACKAGE.rglob("*.py") if imports.search(p.read_text())] == []
