import math

import pytest
import torch

from dockingrl.agents.managed_surge import ManagedSurgePolicy, managed_surge_action
from dockingrl.env.dynamics import observation_from_state

F = math.sqrt(2.0**2 + 0.5**2)
LIMIT = math.atan(0.5 / 2.0)


def reference(x, y, alpha, oc_x, oc_y):
    """Eqs. 13-21 by hand, scalar, numpy sign convention."""
    sign = lambda v: (v > 0) - (v < 0)  # noqa: E731
    x_ss = 0.3 - oc_x
    crab = math.atan2(-oc_y, 0.3 - oc_x)
    y_g = -(F + 0.8) * math.sin(crab) if abs(crab) <= LIMIT else -sign(crab) * 0.25
    e = y - y_g * sign(x_ss)
    beta = math.atan2(e, 6.0 * sign(x_ss))
    w_d = min(max(((crab - beta) - alpha) * 0.5, -0.3), 0.3)
    c = 0.5 * math.atan(1.0 * e) * sign(alpha)
    v_d = min(max(x_ss / math.cos(alpha) - c, -0.4), 0.8)
    return v_d, w_d


CASES = [
    (-20.0, 2.0, 0.1, 0.1, 0.04),  # inside the crab limit
    (-20.0, 2.0, 0.1, 0.1, 0.2),  # crab angle beyond the limit: y_g = -sign * F_y / 2
    (-15.0, -3.0, -0.4, 0.4, 0.0),  # current faster than v_max: negative x_ss
    (-10.0, 1.0, 0.0, 0.3, -0.1),  # x_ss = 0: sign(0) = 0
    (-28.0, 7.0, 1.4, -0.3, 0.3),  # steep heading: surge clipped
]


@pytest.mark.parametrize("case", CASES)
def test_controller_matches_hand_computation(case):
    x, y, alpha, oc_x, oc_y = case
    out = managed_surge_action(
        torch.tensor(x, dtype=torch.float64),
        torch.tensor(y, dtype=torch.float64),
        torch.tensor(alpha, dtype=torch.float64),
        torch.tensor([oc_x, oc_y], dtype=torch.float64),
    )
    v_d, w_d = reference(*case)
    assert out[0].item() == pytest.approx(v_d, abs=1e-12)
    assert out[1].item() == pytest.approx(w_d, abs=1e-12)


def test_hand_values_of_the_first_case():
    # x_ss = 0.2, theta_crab = atan2(-0.04, 0.2) = -0.197396, y_g = 0.561197, e = 1.438803,
    # beta = 0.235356 -> w_d = 0.5 * (-0.197396 - 0.235356 - 0.1) = -0.266376;
    # c = 0.5 atan(1.438803) = 0.481710 -> v_d = 0.2 / cos(0.1) - c = -0.280705
    out = managed_surge_action(
        torch.tensor(-20.0), torch.tensor(2.0), torch.tensor(0.1), torch.tensor([0.1, 0.04])
    )
    assert out[0].item() == pytest.approx(-0.280705, abs=1e-5)
    assert out[1].item() == pytest.approx(-0.266376, abs=1e-5)


def test_batched_and_policy_module():
    x = torch.tensor([c[0] for c in CASES])
    y = torch.tensor([c[1] for c in CASES])
    alpha = torch.tensor([c[2] for c in CASES])
    oc = torch.tensor([[c[3], c[4]] for c in CASES])
    batched = managed_surge_action(x, y, alpha, oc)
    assert batched.shape == (len(CASES), 2)
    zeros = torch.zeros_like(x)
    obs = observation_from_state(x, y, alpha, zeros, zeros, zeros, oc)
    from tensordict import TensorDict

    td = TensorDict({"observation": obs, "ocean_current": oc}, batch_size=[len(CASES)])
    torch.testing.assert_close(ManagedSurgePolicy()(td)["action"], batched, atol=1e-5, rtol=0)
    with pytest.raises(KeyError, match="ekf_mean"):
        ManagedSurgePolicy(use_filter=True)(td)
