#!/usr/bin/env bash
# Set-up and the main job: train a compound-observation PPO docking policy with the
# `ppo-fast-follow-lr8` recipe (dockingrl/recipes/ppo-fast-follow-lr8.yaml, on ppo-fast-follow.yaml
# and ppo-fast.yaml: each command held 0.4 s with the previous one observed, advantages once per
# rollout, a success bonus, nine training episodes in ten under a following current, the
# learning rate 8e-4, no periodic evaluation), 3 M env steps in a few minutes on 2 CPU cores,
# then evaluate it on 2,000 episodes. Works offline; the run folder goes under runs/. Add
# options to change it, e.g. `bash main.sh --seed 1`.
set -euo pipefail
cd "$(dirname "$0")"
bash scripts/install.sh
${PYTHON:-python3} -m dockingrl train --recipe ppo-fast-follow-lr8 --out runs "$@"
