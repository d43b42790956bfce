"""The onboard loop off the vehicle: the ONNX program of the onboard step against
OnboardPolicy, the sensor-log format, the recorder and the replay that gives the env's
commands back, and the example that runs the program with onnxruntime and numpy alone."""

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import tiny_actor

from dockingrl.cli import main
from dockingrl.env import DockingEnv
from dockingrl.env.levels import level_config
from dockingrl.onboard import OnboardPolicy, export_onnx
from dockingrl.onboard.export import ONNX_OPSET, onnx_names
from dockingrl.onboard.sensor_log import read_log, record_episode, replay, ticks, write_log

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")
REPO = Path(__file__).resolve().parents[1]
L5 = level_config("L5")


def robust_like(seed=0):
    """An untrained policy with the robust recipes' pipeline: the filtered estimate and the
    previous command observed, commands held 4 steps, the gated filter that compensates the
    USBL latency and estimates the current's error, at L5's sensors."""
    options = dict(observe_command=True, action_repeat=4, config=L5, compensate_latency=True)
    options.update(estimate_current=True, gate=13.816)
    return OnboardPolicy(tiny_actor(8, "sac", seed), "filtered", **options)


@pytest.fixture(scope="module")
def program(tmp_path_factory):
    path = tmp_path_factory.mktemp("onnx") / "step.onnx"
    return export_onnx(robust_like(), path)


