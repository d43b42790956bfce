"""Learning the EKF's noise covariances ``Q`` and ``R`` by gradient descent, and measuring a
filter setting (RMSE against the truth, NEES consistency).

The paper tuned ``Q`` by hand (Table 1) and took ``R`` from the simulator (Table 2); on a real
vehicle neither is known. Three objectives:

- ``nll``: the negative log-likelihood of the innovations, ``0.5 (y^T S^-1 y + log det S)``,
  which needs the noisy observations only (it could run on logged vehicle data);
- ``supervised``: the negative log-likelihood of ``true_state`` under the filter's Gaussian
  estimate, ``0.5 (e^T P^-1 e + log det P)`` with ``e`` the estimate's error (simulation only).
  It rewards a small error and a covariance ``P`` that states it honestly: at its optimum the
  mean NEES of the training data is the state dimension, 5.
- ``mse``: the estimate's squared error against ``true_state`` alone,
  ``sum_i log mean(e_i^2)`` over the five state components (simulation only). The log makes it
  free of units (metres, radians, m/s, rad/s) and weighs a relative gain in each component
  alike; it asks nothing of ``P``.

All three run the differentiable filter of :mod:`dockingrl.transforms.ekf` over recorded
rollouts with truncated backpropagation through time (windows of ``window`` steps).

On an env whose sensors report at their own rates (``sensor_age`` recorded, docs/realism.md)
the filter updates with the readings that arrived only, as the env's :class:`EKFTransform`
does, and the innovation objectives and metrics (NLL, NIS, whiteness) count those readings
only: a held reading is not a new measurement.

One module per concern: :mod:`~dockingrl.filter_learning.rollouts` records the data,
:mod:`~dockingrl.filter_learning.objectives` runs the filter over it and computes the
objectives, :mod:`~dockingrl.filter_learning.fit` is the optimisation loop and
:mod:`~dockingrl.filter_learning.consistency` scores a filter (RMSE, NEES, NIS).
"""

from typing import TYPE_CHECKING

from dockingrl.imports import lazy_attributes

_EXPORTS = {
    "LEARN_R": "dockingrl.filter_learning.options",
    "OBJECTIVES": "dockingrl.filter_learning.options",
    "FilterFit": "dockingrl.filter_learning.options",
    "behaviour_policy": "dockingrl.filter_learning.rollouts",
    "evaluate_filter": "dockingrl.filter_learning.consistency",
    "filter_estimates": "dockingrl.filter_learning.consistency",
    "fit_filter": "dockingrl.filter_learning.fit",
    "gaussian_nll": "dockingrl.filter_learning.objectives",
    "innovation_whiteness": "dockingrl.filter_learning.objectives",
    "masked_innovation": "dockingrl.filter_learning.objectives",
    "mismatched_config": "dockingrl.filter_learning.rollouts",
    "normalized_errors": "dockingrl.filter_learning.consistency",
    "record_rollouts": "dockingrl.filter_learning.rollouts",
    "run_averaged_nees_test": "dockingrl.filter_learning.consistency",
    "run_filter": "dockingrl.filter_learning.objectives",
    "state_error": "dockingrl.filter_learning.objectives",
    "whiten": "dockingrl.filter_learning.objectives",
}

__all__ = [
    "LEARN_R",
    "OBJECTIVES",
    "FilterFit",
    "behaviour_policy",
    "evaluate_filter",
    "filter_estimates",
    "fit_filter",
    "gaussian_nll",
    "innovation_whiteness",
    "masked_innovation",
    "mismatched_config",
    "normalized_errors",
    "record_rollouts",
    "run_averaged_nees_test",
    "run_filter",
    "state_error",
    "whiten",
]

if TYPE_CHECKING:
    from dockingrl.filter_learning.consistency import (
        evaluate_filter,
        filter_estimates,
        normalized_errors,
        run_averaged_nees_test,
    )
    from dockingrl.filter_learning.fit import fit_filter
    from dockingrl.filter_learning.objectives import (
        gaussian_nll,
        innovation_whiteness,
        masked_innovation,
        run_filter,
        state_error,
        whiten,
    )
    from dockingrl.filter_learning.options import LEARN_R, OBJECTIVES, FilterFit
    from dockingrl.filter_learning.rollouts import (
        behaviour_policy,
        mismatched_config,
        record_rollouts,
    )

__getattr__, __dir__ = lazy_attributes(__name__, _EXPORTS)
