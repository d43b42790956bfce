"""Every ``dockingrl`` error is one line on stderr and a non-zero exit status (2: a bad command
line, 130: interrupted, 1: anything else); the traceback only with ``--debug``."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from dockingrl import make_env
from dockingrl.agents import build_actor
from dockingrl.agents.config import make_config
from dockingrl.agents.saving import save_policy
from dockingrl.cli import main


def tiny_policy(path, scenario="compound", obs_dim=12, **config):
    """Save an untrained SAC actor (2 x 8 hidden) reading ``obs_dim`` numbers as a policy
    trained on ``scenario`` with the config fields ``config``."""
    env = make_env("noise", 1, seed=0)
    cfg = make_config("sac", "paper", scenario=scenario, hidden=(8, 8), **config)
    torch.manual_seed(0)
    actor = build_actor(cfg, obs_dim, env.action_spec, 30.0)
    save_policy(path, actor, cfg, obs_dim, env.action_spec, 30.0)
    return path


def fails(capsys, argv, code):
    """Run ``dockingrl argv`` in-process; check that it exits with ``code`` after one line on
    stderr, and return that line."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == code, err
    assert err.count("\n") == 1 and err.startswith("dockingrl: error: "), err
    assert "Traceback" not in err
    return err.strip()


@pytest.fixture(scope="module")
def compound_policy(tmp_path_factory):
    return tiny_policy(tmp_path_factory.mktemp("policy") / "policy.pt")


def bad_policy_file(kind, folder, good):
    path = folder / f"{kind}.pt"
    if kind == "directory":
        path.mkdir()
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "truncated":
        path.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    elif kind == "random bytes":
        path.write_bytes(bytes(torch.randint(0, 256, (4096,), dtype=torch.uint8).tolist()))
    elif kind == "text":
        path.write_text("policy = 'a good one'\n")
    return path


@pytest.mark.parametrize("kind", ["directory", "empty", "truncated", "random bytes", "text"])
def test_a_bad_policy_file_is_one_line_naming_it(kind, tmp_path, capsys, compound_policy):
    path = bad_policy_file(kind, tmp_path, compound_policy)
    line = fails(capsys, ["eval", "--policy", str(path), "--episodes", "2", "--quiet"], 1)
    assert str(path) in line
    line = fails(capsys, ["export", "--policy", str(path), "--out", str(tmp_path / "p.pt2")], 1)
    assert str(path) in line


