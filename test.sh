#!/usr/bin/env bash
# Set-up and the whole test suite (a few minutes on 2 CPU cores).
set -euo pipefail
cd "$(dirname "$0")"
bash scripts/install.sh
${PYTHON:-python3} -m pytest -q tests "$@"
