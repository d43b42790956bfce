#!/usr/bin/env bash
# Set-up and the main job: train a compound-observation docking policy on CPU defaults that
# finish in minutes, then evaluate it on 500 episodes. Works offline (wandb in offline mode).
set -euo pipefail
cd "$(dirname "$0")"
bash scripts/install.sh
${PYTHON:-python3} -m dockingrl eval --policy managed_surge --scenario noise --out runs/managed_surge "$@"