def test_a_missing_policy_file_is_one_line(tmp_path, capsys):
    line = fails(capsys, ["eval", "--policy", str(tmp_path / "none.pt"), "--quiet"], 1)
    assert "neither 'managed_surge' nor a file" in line


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["eval", "--episodes", "0"], "argument --episodes: must be an integer >= 1, got '0'"),
        (["eval", "--episodes", "-5"], "argument --episodes: must be an integer >= 1"),
        (["eval", "--episodes", "200000000"], "--episodes: must be an integer <= 1000000"),
        (["stress", "--episodes", "2000000"], "--episodes: must be an integer <= 1000000"),
        (["eval", "--threads", "0"], "argument --threads: must be an integer >= 1, got '0'"),
        (["eval", "--map-trials", "0"], "argument --map-trials: must be an integer >= 1"),
        (["eval", "--seed", "-1"], "argument --seed: must be an integer >= 0"),
        (["eval", "--speed-tolerance", "nan"], "argument --speed-tolerance: must be a finite"),
        (["eval", "--range-noise-scale", "-1"], "argument --range-noise-scale: must be >= 0"),
        (["eval", "--bearing-noise-scale", "inf"], "must be a finite number, got 'inf'"),
        (["eval", "--episodes", "ten"], "argument --episodes: expected an integer, got 'ten'"),
        (["eval", "--device", "gpu0"], "argument --device: not a torch device: 'gpu0'"),
        (["eval", "--scenario", "calm"], "argument --scenario: invalid choice: 'calm'"),
        (["export", "--policy", "p.pt", "--out", "p.pt2", "--batch", "0"], "--batch: must be"),
        (["filter-figure", "--current", "nan", "0"], "argument --current: must be a finite"),
        (["learn-filter", "--window", "1"], "argument --window: must be an integer >= 2"),
        (["learn-filter", "--lr", "0"], "argument --lr: must be > 0"),
        (["learn-filter", "--steps", "20", "--window", "50"], "--steps (20) must exceed"),
        (["learn-filter", "--seed", "1000"], "--seed 1000 draws the held-out rollouts"),
        (["filter-ablation", "--mismatch", "-2"], "argument --mismatch: must be > 0"),
        (["filter-ablation", "--whiteness", "0.5"], "--whiteness applies to learn-filter"),
        (["ppo-filter-comparison", "--total-steps", "0", "--filter-params", "f.pt"], "must be"),
        (["ppo-filter-comparison", "--filter-params", "."], "--filter-params: .: a folder, not"),
        (["eval", "--filter-params", "."], "argument --filter-params: .: a folder, not a file"),
        (["export", "--policy", "p.pt", "--out", "p.pt2", "--filter-params", "q.pt"], "no such"),
        (["filter-figure", "--start", "-500", "0", "0"], "more than 120 m from the DS"),
        (["filter-figure", "--current", "0", "-1.5"], "within +-1 m/s (the AUV's top speed)"),
        (["learn-filter", "--objective", "supervised", "--whiteness", "1"], "nll objective"),
        (["learn-filter", "--context-epochs", "3"], "unrecognized arguments: --context-epochs"),
        (["stress", "--policy", "managed_surge", "--levels", "L0,L9"], "unknown level 'L9'"),
        (["grid", "table6", "--max-concurrent", "0"], "argument --max-concurrent: must be"),
        (["grid", "table6", "--view-every", "0"], "argument --view-every: must be > 0"),
        (["grid", "table6", "--hours", "-1"], "argument --hours: must be >= 0"),
        (["train", "--algo", "ppo", "--scenario", "calm"], "PPOConfig.scenario: unknown"),
        (["train", "--algo", "ppo", "--threads", "0"], "PPOConfig.threads: must be >= 1"),
        (["train", "--recipe", "ppo", "--final-eval-episodes", "200000000"], "must be <= 1000000"),
        (["train", "--algo", "sac", "--num-envs", "5000000"], "SACConfig.num_envs: must be <="),
        (["train", "--algo", "sac", "--total-steps", "0"], "SACConfig.total_steps: must be"),
        (["train", "--algo", "sac", "--lr", "nan"], "SACConfig.lr: must be finite"),
        (["train", "--algo", "sac", "--total-steps", "5000"], "--start-steps 10000 >= --total"),
        (["train", "--recipe", "td3", "--total-steps", "100"], "never learn; give fewer"),
        (["train", "--recipe", "sac", "--epochs", "3"], "--epochs does not apply to sac"),
        (["train", "--recipe", "sac", "--preset", "fast"], "exclude each other"),
        (["train", "--total-steps", "256"], "--algo or --recipe is required"),
        (["eval", "--mirrored"], "--mirrored needs a saved agent"),
        (["eval", "--map-trials", "3"], "--map-trials applies to a --map only"),
        (["eval", "--stochastic"], "--stochastic samples a saved agent's actions"),
        (["learn-filter", "--lags", "2"], "--lags applies to a --whiteness penalty only"),
        (["learn-filter", "--whiteness", "1", "--window", "4"], "--lags (5) must be below"),
        (["filter-ablation", "--context-epochs", "3"], "applies to the --context-noise rows"),
        ([], "the following arguments are required: command"),
        (["evaluate"], "argument command: invalid choice: 'evaluate'"),
        (["eval", "--bogus", "3"], "unrecognized arguments: --bogus 3"),
    ],
)
def test_a_bad_command_line_is_one_usage_line(argv, says, capsys):
    line = fails(capsys, argv, 2)
    assert says in line
    known = argv[:1] != ["evaluate"]
    prog = f"dockingrl {argv[0]}" if argv and known else "dockingrl"
    assert line.endswith(f"(see {prog} --help)")  # the help of the command that refused it


