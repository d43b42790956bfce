"""A training process killed with SIGKILL at any moment leaves a run that ``--resume``
completes, with ``curves.csv`` and the logger backend holding every step once."""

import csv
import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from dockingrl.agents.config import make_config
from dockingrl.training import read_curves, train

CONFIG = {
    "scenario": "noise",
    "total_steps": 800,
    "num_envs": 4,
    "start_steps": 100,
    "frames_per_batch": 100,
    "batch_size": 32,
    "hidden": [32, 32],
    "updates_per_step": 0.5,
    "eval_every": 300,
    "eval_episodes": 2,
    "final_eval_episodes": 4,
    "logger": "csv",
    "checkpoint_every": 200,
    "threads": 1,
}

# Runs ``train`` in a fresh process that kills itself with SIGKILL at the named moment:
# argv = moment, out, config (JSON). Counts are chosen past the first checkpoint (200 env
# steps = 2 batches of 100), except for "before_first_checkpoint".
KILLER = r"""
import json, os, signal, sys
moment, out, config = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
import torch
import torchrl.data
import dockingrl.training as training
import dockingrl.training.selection as selection
from dockingrl.agents.config import make_config
from dockingrl.env import DockingEnv

calls = {"n": 0}

def die_on(n):
    calls["n"] += 1
    if calls["n"] == n:
        os.kill(os.getpid(), signal.SIGKILL)

def wrap(owner, name, n, after=False):
    original = getattr(owner, name)
    def wrapped(*args, **kwargs):
        if not after:
            die_on(n)
        result = original(*args, **kwargs)
        if after:
            die_on(n)
        return result
    setattr(owner, name, wrapped)

if moment == "before_first_checkpoint":  # the first batch was logged, nothing checkpointed
    wrap(training.RunLogger, "log", 1, after=True)
elif moment == "collection":  # env steps of the 3rd batch (25 steps of 4 envs a batch)
    wrap(DockingEnv, "_step", 60)
elif moment == "update":  # an optimizer step inside an update of the 3rd or 4th batch
    wrap(torch.optim.Adam, "step", 150)
elif moment == "checkpoint_write":  # the 2nd checkpoint: state written, not yet in place
    wrap(torchrl.data.ReplayBuffer, "dumps", 2, after=True)
elif moment == "periodic_eval":  # inside the 2nd periodic evaluation
    original = selection.evaluate
    def evaluate(policy, scenario, episodes, **kwargs):
        if episodes == config["eval_episodes"]:
            die_on(2)
        return original(policy, scenario, episodes, **kwargs)
    selection.evaluate = evaluate
elif moment == "final_eval":  # inside the final evaluation, after policy.pt is written
    original = selection.evaluate
    def evaluate(policy, scenario, episodes, **kwargs):
        if episodes == config["final_eval_episodes"]:
            die_on(1)
        return original(policy, scenario, episodes, **kwargs)
    selection.evaluate = evaluate
else:
    raise SystemExit(f"unknown moment {moment}")
cfg = make_config("sac", "paper", out=out, run_name="run", **config)
training.train(cfg, progress=False)
raise SystemExit("not killed")
"""

MOMENTS = [
    "before_first_checkpoint",
    "collection",
    "update",
    "checkpoint_write",
    "periodic_eval",
    "final_eval",
]


def _config(out: Path, **extra):
    fields = {**CONFIG, "hidden": tuple(CONFIG["hidden"]), **extra}
    return make_config("sac", "paper", out=str(out), run_name="run", **fields)


def _backend_rows(run: Path) -> dict[str, list[tuple[int, float]]]:
    """The CSV logger backend's files: ``{key: [(step, value), ...]}``."""
    scalars = run / "csv" / run.name / "scalars"
    rows = {}
    for path in sorted(scalars.rglob("*.csv")):
        key = path.relative_to(scalars).with_suffix("").as_posix()
        with path.open() as f:
            rows[key] = [(int(s), float(v)) for s, v in csv.reader(f)]
    return rows


