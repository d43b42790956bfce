#!/usr/bin/env bash
# Set-up and the main job: train a compound-observation PPO docking policy with the `ppo`
# recipe (dockingrl/recipes/ppo.yaml), 3 M env steps (348-877 s of training in the Table 6
# ppo compound trials on a 2-core AMD EPYC, each beside another run, results/table6/), then
# evaluate it on 2,000 episodes. Works offline; the run folder goes under runs/. Add
# options to change it, e.g. `bash main.sh --seed 100`.
set -euo pipefail
cd "$(dirname "$0")"
bash scripts/install.sh
${PYTHON:-python3} -m dockingrl train --recipe ppo --scenario compound --out runs "$@"
