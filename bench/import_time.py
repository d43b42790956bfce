"""The wall-clock of ``import dockingrl``, of the first public name's import (torch, TorchRL
and the env) and of ``dockingrl --help``, each in a fresh interpreter, best of ``--rounds``.

    python bench/import_time.py --rounds 5
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

CASES = {
    "import dockingrl": [sys.executable, "-c", "import dockingrl"],
    "dockingrl.make_env": [sys.executable, "-c", "import dockingrl; dockingrl.make_env"],
    "dockingrl --help": [sys.executable, "-m", "dockingrl", "--help"],
}


def best_time(argv: list[str], rounds: int) -> float:
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        subprocess.run(argv, check=True, capture_output=True)
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    print("| command | best wall-clock (s) |\n|---|---|")
    for name, argv in CASES.items():
        print(f"| `{name}` | {best_time(argv, args.rounds):.2f} |")


if __name__ == "__main__":
    main()