def _curve_rows(run: Path) -> list[tuple[int, str]]:
    with (run / "curves.csv").open() as f:
        return [(int(r["step"]), r["key"]) for r in csv.DictReader(f)]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The steps an uninterrupted run logs: every batch's, and the periodic evaluations'."""
    run = Path(train(_config(tmp_path_factory.mktemp("ref")), progress=False)["run_dir"])
    curves = read_curves(run)
    return {key: [s for s, _ in curves[key]] for key in ("time/updates", "eval/success_rate")}


@pytest.fixture(scope="module")
def killed(tmp_path_factory):
    """One process per moment, run side by side, each killed there: ``{moment: (returncode,
    stderr, out folder)}``."""
    procs = {}
    for moment in MOMENTS:
        out = tmp_path_factory.mktemp(moment)
        procs[moment] = (
            subprocess.Popen(
                [sys.executable, "-c", KILLER, moment, str(out), json.dumps(CONFIG)],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
            ),
            out,
        )
    return {m: (p.wait(timeout=600), p.stderr.read(), out) for m, (p, out) in procs.items()}


@pytest.mark.parametrize("moment", MOMENTS)
def test_a_run_killed_at_any_moment_resumes_with_each_step_logged_once(moment, killed, reference):
    returncode, stderr, out = killed[moment]
    assert returncode == -signal.SIGKILL, stderr[-2000:]
    run = out / "run"
    assert not (run / "summary.json").exists()

    result = train(None, resume=run, progress=False)
    assert result["summary"]["frames"] == CONFIG["total_steps"]
    assert (run / "summary.json").exists() and (run / "policy.pt").exists()

    rows = _curve_rows(run)
    assert len(rows) == len(set(rows)), "a (step, key) logged twice in curves.csv"
    curves = read_curves(run)
    for key, steps in reference.items():
        assert [s for s, _ in curves[key]] == steps, key
    assert [s for s, _ in curves["eval/final_success_rate"]] == [CONFIG["total_steps"]]
    # the backend holds exactly what curves.csv holds, once
    backend = _backend_rows(run)
    assert set(backend) == set(curves)
    for key, values in curves.items():
        assert backend[key] == values, key
    assert json.loads((run / "logged.json").read_text())["rows"] == len(rows)


def test_a_run_killed_before_its_first_checkpoint_can_be_started_again(tmp_path):
    """Without ``--resume``, the refusal names the flag that continues it."""
    cfg = _config(tmp_path, total_steps=200, logger="none")
    killed = subprocess.run(
        [
            sys.executable,
            "-c",
            KILLER,
            "before_first_checkpoint",
            str(tmp_path),
            json.dumps({**CONFIG, "total_steps": 200, "logger": "none"}),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-2000:]
    with pytest.raises(FileExistsError, match="--resume"):
        train(cfg, progress=False)
    result = train(None, resume=tmp_path / "run", progress=False)
    assert result["summary"]["frames"] == 200


class _Recorder:
    """A logger backend that records what it is sent, as wandb's would hold it."""

    def __init__(self):
        self.rows = []

    def log_scalar(self, key, value, step):
        self.rows.append((step, key, value))


def test_a_backend_that_cannot_be_rewritten_is_sent_each_row_once(tmp_path):
    """wandb keeps what it was sent: the rows sent before a kill are not sent again, the rows
    logged after the last checkpoint are sent only by the resumed run."""
    from dockingrl.training import RunLogger
    from dockingrl.training.checkpointing import Checkpoints

    def logger(recorder):
        log = RunLogger({}, "none", tmp_path, "run", buffered=True)
        log.backend, log.kind = recorder, "wandb"
        return log

    first = _Recorder()
    log = logger(first)
    log.sync()
    log.log({"a": 1.0, "b": 2.0}, 100)
    log.log({"a": 3.0}, 200)
    log.flush()  # the checkpoint at 200
    log.log({"a": 5.0}, 300)  # then the kill: 300 is trained again
    assert first.rows == [(100, "a", 1.0), (100, "b", 2.0), (200, "a", 3.0)]

    cfg = type("Cfg", (), {"total_steps": 1000})()
    Checkpoints(tmp_path, cfg, None, None, None, "").drop_curves_after(200)
    second = _Recorder()
    log = logger(second)
    log.sync()
    assert second.rows == []
    log.log({"a": 6.0}, 300)
    log.finish({})
    assert second.rows == [(300, "a", 6.0)]
    sent = first.rows + second.rows
    with (tmp_path / "curves.csv").open() as f:
        logged = [(int(r["step"]), r["key"], float(r["value"])) for r in csv.DictReader(f)]
    assert sent == logged


@pytest.mark.parametrize("tail", ["4", "300,eval/success_rate,4", "\0\0\0\0", "\n"])
def test_a_curves_file_cut_short_by_a_kill_resumes_without_its_torn_line(tmp_path, tail):
    """The one file appended in place: a write cut short leaves a partial last line (or
    zeros, after a crash), which the resumed run drops with the steps it trains again."""
    from dockingrl.training.logger import drop_curves_after

    whole = "step,key,value\n100,a,1.0\n200,a,3.0\n300,a,5.0\n"
    (tmp_path / "curves.csv").write_text(whole + tail)
    assert read_curves(tmp_path) == {"a": [(100, 1.0), (200, 3.0), (300, 5.0)]}
    drop_curves_after(tmp_path, 200, 1000)
    assert (tmp_path / "curves.csv").read_text() == "step,key,value\n100,a,1.0\n200,a,3.0\n"