def test_train_into_a_file_is_one_line_and_makes_nothing(capsys, tmp_path):
    (tmp_path / "f").write_text("")
    for out in ("f", "f/runs"):
        argv = ["train", "--algo", "sac", "--out", str(tmp_path / out), "--logger", "none"]
        assert f"not a folder ({tmp_path / 'f'} is a file)" in fails(capsys, argv, 1)
    assert [p.name for p in tmp_path.iterdir()] == ["f"]


def test_unknown_recipe_is_one_line(capsys, tmp_path):
    line = fails(capsys, ["train", "--recipe", "nope", "--out", str(tmp_path)], 1)
    assert "unknown recipe 'nope'" in line
    assert "unknown recipe 'nope'" in fails(capsys, ["recipes", "nope"], 1)


def test_a_compound_policy_in_the_noise_scenario_says_both_layouts(capsys, compound_policy):
    argv = ["eval", "--policy", str(compound_policy), "--episodes", "2", "--quiet"]
    line = fails(capsys, [*argv, "--scenario", "noise"], 1)
    assert str(compound_policy) in line
    assert "filtered_observation; 12 numbers" in line and "observation; 6 numbers" in line
    assert "'compound'" in line and "'noise'" in line
    # the layout it was trained on passes the check: eval goes on to refuse a video file of
    # an unknown kind (before it runs any episode)
    line = fails(capsys, [*argv, "--scenario", "compound", "--video", "clip.avi"], 2)
    assert "--video clip.avi: the suffix must be one of .gif, .mp4" in line
    line = fails(capsys, [*argv, "--scenario", "compound", "--video-episodes", "5"], 2)
    assert "--video-episodes applies to a --video only" in line


def test_a_policy_whose_actor_does_not_read_its_layout_is_refused(tmp_path, capsys):
    """A file that says its policy reads the current (14 numbers) with an actor reading 12:
    eval, the onboard policy and export all refuse it in one line instead of a tensor-size
    error inside the actor."""
    from dockingrl.onboard import OnboardPolicy

    path = tiny_policy(tmp_path / "odd.pt", obs_dim=12, observe_current=True)
    line = fails(capsys, ["eval", "--policy", str(path), "--episodes", "2", "--quiet"], 1)
    assert "12 numbers" in line and "14 numbers" in line and "ocean_current" in line
    with pytest.raises(ValueError, match="14 numbers"):
        OnboardPolicy.from_file(path)
    line = fails(capsys, ["export", "--policy", str(path), "--out", str(tmp_path / "p.pt2")], 1)
    assert "14 numbers" in line and not (tmp_path / "p.pt2").exists()


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_shows_the_traceback(where, tmp_path, capsys):
    argv = ["eval", "--policy", str(tmp_path), "--quiet"]
    argv = ["--debug", *argv] if where == "before" else [*argv, "--debug"]
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 1
    assert err.startswith("Traceback") and "in load_policy" in err
    assert err.splitlines()[-1].startswith(f"dockingrl: error: {tmp_path}")


def _raise(exc):
    def command(args):
        raise exc

    return command


def test_an_unexpected_error_is_one_line_that_points_to_debug(monkeypatch, capsys):
    monkeypatch.setattr("dockingrl.cli.filter.cmd_filter_figure", _raise(ZeroDivisionError("oops")))
    line = fails(capsys, ["filter-figure"], 1)
    assert line == (
        "dockingrl: error: ZeroDivisionError: oops (unexpected: run with --debug for the traceback)"
    )


