"""What a filter fit takes (:class:`FilterFit`, :data:`OBJECTIVES`, :data:`LEARN_R`), without
torch: the command line builds its options from these."""

from __future__ import annotations

from dataclasses import dataclass

#: the objectives a fit minimises (:mod:`dockingrl.filter_learning.objectives`)
OBJECTIVES = ("nll", "supervised", "mse")

#: Which of ``R``'s six sigmas a fit learns; the others keep their values (Table 2 unless
#: loaded): ``usbl`` learns the range and bearing sigmas only, the sensor whose noise depends on
#: the acoustic conditions, and keeps the heading, DVL and IMU sigmas of their data sheets.
LEARN_R = {"all": (0, 1, 2, 3, 4, 5), "usbl": (0, 1), "none": ()}


@dataclass
class FilterFit:
    """Options of :func:`fit_filter`."""

    objective: str = "nll"
    num_envs: int = 128
    steps: int = 600
    window: int = 50
    epochs: int = 4
    lr: float = 0.03
    behaviour: str = "managed_surge"
    seed: int = 0
    whiteness: float = 0.0  # nll only: weight of the innovations' whiteness penalty
    lags: int = 5
    learn_r: str = "all"  # which of R's sigmas are fitted (LEARN_R)
