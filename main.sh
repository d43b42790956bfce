#!/usr/bin/env bash
# Set-up and the main job: train a compound-observation PPO docking policy with the `ppo`
# recipe (dockingrl/recipes/ppo.yaml), 4.5 M env steps on both cores, then evaluate it on 2,000
# episodes: 153-166 s from the start of training to the printed success rate on a 2-core AMD
# EPYC (2.4 GHz, no AVX-512), seeds 100-104, 96.40-98.25 % (results/main_job/). Works
# offline; the run folder goes under runs/. Add options to change it, e.g.
# `bash main.sh --seed 100`.
set -euo pipefail
cd "$(dirname "$0")"
bash scripts/install.sh
${PYTHON:-python3} -m dockingrl train --recipe ppo --scenario compound --out runs "$@"
