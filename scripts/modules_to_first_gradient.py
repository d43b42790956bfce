"""The dockingrl modules whose code runs from the command line to the first gradient step of a
training run: ``python scripts/modules_to_first_gradient.py train --recipe ppo``.

Every call into a dockingrl function is recorded until the first optimiser step, then the run
stops; the modules are printed in the order they were first entered. What runs while a module
is imported (its module-level code, its class bodies, the functions they call) is left out:
importing is not passing through. The last lines give the call path at the first step: the
modules on the stack from the command line to the optimiser."""

from __future__ import annotations

import sys
import tempfile
import threading


class FirstStep(Exception):
    """Raised by the first optimiser step."""


def main(argv: list[str]) -> int:
    import torch

    from dockingrl.cli import main as cli

    seen: dict[str, None] = {}

    top = sys._getframe()  # what called this script is not on the way

    def importing(frame) -> bool:
        """Whether ``frame`` runs within an import: below a module's top-level code."""
        while frame is not None and frame is not top:
            if frame.f_code.co_name == "<module>":
                return True
            frame = frame.f_back
        return False

    def profile(frame, event, arg):
        if event == "call":
            name = frame.f_globals.get("__name__", "")
            if name.startswith("dockingrl") and name not in seen and not importing(frame):
                seen[name] = None

    reached = []

    path: dict[str, None] = {}

    def stop(self, *args, **kwargs):
        sys.setprofile(None)  # what handles the stop is not on the way to it
        reached.append(True)  # the command line turns the exception into its exit
        frame, stack = sys._getframe(1), []
        while frame is not None:
            name = frame.f_globals.get("__name__", "")
            if name.startswith("dockingrl"):
                stack.append(name)
            frame = frame.f_back
        path.update(dict.fromkeys(reversed(stack)))
        raise FirstStep

    step, torch.optim.Adam.step = torch.optim.Adam.step, stop
    with tempfile.TemporaryDirectory() as out:
        sys.setprofile(profile)
        threading.setprofile(profile)
        try:
            cli([*argv, "--out", out, "--logger", "none"])
        except (FirstStep, SystemExit):
            pass
        finally:
            sys.setprofile(None)
            threading.setprofile(None)
            torch.optim.Adam.step = step
    if not reached:
        print("the command ended before its first gradient step", file=sys.stderr)
        return 1
    for name in seen:
        print(name)
    print(f"{len(seen)} modules")
    print("call path: " + " -> ".join(path))
    print(f"{len(path)} modules on the call path")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:] or ["train", "--recipe", "ppo", "--threads", "1"]))
