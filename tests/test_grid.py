"""``dockingrl grid``: grid files, the order of trials, and a grid that survives a SIGKILL of
its driver (local Ray)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import fake_run

from dockingrl.agents.config import SACConfig
from dockingrl.agents.config_diff import config_mismatch
from dockingrl.grid import load_grid, progress
from dockingrl.grid.folders import finished_summary

ROOT = Path(__file__).resolve().parents[1]

TINY_PPO = (
    "{total_steps: 2400, num_envs: 4, steps_per_env: 50, minibatch_size: 100, epochs: 2, "
    "hidden: [32, 32], eval_every: 2400, eval_episodes: 2, final_eval_episodes: 4, "
    "select_episodes: 4, checkpoint_every: 800, logger: none}"
)


def write_grid(tmp_path: Path, seeds=(0, 1)) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(
        f"name: tiny\nout: {tmp_path / 'runs'}\ncollect: {tmp_path / 'collect'}\nthreads: 1\n"
        f"scenarios: [noise]\noverrides: {TINY_PPO}\n"
        f"groups:\n  - recipes: [ppo]\n    seeds: {list(seeds)}\n"
    )
    return path


def test_table6_is_the_papers_grid_on_held_out_seeds():
    grid = load_grid("table6")
    names = [t.name for t in grid.trials]
    held_out = range(100, 105)
    assert len(names) == 3 * 4 * 5 + 4
    for recipe in ("sac", "td3", "ppo"):
        for scenario in ("no_noise", "noise", "filtered", "compound"):
            assert {f"{recipe}__{scenario}__s{s}" for s in held_out} <= set(names)
    assert {f"paper-sac__{s}__s100" for s in ("no_noise", "noise", "filtered", "compound")} <= set(
        names
    )
    assert min(t.seed for t in grid.trials) >= 100  # no tuning seed among reported figures
    # every cell's first seed starts before any second one
    seeds = [t.seed for t in grid.trials]
    assert seeds == sorted(seeds)
    configs = [t.config(grid.out, 1) for t in grid.trials]
    assert all(c.final_eval_episodes == 2000 for c in configs)


def test_table6_estimates_are_its_finished_trials_mean_wall_clock(tmp_path):
    """Each recipe's ``estimate_s`` (what ``--hours`` plans with before a trial of the recipe
    has finished, and what docs/grid.md costs the grid at) stays within 15 % of the mean
    training wall-clock of its trials in results/table6/trials."""
    grid = load_grid("table6", out=tmp_path, collect=str(ROOT / "results" / "table6" / "trials"))
    finished: dict[str, list[float]] = {}
    estimates = {}
    for trial in grid.trials:
        estimates[trial.recipe] = trial.estimate_s
        if (summary := finished_summary(grid, trial)) is not None:
            finished.setdefault(trial.recipe, []).append(summary["train_wall_clock_s"])
    assert finished, "no finished trial to measure the estimates on"
    for recipe, times in finished.items():
        mean, estimate = sum(times) / len(times), estimates[recipe]
        assert abs(estimate - mean) <= 0.15 * mean, (recipe, estimate, round(mean))


@pytest.mark.parametrize(
    "text, message",
    [
        ("groups: 3\n", "list of groups"),
        ("groups:\n  - recipes: [nope]\n", "unknown recipe"),
        ("groups:\n  - recipes: [sac]\n    scenarios: [sea]\n", "unknown scenario"),
        ("groups:\n  - recipes: [sac]\n    seeds: [-1]\n", "seeds"),
        ("groups:\n  - recipes: [sac]\n    colour: red\n", "group 0"),
        ("threads: 0\ngroups:\n  - recipes: [sac]\n", "threads"),
        ("overrides: {gamma: 3}\ngroups:\n  - recipes: [sac]\n", "gamma"),
        ("groups:\n  - recipes: [sac, sac]\n", "twice"),
        ("groups: []\n", "no trials"),
        ("groups:\n  - recipes: [sac]\n    seeds: 3\n", "seeds must be a list"),
        ("overrides: [1]\ngroups:\n  - recipes: [sac]\n", "overrides must be a mapping"),
        ("groups:\n  - recipes: [sac]\n    overrides: 5\n", "group 0: overrides must be"),
        (
            "groups:\n  - recipes: [sac]\n    estimate_s: abc\n",
            "estimate_s must be a finite number",
        ),
        ("groups:\n  - recipes: sac\n", "recipes must be a list of names"),
        ("scenarios: compound\ngroups:\n  - recipes: [sac]\n", "scenarios must be a list"),
        ("groups:\n  - recipes: [sac]\n    estimate_s: .nan\n", "estimate_s must be a finite"),
        ("out: 5\ngroups:\n  - recipes: [sac]\n", "out must be a string"),
        ("name: [a, b]\ngroups:\n  - recipes: [sac]\n", "name must be a string"),
        ("threads: true\ngroups:\n  - recipes: [sac]\n", "threads must be an integer"),
        ("overrides: {1: 2}\ngroups:\n  - recipes: [sac]\n", "overrides must be a mapping"),
    ],
)
def test_bad_grid_files_are_refused_before_anything_runs(tmp_path, text, message):
    path = tmp_path / "g.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        load_grid(path)
    assert "\n" not in str(info.value)


def test_a_binary_grid_file_is_one_line(tmp_path):
    path = tmp_path / "g.yaml"
    path.write_bytes(b"\xff\xfe\x00groups")
    with pytest.raises(ValueError, match="g.yaml: not a readable text file"):
        load_grid(path)


def test_damaged_trial_files_are_neither_finished_nor_a_traceback(tmp_path, capsys):
    from dockingrl.cli import main
    from dockingrl.grid import run_trial

    grid = load_grid(write_grid(tmp_path, seeds=(0, 1)))
    torn, listed = (grid.run_dir(t) for t in grid.trials)
    torn.mkdir(parents=True)
    cfg = grid.trials[0].config(grid.out, grid.threads)
    (torn / "config.json").write_text(json.dumps(cfg.to_dict()))
    (torn / "summary.json").write_text('{"algo": "ppo", "scen')  # torn by a power cut
    result = run_trial(grid.trials[0], str(grid.out), 1)
    assert result["status"] == "failed"
    assert "summary.json: damaged" in result["error"] and "\n" not in result["error"]
    listed.mkdir(parents=True)
    (listed / "summary.json").write_text(json.dumps({"success_rate": "high"}))
    assert main(["grid", str(write_grid(tmp_path, seeds=(0, 1))), "--list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].endswith("not finished") and out[1].endswith("finished, unknown")


def test_a_trial_of_another_config_is_named():
    saved = {"gamma": 0.99, "threads": 1, "hidden": [32, 32]}
    assert config_mismatch(saved, {"gamma": 0.98, "threads": 2, "hidden": (32, 32)}) == ["gamma"]
    # a field added after the run started counts as its default in the saved config
    defaults = SACConfig().to_dict()
    wanted = {**saved, "train_level": "L0"}
    assert config_mismatch(saved, wanted, defaults) == []
    assert config_mismatch(saved, {**saved, "train_level": "L5"}, defaults) == ["train_level"]
    assert config_mismatch(saved, wanted) == ["train_level"]  # without defaults: differs


def test_progress_reads_the_end_of_the_curves(tmp_path):
    (tmp_path / "curves.csv").write_text(
        "step,key,value\n100,train/episodes,1\n200,eval/success_rate,40.0\n300,time/updates,3\n"
    )
    assert progress(tmp_path) == {"steps": 300, "success": 40.0}
    assert progress(tmp_path / "none") == {"steps": 0, "success": None}


def _grid_command(path: Path) -> list[str]:
    return [
        sys.executable,
        "-m",
        "dockingrl",
        "grid",
        str(path),
        "--max-concurrent",
        "1",
        "--view-every",
        "1",
    ]


def test_a_grid_resumes_after_its_driver_is_killed(tmp_path):
    pytest.importorskip("ray")
    path = write_grid(tmp_path)
    runs = tmp_path / "runs"
    first, second = runs / "ppo__noise__s0", runs / "ppo__noise__s1"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "RAY_AUTH_MODE": "disabled"}
    driver = subprocess.Popen(
        _grid_command(path), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        deadline = time.time() + 600  # a hang guard; Ray starts slowly on a loaded machine
        # kill it once the first trial has finished and the second has checkpointed
        while not (
            (first / "summary.json").exists() and (second / "checkpoints" / "latest.json").exists()
        ):
            assert driver.poll() is None, "the grid ended before it could be killed"
            assert time.time() < deadline, "the grid made no progress"
            time.sleep(0.2)
        driver.send_signal(signal.SIGKILL)
        driver.wait()
        assert not (second / "summary.json").exists()
        finished_at = (first / "summary.json").stat().st_mtime_ns
        rerun = subprocess.run(
            _grid_command(path), env=env, capture_output=True, text=True, timeout=300
        )
        assert rerun.returncode == 0, rerun.stdout[-2000:] + rerun.stderr[-2000:]
    finally:
        if driver.poll() is None:
            driver.kill()
    assert (first / "summary.json").stat().st_mtime_ns == finished_at  # not rerun
    summary = json.loads((second / "summary.json").read_text())
    assert summary["frames"] >= 2400
    rows = (second / "curves.csv").read_text().splitlines()[1:]
    keys = [tuple(r.split(",")[:2]) for r in rows]
    assert len(keys) == len(set(keys)), "a step was logged twice"
    for trial in (first, second):
        assert (tmp_path / "collect" / trial.name / "summary.json").exists()
        assert (tmp_path / "collect" / trial.name / "policy.pt").exists()


def test_a_trial_whose_worker_dies_is_started_again_after_a_pause(tmp_path, monkeypatch):
    pytest.importorskip("ray")
    from dockingrl.grid import driver

    deaths = tmp_path / "deaths"
    deaths.mkdir()

    def dies_twice(trial, out, threads):  # pickled by value into the Ray worker
        died = list(deaths.iterdir())
        if len(died) < 2:
            (deaths / str(len(died))).touch()
            os._exit(1)  # the worker process dies, as when the kernel kills it for memory
        return {"name": trial.name, "status": "finished", "error": ""}

    monkeypatch.setattr(driver, "run_trial", dies_twice)
    monkeypatch.setattr(driver, "RETRY_PAUSE_S", 0.5)
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    grid = load_grid(write_grid(tmp_path, seeds=(0,)))
    grid.collect = None
    started = time.time()
    states = driver.run_grid(grid, max_concurrent=1, view_every=1)
    assert states == {"ppo__noise__s0": "finished"}
    assert len(list(deaths.iterdir())) == 2
    assert time.time() - started >= 0.5 + 1.0  # the two pauses, 0.5 s then doubled

    deaths_forever = tmp_path / "forever"

    def always_dies(trial, out, threads):
        deaths_forever.mkdir(exist_ok=True)
        (deaths_forever / str(len(list(deaths_forever.iterdir())))).touch()
        os._exit(1)

    monkeypatch.setattr(driver, "run_trial", always_dies)
    monkeypatch.setattr(driver, "RETRY_PAUSE_S", 0.1)
    states = driver.run_grid(grid, max_concurrent=1, view_every=1)
    assert states == {"ppo__noise__s0": "failed"}
    assert len(list(deaths_forever.iterdir())) == 1 + driver.WORKER_RETRIES


def test_part_of_a_grid_runs_by_trial_name_with_its_own_threads(tmp_path):
    from dockingrl.grid import select_trials

    grid = load_grid(write_grid(tmp_path, seeds=(0, 1, 2)))
    part = select_trials(grid, ["*__s2", "ppo__noise__s0"], threads=2)
    assert [t.name for t in part.trials] == ["ppo__noise__s0", "ppo__noise__s2"]  # grid order
    assert part.threads == 2 and part.out == grid.out and part.collect == grid.collect
    assert select_trials(grid).trials == grid.trials and select_trials(grid).threads == 1
    with pytest.raises(ValueError, match="no trial matches 'td3__\\*'") as info:
        select_trials(grid, ["ppo__*", "td3__*"])
    assert "\n" not in str(info.value)


def test_a_trial_resumes_with_the_threads_it_is_given(tmp_path, monkeypatch):
    import dockingrl.training
    from dockingrl.grid import run_trial

    grid = load_grid(write_grid(tmp_path, seeds=(0,)))
    trial = grid.trials[0]
    run_dir = grid.run_dir(trial)
    run_dir.mkdir(parents=True)
    (run_dir / "config.json").write_text(json.dumps(trial.config(grid.out, 1).to_dict()))
    calls = []
    monkeypatch.setattr(dockingrl.training, "train", lambda cfg, **kw: calls.append(kw))
    assert run_trial(trial, str(grid.out), 2)["status"] == "finished"
    assert calls[0]["resume"] == run_dir and calls[0]["overrides"] == {"threads": 2}


def test_the_table_of_a_grid_run_in_part_is_the_whole_grids(tmp_path, capsys):
    pytest.importorskip("ray")
    from dockingrl.cli import main

    path = write_grid(tmp_path)
    grid = load_grid(path)
    configs = [t.config(grid.out, 1).to_dict() for t in grid.trials]
    fake_run(grid.collect, "ppo", "ppo", "noise", 0, 50.0, config=configs[0])
    table = tmp_path / "table"
    assert main(["grid", str(path), "--only", "*__s0", "--table", str(table)]) == 0
    assert "table not written: 1 trials" in capsys.readouterr().out
    assert not table.exists()  # a table of seed 0 alone would pass for the grid's
    fake_run(grid.collect, "ppo", "ppo", "noise", 1, 70.0, config=configs[1])
    assert main(["grid", str(path), "--only", "*__s0", "--table", str(table)]) == 0
    cells = json.loads((table / "table.json").read_text())["cells"]
    assert [(c["seeds"], c["success_mean"]) for c in cells] == [([0, 1], 60.0)]
    # policies are kept unless pruning is asked for: other results may load any seed's
    seeds = [grid.collect / f"ppo__noise__s{seed}" / "policy.pt" for seed in (0, 1)]
    assert all(p.exists() for p in seeds)
    argv = ["grid", str(path), "--table", str(table), "--prune-policies"]
    assert main(argv) == 0
    assert [p.exists() for p in seeds] == [False, True]  # the best seed's stays


def test_a_finished_trial_of_another_config_is_neither_counted_nor_rerun(tmp_path, capsys):
    from dockingrl.cli import main
    from dockingrl.grid import finished_summary, finished_trial

    path = write_grid(tmp_path)
    grid = load_grid(path)
    configs = [t.config(grid.out, 1).to_dict() for t in grid.trials]
    fake_run(grid.collect, "ppo", "ppo", "noise", 0, 50.0, config=configs[0])
    # the grid's recipe changed since seed 1 finished: its result is of another config
    fake_run(grid.out, "ppo", "ppo", "noise", 1, 70.0, config={**configs[1], "lr": 0.01})
    assert finished_summary(grid, grid.trials[0])["machine"] == "m"
    assert finished_summary(grid, grid.trials[1]) is None
    summary, refusal = finished_trial(grid, grid.trials[1])
    assert summary is not None and "holds a run of another config (lr differ)" in refusal
    assert main(["grid", str(path), "--list"]) == 0
    listed = capsys.readouterr().out.splitlines()
    assert "finished, 50.0 %" in listed[0] and "finished with another config" in listed[1]
    stale = grid.run_dir(grid.trials[1]) / "summary.json"
    before = stale.read_bytes()
    table = tmp_path / "table"
    # nothing to run: the stale trial fails without starting Ray, and no table is written
    assert main(["grid", str(path), "--table", str(table)]) == 1
    assert "1 of 2 trials not finished" in capsys.readouterr().out
    assert stale.read_bytes() == before and not table.exists()


def test_a_stopping_grid_signals_only_a_process_that_holds_the_lock(tmp_path):
    from dockingrl.training import RunLock

    assert RunLock.holder(tmp_path) is None  # no lock file
    with RunLock(tmp_path):
        assert RunLock.holder(tmp_path) == os.getpid()
    # the lock file keeps the PID of a process that has ended, a number another may take
    assert (tmp_path / "run.lock").read_text().strip() == str(os.getpid())
    assert RunLock.holder(tmp_path) is None


def test_more_trials_than_cores_share_them():
    from dockingrl.grid.driver import task_cpus

    assert task_cpus(cpus=16, threads=2, limit=8) == 2.0  # they fit: their threads each
    assert task_cpus(cpus=2, threads=1, limit=3) == 0.666  # a share, just under 2/3
    assert 3 * task_cpus(cpus=2, threads=1, limit=3) <= 2
    assert task_cpus(cpus=16, threads=4, limit=6) == 2.0  # whole CPUs above one
    assert 6 * task_cpus(cpus=16, threads=4, limit=6) <= 16


def test_a_trial_is_expected_to_take_as_long_as_its_finished_kin():
    from dockingrl.grid.driver import _estimate
    from dockingrl.grid.files import Trial

    kin = [Trial("sac", "compound", s, {"total_steps": 9}, estimate_s=100.0) for s in range(3)]
    other = Trial("sac", "compound", 3, {"total_steps": 8}, estimate_s=50.0)
    done = {
        kin[0].name: {"train_wall_clock_s": 300.0, "selection_wall_clock_s": 100.0},
        kin[1].name: {"train_wall_clock_s": 200.0},
        other.name: {"train_wall_clock_s": 9999.0},  # other overrides: another total
    }
    assert _estimate(kin[2], kin + [other], done) == pytest.approx(1.1 * 300.0)
    assert _estimate(kin[2], kin + [other], {}) == 100.0  # none finished: the grid file's


def test_max_concurrent_above_the_cores_runs_every_trial_at_once(tmp_path, monkeypatch):
    """One more trial than the machine has cores, with ``max_concurrent`` that high: each
    trial starts before any ends (a local Ray of the machine's CPUs)."""
    pytest.importorskip("ray")
    from dockingrl.grid import driver

    marks = tmp_path / "marks"
    marks.mkdir()

    def waits_for_all(trial, out, threads):  # pickled by value into the Ray worker
        (marks / f"start_{trial.name}").touch()
        deadline = time.time() + 60
        while len(list(marks.glob("start_*"))) < n and time.time() < deadline:
            time.sleep(0.1)
        # how many trials had started when this one ended
        (marks / f"end_{trial.name}").write_text(str(len(list(marks.glob("start_*")))))
        return {"name": trial.name, "status": "finished", "error": ""}

    n = (os.cpu_count() or 1) + 1
    monkeypatch.setattr(driver, "run_trial", waits_for_all)
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    grid = load_grid(write_grid(tmp_path, seeds=tuple(range(n))))
    grid.collect = None
    states = driver.run_grid(grid, max_concurrent=n, view_every=1)
    assert set(states.values()) == {"finished"}
    # every trial saw all n started before it ended (one run alone would give up after 60 s
    # having seen fewer), however slowly a loaded machine starts them
    ends = sorted(marks.glob("end_*"))
    assert len(ends) == n and [int(p.read_text()) for p in ends] == [n] * n


def test_the_cost_bench_extrapolates_the_rate_past_the_warm_up():
    """bench/grid_cost.py: a run that took 100 s for its first 10 k env steps (random start,
    compiling), then 50 steps/s, is estimated from the later rate, not the mean one."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "grid_cost", Path(__file__).parents[1] / "bench" / "grid_cost.py"
    )
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    points = [(1000 * k, 10.0 * k) for k in range(1, 11)]  # 100 steps/s to 10 k
    points += [(10_000 + 1000 * k, 100.0 + 20.0 * k) for k in range(1, 16)]  # then 50 steps/s
    row = bench.extrapolate(points, 100_000, warm_steps=10_000)
    assert row["steps_per_s"] == pytest.approx(50.0)
    assert row["estimate_s"] == pytest.approx(100 + 90_000 / 50)
    with pytest.raises(ValueError, match="--seconds"):
        bench.extrapolate(points[:8], 100_000, warm_steps=10_000)