def test_a_runtime_error_of_dockingrl_is_input_one_of_a_library_a_bug(monkeypatch, capsys):
    from dockingrl.transforms.repeat import ActionRepeat

    def dockingrl_check(args):
        ActionRepeat(2).forward(None)  # "... use it inside a TransformedEnv"

    monkeypatch.setattr("dockingrl.cli.filter.cmd_filter_figure", dockingrl_check)
    line = fails(capsys, ["filter-figure"], 1)
    assert "TransformedEnv" in line and "--debug" not in line

    def library_error(args):
        torch.zeros(2) @ torch.zeros(3)

    monkeypatch.setattr("dockingrl.cli.filter.cmd_filter_figure", library_error)
    line = fails(capsys, ["filter-figure"], 1)
    assert line.startswith("dockingrl: error: RuntimeError: ") and "--debug" in line


def test_ctrl_c_is_one_line_and_status_130(monkeypatch, capsys):
    monkeypatch.setattr("dockingrl.cli.filter.cmd_filter_figure", _raise(KeyboardInterrupt()))
    assert fails(capsys, ["filter-figure"], 130) == "dockingrl: error: interrupted"


def test_the_process_exits_non_zero_with_one_line_and_no_traceback(tmp_path):
    """The interpreter ends a failed ``python -m dockingrl`` with the status alone: no
    traceback, no second line (the in-process tests check the other statuses)."""
    bad = tmp_path / "random.pt"
    bad.write_bytes(bytes(range(256)) * 8)
    run = subprocess.run(
        [sys.executable, "-m", "dockingrl", "eval", "--policy", str(bad), "--quiet"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert run.returncode == 1, run.stderr
    assert run.stderr.count("\n") == 1 and run.stderr.startswith(f"dockingrl: error: {bad}")
    assert "Traceback" not in run.stderr and run.stdout == ""


def test_use_filter_is_for_the_managed_surge_controller_in_a_filtered_scenario(
    capsys, compound_policy
):
    line = fails(capsys, ["eval", "--episodes", "2", "--use-filter", "--quiet"], 2)
    assert "--use-filter needs a scenario that runs the EKF" in line and "'noise'" in line
    argv = ["stress", "--episodes", "2", "--levels", "L0", "--use-filter"]
    assert "runs the EKF" in fails(capsys, [*argv, "--scenario", "no_noise"], 2)
    argv = ["eval", "--policy", str(compound_policy), "--episodes", "2", "--use-filter"]
    assert "--use-filter is for --policy managed_surge" in fails(capsys, argv, 2)


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["stress", "--device", "banana"], "argument --device: not a torch device: 'banana'"),
        (["stress", "--seed", "-5"], "argument --seed: must be an integer >= 0"),
        (["stress", "--levels", "L0,L0"], "--levels L0,L0: a level is named twice"),
        (["stress", "--levels", ""], "--levels : unknown level ''"),
        (["eval", "--seed", str(2**70)], "argument --seed: must be an integer <= 4294967295"),
        (["train", "--algo", "sac", "--seed", str(2**70)], "SACConfig.seed: must be <= 4294967295"),
        (["export", "--policy", "managed_surge", "--out", "a.pt2"], "only a trained policy.pt"),
        (
            ["export", "--policy", "p.pt", "--out", "a.txt"],
            "--out a.txt: a program file ends in .pt2 or .onnx",
        ),
        (["export", "--policy", "p.pt", "--out", "."], "--out .: a folder; give the program"),
        (
            ["train", "--algo", "sac", "--device", "banana"],
            "SACConfig.device: expected cpu, cuda[:N] or mps",
        ),
        (["train", "--algo", "sac", "--seed", "-1"], "SACConfig.seed: must be >= 0 (got -1)"),
        (
            ["train", "--algo", "sac", "--run-name", "../up"],
            "SACConfig.run_name: must be a folder name",
        ),
        (["train", "--resume", "x", "--recipe", "sac"], "--recipe does not apply to --resume"),
        (["train", "--resume", "x", "--preset", "fast"], "--preset does not apply to --resume"),
    ],
)
def test_devices_seeds_run_names_and_levels_are_checked_up_front(argv, says, capsys):
    assert says in fails(capsys, argv, 2)


