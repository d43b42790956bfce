#!/usr/bin/env bash
# Set-up and the whole test suite (5-17 min on 2 CPU cores, by the machine).
set -euo pipefail
cd "$(dirname "$0")"
bash scripts/install.sh
# one test process per core (-n auto); each test runs torch on one thread (tests/conftest.py)
${PYTHON:-python3} -m pytest -q -n auto tests "$@"
