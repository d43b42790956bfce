"""Train SAC, TD3 or PPO on one of the paper's scenarios.

    python train/train.py --algo sac --scenario compound               # the paper's SAC
    python train/train.py --algo ppo --scenario compound --preset fast # vectorised PPO
    python train/train.py --resume runs/<run folder>                   # continue a run

Same as ``dockingrl train``; ``--help`` lists every config field.
"""

import sys

from dockingrl.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["train", *sys.argv[1:]]))