def test_an_output_folder_that_is_a_file_is_refused_before_any_work(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("")
    for argv in (["stress", "--episodes", "2"], ["table", str(tmp_path)], ["learn-filter"]):
        assert f"argument --out: {afile}: not a folder" in fails(
            capsys, [*argv, "--out", str(afile)], 2
        )
    line = fails(capsys, ["eval", "--out", str(afile / "sub"), "--quiet"], 2)
    assert f"({afile} is a file)" in line
    line = fails(capsys, ["eval", "--video", str(afile / "v.gif"), "--quiet"], 2)
    assert f"--video {afile / 'v.gif'}: cannot be written ({afile} is a file)" in line
    for argv in (
        ["record-log", "--policy", "p.pt"],
        ["replay", "--policy", "p.pt", "--log", str(afile)],
    ):
        line = fails(capsys, [*argv, "--out", str(tmp_path)], 2)
        assert f"argument --out: {tmp_path}: a folder; give a file's path" in line
        line = fails(capsys, [*argv, "--out", str(afile / "log.csv")], 2)
        assert f"argument --out: {afile / 'log.csv'}: cannot be written ({afile} is a file)" in line
        line = fails(capsys, [*argv, "--out", str(tmp_path / "log.txt")], 2)
        assert f"argument --out: {tmp_path / 'log.txt'}: a CSV file; its name must end" in line
        assert not (tmp_path / "log.txt").exists()
    said = fails(capsys, ["record-log", "--policy", "p.pt", "--out", "x.csv", "--seed", "-1"], 2)
    assert "argument --seed: must be an integer >= 0" in said
    said = fails(capsys, ["replay", "--policy", "p.pt", "--log", "nolog.csv", "--out", "x.csv"], 1)
    assert "sensor log nolog.csv: cannot read it" in said


def test_an_output_that_is_the_command_s_own_input_is_refused(tmp_path, capsys):
    # a policy file may have any name: one ending in .csv passes the --out suffix check
    log, policy = tmp_path / "log.csv", tmp_path / "p.csv"
    log.write_text("kept")
    policy.write_text("kept")
    for argv, flag, path in (
        (["replay", "--policy", str(policy), "--log", str(log), "--out", str(log)], "log", log),
        (
            ["replay", "--policy", str(policy), "--log", str(log), "--out", str(policy)],
            "policy",
            policy,
        ),
        (
            [
                "record-log",
                "--policy",
                str(policy),
                "--out",
                f"{tmp_path}/../{tmp_path.name}/p.csv",
            ],
            "policy",
            policy,
        ),
    ):
        assert f"is the --{flag} file; write to another" in fails(capsys, argv, 2)
        assert path.read_text() == "kept"


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("", "not a readable run config"),
        ("[1]", "not a run config (no algo of"),
        ('{"algo": "foo"}', "not a run config (no algo of"),
        ('{"algo": "ppo"}', "not a run config (no scenario, seed, total_steps)"),
        # an eval.json or a summary.json copied in its place
        ('{"algo": "ppo", "scenario": "compound", "seed": 10000}', "not a run config (no total"),
        (
            '{"algo": "sac", "scenario": "compound", "seed": 0, "total_steps": 1000, "lr": "abc"}',
            "sac option lr: expected <class 'float'>, got 'abc'",
        ),
    ],
)
def test_resuming_a_folder_with_a_broken_config_names_the_file(text, says, tmp_path, capsys):
    (tmp_path / "config.json").write_text(text)
    line = fails(capsys, ["train", "--resume", str(tmp_path)], 1)
    assert str(tmp_path / "config.json") in line and says in line and "unexpected" not in line


