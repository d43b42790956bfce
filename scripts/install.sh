#!/usr/bin/env bash
# Installs dockingrl and its dependencies into the current Python. torch is pinned to the
# 2.13.0 CPU build first so that nothing pulls the CUDA wheels.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
"$PYTHON" -m pip install -q --disable-pip-version-check torch==2.13.0
"$PYTHON" -m pip install -q --disable-pip-version-check -e ".[dev,grid]"
