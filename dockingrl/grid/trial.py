"""One trial of a grid, as a Ray worker runs it: trained to its end in its run folder, resumed
from its checkpoint where the folder holds one."""

from __future__ import annotations

import time
from pathlib import Path

from dockingrl.agents.config_diff import saved_differs
from dockingrl.grid.files import Trial
from dockingrl.grid.folders import another_config, read_json


def run_trial(trial: Trial, out: str, threads: int) -> dict:
    """Train ``trial`` to its end in ``out/NAME``: resumed from its checkpoint if its folder
    holds a run, else started; a finished one is left as it is. Waits while another process
    trains in the folder (a trial left running by a driver that was killed). Returns
    ``{"name", "status": finished | interrupted | failed, "error"}``."""
    import contextlib
    import traceback

    import torch

    from dockingrl.training import RunInUse, TrainingInterrupted, train

    torch.set_num_threads(threads)
    run_dir = Path(out) / trial.name
    run_dir.mkdir(parents=True, exist_ok=True)
    result = {"name": trial.name, "status": "finished", "error": ""}
    with (run_dir / "train.log").open("a") as log:
        with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            while True:
                try:
                    cfg = trial.config(Path(out), threads)
                    saved = read_json(run_dir / "config.json")
                    if saved is not None:
                        changed = saved_differs(saved, cfg)
                        if changed:
                            raise ValueError(another_config(run_dir, changed))
                    if (run_dir / "summary.json").exists():
                        if read_json(run_dir / "summary.json") is None:
                            raise ValueError(
                                f"{run_dir / 'summary.json'}: damaged (not a JSON object); "
                                "remove it to finish the trial again from its checkpoint"
                            )
                        return result
                    if saved is not None:
                        train(
                            None,
                            resume=run_dir,
                            progress=False,
                            command=_command(trial),
                            overrides={"threads": threads},
                        )
                    else:
                        train(cfg, progress=False, command=_command(trial))
                    return result
                except RunInUse:
                    time.sleep(5.0)
                except TrainingInterrupted as exc:
                    return {**result, "status": "interrupted", "error": str(exc)}
                except Exception as exc:  # reported by the driver; the other trials go on
                    traceback.print_exc()
                    return {**result, "status": "failed", "error": f"{type(exc).__name__}: {exc}"}


def _command(trial: Trial) -> str:
    return f"dockingrl grid (trial {trial.name})"