def test_a_run_that_cannot_start_leaves_no_folder_in_the_way_of_a_retry(tmp_path, capsys):
    junk = tmp_path / "junk.pt"
    junk.write_text("not a filter")
    argv = ["train", "--algo", "sac", "--scenario", "filtered", "--out", str(tmp_path)]
    line = fails(capsys, [*argv, "--run-name", "fp", "--filter-params", str(junk)], 1)
    assert "junk.pt" in line and "unexpected" not in line
    assert not (tmp_path / "fp").exists()
    (tmp_path / "kept").mkdir()  # a folder that was there before keeps what it held
    (tmp_path / "kept" / "notes.txt").write_text("mine")
    line = fails(capsys, [*argv, "--run-name", "kept", "--filter-params", str(junk)], 1)
    assert "junk.pt" in line and "unexpected" not in line
    assert sorted(p.name for p in (tmp_path / "kept").iterdir()) == ["notes.txt", "run.lock"]


def test_table_names_a_missing_folder_and_a_damaged_file(tmp_path, capsys):
    from helpers import fake_run

    line = fails(capsys, ["table", str(tmp_path / "typo"), "--out", str(tmp_path / "t")], 1)
    assert f"{tmp_path / 'typo'}: no such run folder" in line
    (tmp_path / "afile").write_text("")
    line = fails(capsys, ["table", str(tmp_path / "afile"), "--out", str(tmp_path / "t")], 1)
    assert f"{tmp_path / 'afile'}: a file, not a run folder" in line
    run = fake_run(tmp_path, "ppo", "ppo", "noise", 0, 50.0)
    (run / "config.json").write_text("[1]")
    line = fails(capsys, ["table", str(run), "--out", str(tmp_path / "t")], 1)
    assert f"{run / 'config.json'}: not a run's config (no algo, scenario, seed)" in line
    run = fake_run(tmp_path, "ppo", "ppo", "noise", 1, 50.0)
    with (run / "curves.csv").open("a") as f:
        f.write("garbage\n")
    line = fails(capsys, ["table", str(run), "--out", str(tmp_path / "t")], 1)
    assert f"{run / 'curves.csv'}, line" in line and "'garbage'" in line


def test_upgrade_names_a_damaged_old_file_and_goes_on_to_the_next(tmp_path, capsys):
    damaged, also = tmp_path / "a.pt", tmp_path / "b.pt"
    for path in (damaged, also):  # an old filter file whose noises hold no parameters
        old = {"format": "dockingrl.filter_params/1", "process_noise": {}, "measurement_noise": {}}
        torch.save(old, path)
    assert main(["upgrade", str(damaged), str(also)]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(": ")[2] for line in lines] == [str(damaged), str(also)]
    assert all("a damaged dockingrl.filter_params file, not converted" in x for x in lines)


def test_a_reader_that_stops_early_gets_no_error():
    """`dockingrl recipes sac | head -1`: the pipe's reader exits before the listing is
    written; the command stops quietly with SIGPIPE's status."""
    import subprocess
    import sys

    proc = subprocess.Popen(
        [sys.executable, "-m", "dockingrl", "recipes", "sac"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # before the interpreter has started: every write meets a closed pipe
    stderr = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141, stderr
    assert "rror" not in stderr, stderr


@pytest.mark.parametrize(
    ("layout", "says"),
    [
        ("finished", "a finished run (summary.json) with no checkpoint to resume from"),
        ("no_pointer", "holds checkpoint folders but no latest.json naming a complete one"),
        ("file", "a file, not the run's checkpoint folder"),
    ],
)
def test_resuming_a_run_with_nothing_to_go_on_from_leaves_it_as_it_was(
    layout, says, tmp_path, capsys
):
    """A run folder whose work a start from scratch would overwrite (a finished run without
    checkpoints, checkpoints without the pointer to a complete one) is refused before anything
    in it is written."""
    source = Path(__file__).parent / "data" / "sac_run"
    run = tmp_path / "run"
    run.mkdir()
    for name in ("config.json", "curves.csv", "summary.json"):
        shutil.copy(source / name, run / name)
    if layout == "no_pointer":
        (run / "summary.json").unlink()
        (run / "checkpoints" / "step_0000001000").mkdir(parents=True)
    elif layout == "file":
        (run / "checkpoints").write_text("")
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()}
    line = fails(capsys, ["train", "--resume", str(run), "--total-steps", "600000"], 1)
    assert says in line and "unexpected" not in line
    # the folder as it was, but for the lock the refusing process held (run.lock)
    after = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file() and p.name != "run.lock"}
    assert after == before
    assert sorted(p.name for p in run.iterdir() if p.name != "run.lock") == sorted(
        [*before, *(["checkpoints"] if layout == "no_pointer" else [])]
    )


