#!/usr/bin/env bash
# Set-up and the main job: train a compound-observation PPO docking policy with vectorised
# collection (64 envs), about 3 minutes on 2 CPU cores, then evaluate it on 500 episodes.
# Works offline: wandb logs in offline mode into the run folder under runs/.
set -euo pipefail
cd "$(dirname "$0")"
bash scripts/install.sh
${PYTHON:-python3} -m dockingrl train --algo ppo --scenario compound --preset fast \
    --total-steps 400000 --out runs "$@"
