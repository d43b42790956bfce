"""Fit the EKF's noise covariances Q and R by gradient descent on rollouts.

    python train/learn_filter.py --objective nll --out runs/filter_nll
    python train/learn_filter.py --objective supervised --noise-scale 2 --out runs/filter_sup

The saved ``filter_params.pt`` loads with ``make_env(..., filter_params=PATH)`` or
``dockingrl train ... --filter-params PATH``. Same as ``dockingrl learn-filter``.
"""

import sys

from dockingrl.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["learn-filter", *sys.argv[1:]]))