def _finished_run(folder: Path) -> Path:
    """A folder that looks like a finished training run: config, summary, final evaluation."""
    folder.mkdir(parents=True)
    for name in ("config.json", "summary.json", "eval.json"):
        (folder / name).write_text("{}")
    return folder


def test_a_run_folder_is_refused_as_the_out_of_a_command_that_writes_an_eval(
    tmp_path, capsys, compound_policy
):
    run = _finished_run(tmp_path / "run")
    for argv in (
        ["eval", "--policy", str(compound_policy), "--episodes", "2", "--out", str(run)],
        ["learn-filter", "--steps", "10", "--out", str(run)],
    ):
        line = fails(capsys, argv, 2)
        assert "a training run's folder" in line and str(run) in line
    assert all((run / name).read_text() == "{}" for name in ("summary.json", "eval.json"))


def test_a_video_path_that_is_a_folder_is_refused_before_the_evaluation(tmp_path, capsys):
    folder = tmp_path / "clip.gif"
    folder.mkdir()
    argv = ["eval", "--policy", "managed_surge", "--episodes", "2", "--video", str(folder)]
    assert "a folder; give a file's path" in fails(capsys, argv, 2)


def test_training_into_a_finished_run_says_it_is_finished(tmp_path, capsys):
    _finished_run(tmp_path / "done")
    argv = ["train", "--algo", "ppo", "--out", str(tmp_path), "--run-name", "done"]
    line = fails(capsys, argv, 1)
    assert "already holds a finished run" in line and "--resume" not in line


def test_grid_table_options_are_checked_before_any_trial_runs(tmp_path, capsys):
    grid = tmp_path / "g.yaml"
    grid.write_text(
        f"out: {tmp_path / 'runs'}\nscenarios: [compound]\n"
        "groups:\n  - recipes: [ppo]\n    seeds: [0]\n"
    )
    base = ["grid", str(grid)]
    line = fails(capsys, [*base, "--held-out", "--prune-policies"], 2)
    assert "--held-out, --prune-policies apply to the table: give --table DIR" in line
    (tmp_path / "file").write_text("")
    assert "not a folder" in fails(capsys, [*base, "--table", str(tmp_path / "file")], 2)
    table = ["--table", str(tmp_path / "table")]
    assert "not held out" in fails(capsys, [*base, *table, "--held-out"], 1)
    baseline = tmp_path / "eval.json"
    baseline.write_text("{}")
    line = fails(capsys, [*base, *table, "--baseline", str(baseline)], 1)
    assert "not an evaluation's eval.json" in line
    assert not (tmp_path / "runs").exists()  # no trial ran


def test_whiteness_lags_default_and_given():
    from dockingrl.cli import build_parser
    from dockingrl.cli.filter import _fit_options
    from dockingrl.filter_learning import FilterFit

    parse = build_parser("learn-filter").parse_args
    given = parse(["learn-filter", "--whiteness", "1", "--lags", "2"])
    assert _fit_options(given, "nll").lags == 2
    default = parse(["learn-filter", "--whiteness", "1"])
    assert _fit_options(default, "nll").lags == FilterFit().lags