def test_the_onnx_program_agrees_with_the_onboard_policy_over_l5_approaches(program):
    import onnx

    model = onnx.load(str(program))
    assert [o.version for o in model.opset_import if o.domain in ("", "ai.onnx")] == [ONNX_OPSET]
    inputs, outputs = onnx_names(robust_like())
    session = ort.InferenceSession(str(program), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == inputs
    assert [o.name for o in session.get_outputs()] == outputs
    steps, approaches = 0, 0
    for seed in range(3):
        policy = robust_like()
        log, commands = record_episode(policy, DockingEnv(1, config=L5, seed=seed), max_steps=200)
        # the ONNX program over the same readings, carrying its own state
        replayed = replay(robust_like(), log, L5.dt)
        state = [t.numpy() for t in robust_like().initial_state(1)]
        mean, cov, command, age, history = state
        z_log = list(ticks(log, L5.dt))
        for k, tick in enumerate(z_log):
            z, current = tick.z[None].numpy(), tick.current[None].numpy()
            ages = tick.ages[None].numpy()
            feed = dict(
                zip(inputs, (z, current, mean, cov, command, age, ages, history), strict=True)
            )
            command, mean, cov, age, history = session.run(None, feed)
            np.testing.assert_allclose(command[0], commands[k].numpy(), rtol=0, atol=1e-5)
            np.testing.assert_allclose(mean[0], replayed.means[k].numpy(), rtol=1e-5, atol=1e-5)
        steps += len(z_log)
        approaches += 1
    assert steps > 300 and approaches == 3


def test_a_replayed_log_gives_the_env_commands_back_exactly(tmp_path):
    log, commands = record_episode(robust_like(), DockingEnv(1, config=L5, seed=7))
    assert len(log.times["usbl"]) < len(log.times["dvl"]) < len(log.times["imu"])  # own rates
    path = write_log(log, tmp_path / "log.csv")
    result = replay(robust_like(), read_log(path), L5.dt)
    assert torch.equal(result.commands, commands)
    assert torch.equal(result.logged_commands, commands)
    assert result.means.shape == (len(commands), 7) and bool((result.stds > 0).all())


def test_the_replay_and_record_commands(tmp_path, capsys):
    policy_file = REPO / "tests/data/ppo_policy/policy.pt"
    log, out = tmp_path / "log.csv", tmp_path / "commands.csv"
    assert (
        main(
            [
                "record-log",
                "--policy",
                str(policy_file),
                "--level",
                "L1",
                "--seed",
                "2",
                "--out",
                str(log),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "replay",
                "--policy",
                str(policy_file),
                "--level",
                "L1",
                "--log",
                str(log),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert "largest difference 0" in capsys.readouterr().out
    header = out.read_text().splitlines()[0].split(",")
    assert header[:4] == ["t", "v_d", "w_d", "x"] and "std_x" in header and "logged_v_d" in header


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("t,sensor,a,b\n0,usbl,1,2\n", "not a dockingrl sensor log"),
        ("# dockingrl sensor log v1\nt,sensor,a\n", "line 2 must be the columns"),
        ("# dockingrl sensor log v1\nt,sensor,a,b\n0,gps,1,2\n", "line 3: unknown sensor 'gps'"),
        ("# dockingrl sensor log v1\nt,sensor,a,b\n0,usbl,nan,2\n", "line 3: .* must be finite"),
        ("# dockingrl sensor log v1\nt,sensor,a,b\n0,usbl,x,2\n", "line 3: .* must be numbers"),
        ("# dockingrl sensor log v1\nt,sensor,a,b\n0,usbl,-1,2\n", "line 3: a usbl range .* >= 0"),
        (
            "# dockingrl sensor log v1\nt,sensor,a,b\n1,usbl,1,2\n0,dvl,1,2\n",
            "line 4: t 0.0 is before",
        ),
        ("# dockingrl sensor log v1\nt,sensor,a,b\n0,usbl,1\n", "line 3: 4 fields expected"),
        ("# dockingrl sensor log v1\nt,sensor,a,b\n", "no messages"),
        (
            "# dockingrl sensor log v1\nt,sensor,a,b\n0,usbl,1,2\n1e9,usbl,1,2\n",
            "line 4: .* a silence over 60 s",
        ),
        (  # a log in milliseconds: every gap under 60, its span far over an hour
            "# dockingrl sensor log v1\nt,sensor,a,b\n"
            + "".join(f"{50 * k},imu,1,2\n" for k in range(80)),
            "line 76: .* at most 3600 s",
        ),
    ],
)
def test_a_bad_log_is_refused_in_one_line(tmp_path, text, message):
    path = tmp_path / "log.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        read_log(path)


def test_a_non_finite_command_names_the_tick_that_gave_it(tmp_path, monkeypatch):
    rows = "".join(f"{t},{s},1e30,0.1\n" for t in (0, 0.2) for s in ("usbl", "dvl", "imu"))
    path = tmp_path / "log.csv"
    path.write_text(f"# dockingrl sensor log v1\nt,sensor,a,b\n0,current,0,0\n{rows}")
    policy = robust_like()
    broken = lambda *state: (torch.full((1, 2), math.nan), *state[2:])  # noqa: E731
    monkeypatch.setattr(policy.step, "forward", broken)
    with pytest.raises(
        RuntimeError,
        match=r"at t 0 s, readings \(1e\+30, 0\.1, .*\), current \(0, 0\): .* non-finite command",
    ):
        replay(policy, read_log(path))


def test_a_log_without_a_sensor_cannot_start_the_loop(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text("# dockingrl sensor log v1\nt,sensor,a,b\n0,usbl,20,0.1\n0,current,0,0\n")
    with pytest.raises(ValueError, match="no dvl, imu messages"):
        replay(robust_like(), read_log(path))


def test_the_example_runs_the_program_with_onnxruntime_and_numpy_alone(program, tmp_path):
    log, commands = record_episode(robust_like(), DockingEnv(1, config=L5, seed=3), max_steps=80)
    path = write_log(log, tmp_path / "log.csv")
    script = f"""
import runpy, sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('torch', 'torchrl', 'tensordict', 'dockingrl'):
            raise ImportError(name)
sys.meta_path.insert(0, Block())
sys.argv = ['onnx_control_loop.py', {str(program)!r}, {str(path)!r}]
runpy.run_path({str(REPO / "examples/onnx_control_loop.py")!r}, run_name='__main__')
"""
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    lines = run.stdout.strip().splitlines()
    assert lines[0] == "t,v_d,w_d" and len(lines) == len(commands) + 1
    got = np.array([[float(x) for x in line.split(",")[1:]] for line in lines[1:]])
    np.testing.assert_allclose(got, commands.numpy(), rtol=0, atol=1e-5)


def test_the_export_command_writes_onnx(tmp_path, capsys):
    policy_file = str(REPO / "tests/data/ppo_policy/policy.pt")
    out = tmp_path / "policy.onnx"
    assert main(["export", "--policy", policy_file, "--out", str(out)]) == 0
    assert "ONNX opset 18" in capsys.readouterr().out
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()][:2] == ["z", "current"]
    for bad in (
        ["--format", "onnx", "--out", str(tmp_path / "p.pt2")],
        ["--out", str(tmp_path / "p.txt")],
    ):
        with pytest.raises(SystemExit, match="ends in"):
            main(["export", "--policy", policy_file, *bad])


def test_the_export_silences_the_exporters_own_warnings_only_while_it_runs():
    import logging
    import warnings

    from dockingrl.onboard.export import _quiet_exporter

    registration = logging.getLogger("torch.onnx._internal.exporter._registration")
    ir = logging.getLogger("onnx_ir._convenience")
    before = [registration.getEffectiveLevel(), ir.getEffectiveLevel()]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with _quiet_exporter():
            assert not registration.isEnabledFor(logging.WARNING)
            assert not ir.isEnabledFor(logging.WARNING) and ir.isEnabledFor(logging.ERROR)
            warnings.warn("deprecated inside torch", FutureWarning, stacklevel=1)
        assert not caught
        warnings.warn("after the export", FutureWarning, stacklevel=1)
        assert len(caught) == 1
    assert [registration.getEffectiveLevel(), ir.getEffectiveLevel()] == before
    assert before[0] <= logging.WARNING
