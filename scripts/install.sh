#!/usr/bin/env bash
# Installs dockingrl and its dependencies into the current Python (use a virtual environment on
# a system Python that refuses pip: `python3 -m venv .venv && . .venv/bin/activate`, or set
# PYTHON). torch comes first, as the 2.13.0 CPU build, so that nothing pulls the CUDA wheels:
# from pip's own indexes or wheelhouse when they hold it, else from PyTorch's CPU index
# (TORCH_INDEX_URL overrides it), else the plain 2.13.0 wheel (macOS, whose wheels are CPU-only).
# A torch 2.13 already installed, of any build (a CUDA one included), is kept.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
pip_install() { "$PYTHON" -m pip install -q --disable-pip-version-check "$@"; }
# Two set-ups at once (two `bash main.sh` started together) would race in pip's install of the
# same Python: where flock exists, the second waits for the first.
if command -v flock >/dev/null 2>&1; then
    exec 9>"${TMPDIR:-/tmp}/dockingrl-install-$(id -u).lock"
    flock 9
fi
if ! "$PYTHON" -c 'import sys, torch; sys.exit(not torch.__version__.startswith("2.13."))' 2>/dev/null; then
    pip_install torch==2.13.0+cpu 2>/dev/null \
        || pip_install torch==2.13.0+cpu --extra-index-url "${TORCH_INDEX_URL:-https://download.pytorch.org/whl/cpu}" \
        || pip_install torch==2.13.0
fi
pip_install -e ".[dev,grid,stats,onboard]"
