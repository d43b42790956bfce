"""Files dockingrl reads back (policies, learned filters, checkpoints): a format version and a
content hash checked on load, weights-only loading (no code runs), checkpoint pointers confined
to their folder, one-line errors naming the file, ``dockingrl upgrade`` for older formats."""

import argparse
import builtins
import hashlib
import io
import json
import os
import shutil
import stat

import pytest
import torch
from tensordict import TensorDict

from dockingrl.agents.config import make_config
from dockingrl.agents.layout import check_layout
from dockingrl.agents.saving import load_policy, read_policy, save_policy
from dockingrl.cli.upgrade import add_upgrade_command
from dockingrl.env import DockingConfig
from dockingrl.io import ArtifactError, atomic_write, read_artifact, save_artifact
from dockingrl.scenarios import make_env
from dockingrl.training import Trainer
from dockingrl.training.checkpointing import latest_checkpoint, read_state
from dockingrl.transforms import EKFTransform
from dockingrl.transforms.params import read_filter_params

TINY_PPO = {"num_envs": 2, "steps_per_env": 8, "minibatch_size": 8, "hidden": (8, 8)}
TINY_SAC = {
    "num_envs": 2,
    "frames_per_batch": 8,
    "batch_size": 4,
    "start_steps": 8,
    "hidden": (8, 8),
}


def config(algo="ppo", scenario="compound", tmp_path=".", **extra):
    tiny = TINY_PPO if algo == "ppo" else TINY_SAC
    return make_config(
        algo,
        "paper",
        scenario=scenario,
        out=str(tmp_path),
        run_name="run",
        logger="none",
        threads=1,
        **{**tiny, **extra},
    )


def saved_policy(path, scenario="compound", **extra):
    """A freshly initialised actor of ``scenario`` saved at ``path``; returns the env too."""
    from dockingrl.agents import build_actor

    cfg = config("ppo", scenario, **extra)
    env = make_env(scenario, 1, seed=0)
    obs_dim = env.observation_spec["observation"].shape[-1]
    torch.manual_seed(1)
    actor = build_actor(cfg, obs_dim, env.action_spec[0], 60.0)
    save_policy(path, actor, cfg, obs_dim, env.action_spec[0], 60.0, note="test")
    return actor, env


def run(*argv):
    parser = argparse.ArgumentParser()
    add_upgrade_command(parser.add_subparsers())
    args = parser.parse_args(["upgrade", *map(str, argv)])
    return args.func(args)


def sealed(data: bytes) -> bytes:
    """A PyTorch file's bytes with the content hash dockingrl writes (a ZIP comment)."""
    comment = b"dockingrl-sha256:"
    data = bytearray(data)
    data[-2:] = (len(comment) + 64).to_bytes(2, "little")
    return bytes(data) + comment + hashlib.sha256(data).hexdigest().encode()


class Marker:
    """Unpickled, it creates the file ``path``."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return builtins.open, (self.path, "w")


def crafted(path, marker, fmt, hashed):
    buffer = io.BytesIO()
    torch.save({"format": fmt, "agent": Marker(marker), "state_dict": Marker(marker)}, buffer)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(sealed(buffer.getvalue()) if hashed else buffer.getvalue())


def flipped(path, offsets, tmp_path):
    """Copies of ``path``, each with the byte at one of ``offsets`` changed."""
    data = path.read_bytes()
    for i, offset in enumerate(offsets):
        bad = bytearray(data)
        bad[offset] ^= 0x01 if i % 2 else 0xFF
        copy = tmp_path / f"flip_{offset}_{path.name}"
        copy.write_bytes(bytes(bad))
        yield offset, copy


def spread(size, n=10):
    return sorted({0, size - 1, *(size * k // n for k in range(1, n))})


# -- writing ---------------------------------------------------------------------------------


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_atomic_write_gives_files_the_umask_mode(tmp_path, umask):
    old = os.umask(umask)
    try:
        path = atomic_write(tmp_path / "a.json", lambda tmp: tmp.write_text("{}"))
        plain = tmp_path / "plain"
        plain.write_text("")
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)


def test_atomic_write_under_a_file_names_the_file_in_the_way(tmp_path):
    (tmp_path / "afile").write_text("kept")
    target = tmp_path / "afile" / "out" / "eval.json"
    with pytest.raises(NotADirectoryError) as info:
        atomic_write(target, lambda tmp: tmp.write_text("{}"))
    assert str(info.value) == f"{target}: cannot be written ({tmp_path / 'afile'} is a file)"
    assert (tmp_path / "afile").read_text() == "kept"


def test_payloads_that_would_not_load_weights_only_are_not_written(tmp_path):
    with pytest.raises(TypeError, match="weights-only"):
        save_artifact(tmp_path / "x.pt", {"format": "f", "obj": Marker(tmp_path / "m")})
    assert not (tmp_path / "x.pt").exists() and not (tmp_path / "m").exists()


# -- policies --------------------------------------------------------------------------------


def test_policies_round_trip_exactly_with_their_layout(tmp_path):
    actor, env = saved_policy(tmp_path / "p.pt", observe_command=False)
    loaded, info = load_policy(tmp_path / "p.pt")
    saved = actor.state_dict()
    assert set(loaded.state_dict()) == set(saved)
    for k, v in loaded.state_dict().items():
        assert torch.equal(v, saved[k]), k
    assert info["metadata"] == {"note": "test"} and info["algo"] == "ppo"
    assert info["observation_layout"] == {
        "scenario": "compound",
        "keys": ["observation", "filtered_observation"],
        "obs_dim": 12,
        "action_repeat": 1,
    }
    assert info["path"] == str(tmp_path / "p.pt")


def test_layout_check_names_what_differs(tmp_path):
    _, env = saved_policy(tmp_path / "p.pt")
    _, info = load_policy(tmp_path / "p.pt")
    check_layout(info, "compound", 12)
    check_layout(info, "compound", 12, action_repeat=1)
    with pytest.raises(ArtifactError) as err:
        check_layout(info, "noise", 6)
    message = str(err.value)
    assert "\n" not in message and str(tmp_path / "p.pt") in message
    assert "scenario 'compound' (observation: observation, filtered_observation; 12 numbers)" in (
        message
    )
    assert "env gives scenario 'noise' (observation: observation; 6 numbers)" in message
    with pytest.raises(ArtifactError, match="previous_action; 14 numbers"):
        check_layout(info, "compound", 14, observe_command=True)
    with pytest.raises(ArtifactError, match="12 numbers; action_repeat 4"):
        check_layout(info, "compound", 12, action_repeat=4)
    # same entries, another scenario: a cross evaluation, accepted
    saved_policy(tmp_path / "n.pt", scenario="noise")
    check_layout(load_policy(tmp_path / "n.pt")[1], "no_noise", 6)


def test_evaluate_refuses_a_ready_env_of_another_size_and_the_load_policy_pair(tmp_path):
    from dockingrl.evaluation import evaluate

    saved_policy(tmp_path / "p.pt")
    actor, info = load_policy(tmp_path / "p.pt")
    with pytest.raises(ArtifactError) as err:
        evaluate(actor, make_env("noise", 2, seed=0))
    message = str(err.value)
    assert "\n" not in message and str(tmp_path / "p.pt") in message
    assert "reads 12 observation numbers (observation, filtered_observation)" in message
    assert "this env gives 6" in message and "env_options" in message
    with pytest.raises(TypeError, match="load_policy returns the pair"):
        evaluate((actor, info), "compound", 2)
    for episodes in (0, 2_000_000):
        with pytest.raises(ValueError, match=r"num_episodes must lie in \[1, 1000000\]"):
            evaluate(actor, "compound", episodes)
    # the env it was trained on is accepted
    assert evaluate(actor, make_env("compound", 2, seed=0))["episodes"] == 2


@pytest.mark.parametrize("hashed", [False, True])
def test_a_crafted_policy_file_runs_no_code(tmp_path, hashed):
    path, marker = tmp_path / "policy.pt", tmp_path / "marker"
    crafted(path, marker, "dockingrl.policy/2", hashed)
    with pytest.raises(ArtifactError, match="could run code") as err:
        load_policy(path)
    assert str(path) in str(err.value)
    assert not marker.exists()
    assert run(path) == 1
    assert not marker.exists()
    # the file is really malicious: loaded as pickle, it writes the marker
    torch.load(io.BytesIO(path.read_bytes()), weights_only=False)
    assert marker.exists()


def test_every_flipped_byte_of_a_policy_file_is_detected(tmp_path):
    saved_policy(tmp_path / "p.pt")
    size = (tmp_path / "p.pt").stat().st_size
    offsets = spread(size) + list(range(size - 90, size, 9))
    for offset, copy in flipped(tmp_path / "p.pt", offsets, tmp_path):
        with pytest.raises(ArtifactError) as err:
            load_policy(copy)
        assert str(copy) in str(err.value), offset


def policy_payload(tmp_path):
    saved_policy(tmp_path / "good.pt")
    return read_policy(tmp_path / "good.pt")


def narrow_filter(folder):
    """The payload of a learned filter whose ``R`` has two entries, not six."""
    learned_filter(folder / "f.pt")
    payload = read_filter_params(folder / "f.pt")
    return {**payload, "measurement_noise": {"log_std": torch.zeros(2)}}


BAD_POLICIES = {
    "directory": (lambda p, payload: p.mkdir(), "is a directory"),
    "empty": (lambda p, payload: p.write_bytes(b""), "is empty"),
    "truncated": (
        lambda p, payload: p.write_bytes((p.parent / "good.pt").read_bytes()[:3000]),
        "damaged or truncated",
    ),
    "random bytes": (lambda p, payload: p.write_bytes(os.urandom(4000)), "not a PyTorch file"),
    "text": (lambda p, payload: p.write_text("policy = 'ppo'\n"), "a text file"),
    "missing": (lambda p, payload: None, "no such file"),
    "missing keys": (
        lambda p, payload: save_artifact(
            p, {k: v for k, v in payload.items() if k != "state_dict"}
        ),
        "without state_dict",
    ),
    "unknown algorithm": (
        lambda p, payload: save_artifact(p, {**payload, "algo": "dqn"}),
        "unknown algorithm 'dqn'",
    ),
    "extra config fields": (
        lambda p, payload: save_artifact(
            p, {**payload, "config": {**payload["config"], "warp_drive": 1}}
        ),
        "config fields unknown to dockingrl's ppo: warp_drive",
    ),
    "weights of another shape": (
        lambda p, payload: save_artifact(
            p,
            {
                **payload,
                "obs_dim": 7,
                "observation_layout": {**payload["observation_layout"], "obs_dim": 7},
            },
        ),
        "does not rebuild a ppo actor (Error(s) in loading state_dict for ProbabilisticActor: "
        "size mismatch",
    ),
    "integer weights": (
        lambda p, payload: save_artifact(
            p,
            {
                **payload,
                "state_dict": {
                    k: v.long() if i == 0 else v
                    for i, (k, v) in enumerate(payload["state_dict"].items())
                },
            },
        ),
        "weights that are not floating point: ",
    ),
    # hand-edited payloads re-saved whole: refused as training would refuse them
    "config field of the wrong type": (
        lambda p, payload: save_artifact(
            p, {**payload, "config": {**payload["config"], "filter_gate": "abc"}}
        ),
        "its config: ppo option filter_gate: expected <class 'float'>, got 'abc'",
    ),
    "config field out of its range": (
        lambda p, payload: save_artifact(
            p, {**payload, "config": {**payload["config"], "action_repeat": 0}}
        ),
        "its config: PPOConfig.action_repeat",
    ),
    "config of another algorithm": (
        lambda p, payload: save_artifact(
            p, {**payload, "config": {**payload["config"], "algo": "sac"}}
        ),
        "its config: algo 'sac' is not the file's 'ppo'",
    ),
    "obs_dim not a count": (
        lambda p, payload: save_artifact(p, {**payload, "obs_dim": 7.5}),
        "obs_dim must be a whole number > 0 (got 7.5)",
    ),
    "metadata not a dict": (
        lambda p, payload: save_artifact(p, {**payload, "metadata": [1]}),
        "metadata must be a dict (got [1])",
    ),
    "layout another config's": (
        lambda p, payload: save_artifact(
            p,
            {
                **payload,
                "observation_layout": {**payload["observation_layout"], "keys": [1, 2]},
            },
        ),
        "observation_layout keys is [1, 2], not the ['observation', 'filtered_observation'] its "
        "config gives",
    ),
    "carried filter not a dict": (
        lambda p, payload: save_artifact(p, {**payload, "filter_params": "f.pt"}),
        "filter_params must be a dict or None (got 'f.pt')",
    ),
    "carried filter of another shape": (
        lambda p, payload: save_artifact(p, {**payload, "filter_params": narrow_filter(p.parent)}),
        "the filter it carries: do not fit the EKF (Error(s) in loading state_dict for "
        "MeasurementNoise: size mismatch for log_std",
    ),
    "another kind of file": (
        lambda p, payload: save_artifact(p, {**payload, "format": "dockingrl.checkpoint/2"}),
        "not a dockingrl policy file: its format is 'dockingrl.checkpoint/2'",
    ),
    "old format": (
        lambda p, payload: torch.save({**payload, "format": "dockingrl.policy/1"}, p),
        "older format dockingrl.policy/1; convert it once with: dockingrl upgrade",
    ),
    "no hash": (lambda p, payload: torch.save(payload, p), "no content hash"),
    # whole files of dockingrl's whose numbers cannot act
    "NaN weights": (
        lambda p, payload: save_artifact(
            p,
            {
                **payload,
                "state_dict": {
                    k: torch.full_like(v, float("nan")) if i == 0 else v
                    for i, (k, v) in enumerate(payload["state_dict"].items())
                },
            },
        ),
        "non-finite numbers in state_dict.",
    ),
    "NaN action bound": (
        lambda p, payload: save_artifact(p, {**payload, "action_low": [float("nan"), -0.1]}),
        "action_low and action_high must be two numbers each, low < high",
    ),
    "empty action range": (
        lambda p, payload: save_artifact(p, {**payload, "action_high": payload["action_low"]}),
        "low < high",
    ),
    "zero max_dist": (
        lambda p, payload: save_artifact(p, {**payload, "max_dist": 0.0}),
        "max_dist must be a finite number > 0 (got 0.0)",
    ),
    "no layout": (
        lambda p, payload: save_artifact(p, {**payload, "observation_layout": None}),
        "observation_layout must be a dict (got None)",
    ),
}


@pytest.mark.parametrize("kind", list(BAD_POLICIES))
def test_each_bad_policy_file_is_one_line_naming_it(tmp_path, kind):
    make, expected = BAD_POLICIES[kind]
    payload = policy_payload(tmp_path)
    path = tmp_path / "bad.pt"
    make(path, payload)
    with pytest.raises(ArtifactError) as err:
        load_policy(path)
    message = str(err.value)
    assert message.startswith(str(path)) and "\n" not in message
    assert expected in message


def test_upgrade_converts_an_old_policy_that_then_acts_the_same(tmp_path, capsys):
    actor, env = saved_policy(tmp_path / "new.pt")
    payload = read_policy(tmp_path / "new.pt")
    del payload["observation_layout"]
    payload["format"] = "dockingrl.policy/1"
    torch.save(payload, tmp_path / "old.pt")
    with pytest.raises(ArtifactError, match="dockingrl upgrade"):
        load_policy(tmp_path / "old.pt")
    assert run(tmp_path / "old.pt") == 0
    assert "dockingrl.policy/1 -> dockingrl.policy/2" in capsys.readouterr().out
    loaded, info = load_policy(tmp_path / "old.pt")
    assert info["observation_layout"] == load_policy(tmp_path / "new.pt")[1]["observation_layout"]
    td = env.reset()
    assert torch.equal(loaded(td.clone())["action"], actor.eval()(td.clone())["action"])
    assert run(tmp_path / "old.pt") == 0
    assert "already dockingrl.policy/2" in capsys.readouterr().out
    (tmp_path / "text.pt").write_text("hello")
    assert run(tmp_path / "text.pt") == 1
    assert "text.pt: not a dockingrl file (a text file)" in capsys.readouterr().err


# -- learned filter parameters ----------------------------------------------------------------


def learned_filter(path):
    ekf = EKFTransform(learnable=True)
    with torch.no_grad():
        ekf.process_noise.log_diag.add_(0.3)
        ekf.process_noise.off_diag.fill_(0.01)
    ekf.save_filter_params(path)
    return ekf


def test_every_flipped_byte_of_a_filter_file_is_detected(tmp_path):
    learned_filter(tmp_path / "f.pt")
    size = (tmp_path / "f.pt").stat().st_size
    for offset, copy in flipped(tmp_path / "f.pt", spread(size), tmp_path):
        with pytest.raises(ArtifactError) as err:
            EKFTransform().load_filter_params(copy)
        assert str(copy) in str(err.value), offset


@pytest.mark.parametrize("fmt", ["dockingrl.filter_params/4", "dockingrl.filter_params/1"])
def test_old_filter_files_are_refused_then_upgraded_to_the_same_q(tmp_path, fmt):
    log_diag = torch.tensor([-4.0, -4.5, -3.0, -4.4, -5.3])
    off = torch.linspace(-0.02, 0.03, 10)
    rows, cols = torch.tril_indices(5, 5, -1)
    if fmt.endswith("/1"):  # v1: L = diag(sigma) + C_abs
        L = torch.diag(log_diag.exp()).index_put((rows, cols), off)
    else:  # L = diag(sigma) (I + C)
        L = torch.diag(log_diag.exp()) @ torch.eye(5).index_put((rows, cols), off)
    payload = {
        "format": fmt,
        "process_noise": {"log_diag": log_diag, "off_diag": off},
        "measurement_noise": {"log_std": EKFTransform().measurement_noise.log_std.detach()},
    }
    path = tmp_path / "old.pt"
    torch.save(payload, path)
    with pytest.raises(ArtifactError, match=f"{fmt}; convert it once with: dockingrl upgrade"):
        read_filter_params(path)
    assert run(tmp_path) == 0  # a folder: its .pt files
    ekf = EKFTransform().load_filter_params(path)
    torch.testing.assert_close(ekf.process_noise(), L @ L.T + 1e-10 * torch.eye(5))
    assert ekf.range_noise_from == "measurement" and ekf.noise_context is None


def test_upgrade_leaves_an_old_filter_that_does_not_fit_the_ekf_as_it_was(tmp_path, capsys):
    # older formats do not say which filter they were for: what fits is checked before writing
    old = {
        "format": "dockingrl.filter_params/4",
        "process_noise": {"log_diag": torch.zeros(3), "off_diag": torch.zeros(3)},
        "measurement_noise": {"log_std": torch.zeros(6)},
    }
    torch.save(old, tmp_path / "old.pt")
    before = (tmp_path / "old.pt").read_bytes()
    assert run(tmp_path / "old.pt") == 1
    err = capsys.readouterr().err
    assert "old.pt: not converted, its parameters: do not fit the EKF" in err
    assert "size mismatch for log_diag" in err
    assert (tmp_path / "old.pt").read_bytes() == before
    # the same filter carried by an old policy file
    saved_policy(tmp_path / "p.pt")
    policy = {**read_policy(tmp_path / "p.pt"), "format": "dockingrl.policy/1"}
    del policy["observation_layout"]
    torch.save({**policy, "filter_params": old}, tmp_path / "p.pt")
    before = (tmp_path / "p.pt").read_bytes()
    assert run(tmp_path / "p.pt") == 1
    assert "p.pt: the filter it carries: do not fit the EKF" in capsys.readouterr().err
    assert (tmp_path / "p.pt").read_bytes() == before


def test_upgrade_converts_the_old_filter_a_current_policy_carries(tmp_path, capsys):
    saved_policy(tmp_path / "p.pt")
    ekf = EKFTransform()
    old = {
        "format": "dockingrl.filter_params/4",
        "process_noise": ekf.process_noise.state_dict(),
        "measurement_noise": ekf.measurement_noise.state_dict(),
    }
    save_artifact(tmp_path / "p.pt", {**read_policy(tmp_path / "p.pt"), "filter_params": old})
    with pytest.raises(ArtifactError, match="the filter it carries: of the older format"):
        load_policy(tmp_path / "p.pt")
    assert run(tmp_path / "p.pt") == 0
    out = capsys.readouterr().out
    assert "dockingrl.policy/2 carrying dockingrl.filter_params/4 -> dockingrl.policy/2" in out
    _, info = load_policy(tmp_path / "p.pt")
    assert info["filter_params"]["format"] == "dockingrl.filter_params/5"
    assert run(tmp_path / "p.pt") == 0
    assert "already dockingrl.policy/2" in capsys.readouterr().out


def test_a_filter_file_round_trips(tmp_path):
    ekf = learned_filter(tmp_path / "f.pt")
    fresh = EKFTransform().load_filter_params(tmp_path / "f.pt")
    assert torch.equal(fresh.process_noise(), ekf.process_noise())
    for bad, expected in [("x", "a text file"), (b"", "is empty")]:
        path = tmp_path / "bad.pt"
        path.write_bytes(bad.encode() if isinstance(bad, str) else bad)
        with pytest.raises(ArtifactError, match=expected):
            EKFTransform().load_filter_params(path)
    # a whole file whose R holds a NaN would turn every filtered observation into NaN
    payload = read_filter_params(tmp_path / "f.pt")
    first = next(iter(payload["measurement_noise"]))
    noise = {**payload["measurement_noise"], first: torch.tensor(float("nan"))}
    save_artifact(tmp_path / "nan.pt", {**payload, "measurement_noise": noise})
    with pytest.raises(ArtifactError, match=f"non-finite numbers in measurement_noise.{first}"):
        EKFTransform().load_filter_params(tmp_path / "nan.pt")


# -- checkpoints -----------------------------------------------------------------------------


def trainer(tmp_path, algo="sac"):
    return Trainer(config(algo, "noise", tmp_path), tmp_path / "run", progress=False)


def checkpointed(tmp_path):
    """A SAC trainer at 16 frames with 10 transitions in its buffer, checkpointed."""
    t = trainer(tmp_path)
    t.agent.replay_buffer.extend(TensorDict({"observation": torch.randn(10, 6)}, [10]))
    t.progress.frames, t.progress.episodes = 16, 3
    path = t.checkpoints.save()
    return t, path


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="names an fd through /proc")
def test_a_checkpoint_is_on_disk_before_latest_json_names_it(tmp_path, monkeypatch):
    """After a power cut the checkpoint that ``latest.json`` names must hold its bytes: every
    file of it is flushed before ``latest.json`` is replaced (and the older ones dropped)."""
    t = trainer(tmp_path)
    t.agent.replay_buffer.extend(TensorDict({"observation": torch.randn(10, 6)}, [10]))
    events = []
    fsync, replace = os.fsync, os.replace

    def record_fsync(fd):
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        return fsync(fd)

    def record_replace(src, dst):
        events.append(("replace", str(dst)))
        return replace(src, dst)

    monkeypatch.setattr(os, "fsync", record_fsync)
    monkeypatch.setattr(os, "replace", record_replace)
    path = t.checkpoints.save()
    latest = events.index(("replace", str(path.parent / "latest.json")))
    synced = {name.replace(".tmp/", "/") for kind, name in events[:latest] if kind == "fsync"}
    files = {str(p) for p in path.rglob("*") if p.is_file()}
    assert files and files <= synced
    assert ("fsync", str(path.parent)) in events[latest:]  # the rename into latest.json


def test_a_checkpoint_round_trips_with_its_replay_buffer(tmp_path):
    t, path = checkpointed(tmp_path)
    assert not (path / "replay" / "prefetch.pkl").exists()
    assert all(name.endswith((".json", ".memmap")) for name in read_state(path)["replay"])
    fresh = trainer(tmp_path)
    assert fresh.load_checkpoint()
    assert (fresh.progress.frames, fresh.progress.episodes) == (16, 3)
    assert len(fresh.agent.replay_buffer) == 10
    stored = fresh.agent.replay_buffer.storage[:10]["observation"]
    assert torch.equal(stored, t.agent.replay_buffer.storage[:10]["observation"])
    state = torch.load(path / "state.pt", weights_only=True)
    assert state["format"] == "dockingrl.checkpoint/2"


@pytest.mark.parametrize("hashed", [False, True])
def test_a_crafted_checkpoint_runs_no_code(tmp_path, hashed):
    root, marker = tmp_path / "run" / "checkpoints", tmp_path / "marker"
    crafted(root / "step_0000000100" / "state.pt", marker, "dockingrl.checkpoint/2", hashed)
    (root / "latest.json").write_text(json.dumps({"path": "step_0000000100", "frames": 100}))
    with pytest.raises(ArtifactError, match="could run code") as err:
        trainer(tmp_path).load_checkpoint()
    assert str(root / "step_0000000100" / "state.pt") in str(err.value)
    assert not marker.exists()


def test_replay_files_that_could_run_code_are_refused(tmp_path):
    _, path = checkpointed(tmp_path)
    (path / "replay" / "prefetch.pkl").write_bytes(b"\x80\x04N.")
    with pytest.raises(ArtifactError, match="unlisted prefetch.pkl"):
        read_state(path)
    (path / "replay" / "prefetch.pkl").unlink()
    state = read_state(path)
    state["replay"]["prefetch.pkl"] = hashlib.sha256(b"\x80\x04N.").hexdigest()
    save_artifact(path / "state.pt", state)
    with pytest.raises(ArtifactError, match="lists 'prefetch.pkl'"):
        read_state(path)


def test_every_flipped_byte_of_a_checkpoint_is_detected(tmp_path):
    _, path = checkpointed(tmp_path)
    good = (path / "state.pt").read_bytes()
    for offset, copy in flipped(path / "state.pt", spread(len(good)), tmp_path):
        (path / "state.pt").write_bytes(copy.read_bytes())
        with pytest.raises(ArtifactError) as err:
            trainer(tmp_path).load_checkpoint()
        assert str(path / "state.pt") in str(err.value), offset
    (path / "state.pt").write_bytes(good)
    replay = sorted(p for p in (path / "replay").rglob("*") if p.is_file())
    memmap = next(p for p in replay if p.name == "observation.memmap")
    for target in (memmap, next(p for p in replay if p.name == "metadata.json")):
        original = target.read_bytes()
        for offset in spread(len(original), 4):
            bad = bytearray(original)
            bad[offset] ^= 0x01
            target.write_bytes(bytes(bad))
            with pytest.raises(ArtifactError, match="content hash mismatch") as err:
                read_state(path)
            assert str(path / "replay") in str(err.value)
        target.write_bytes(original)
    read_state(path)


def agent_state(state, part, key, value):
    """``state`` with the entry ``key`` of its agent's ``part`` set to ``value``."""
    agent = state["agent"]
    return {**state, "agent": {**agent, part: {**agent[part], key: value}}}


def test_bad_checkpoint_states_are_one_line_naming_them(tmp_path):
    _, path = checkpointed(tmp_path)
    state_file = path / "state.pt"
    good = state_file.read_bytes()
    state = read_artifact(state_file, "x", "dockingrl.checkpoint/2")
    loss = state["agent"]["loss"]
    first_weight = next(k for k, v in loss.items() if k.endswith("weight"))
    cases = {
        "truncated": (lambda: state_file.write_bytes(good[: len(good) // 2]), "truncated"),
        "random": (lambda: state_file.write_bytes(os.urandom(len(good))), "not a PyTorch"),
        "text": (lambda: state_file.write_text("{}"), "a text file"),
        "empty": (lambda: state_file.write_bytes(b""), "is empty"),
        "missing keys": (
            lambda: save_artifact(state_file, {k: v for k, v in state.items() if k != "agent"}),
            "without agent",
        ),
        "old format": (
            lambda: torch.save({**state, "format": "dockingrl.checkpoint/1"}, state_file),
            "older format dockingrl.checkpoint/1; convert it once with: dockingrl upgrade",
        ),
        "another agent": (
            lambda: save_artifact(state_file, {**state, "agent": {"loss": {}}}),
            "does not fit this run",
        ),
        # re-saved whole by hand: refused before the training loop would trip on them
        "frames not a count": (
            lambda: save_artifact(state_file, {**state, "frames": "abc"}),
            "frames must be an integer >= 0 (got 'abc')",
        ),
        "elapsed not finite": (
            lambda: save_artifact(state_file, {**state, "elapsed": float("nan")}),
            "elapsed must be a finite number >= 0 (got nan)",
        ),
        "RNG state not bytes": (
            lambda: save_artifact(state_file, {**state, "torch_rng": [1, 2]}),
            "torch_rng must be a uint8 tensor",
        ),
        "kept actor without weights": (
            lambda: save_artifact(state_file, {**state, "candidates": [{"success": 90.0}]}),
            "candidates must be a list of kept actors",
        ),
        # torch would broadcast a number into the weight, or skip a None
        "a weight replaced by a number": (
            lambda: save_artifact(state_file, agent_state(state, "loss", first_weight, 1.5)),
            f"does not fit this run (loss.{first_weight} must be a tensor of shape",
        ),
        "a NaN weight": (
            lambda: save_artifact(
                state_file,
                agent_state(state, "loss", first_weight, loss[first_weight] * float("nan")),
            ),
            f"non-finite numbers in agent.loss.{first_weight}",
        ),
        "updates not a count": (
            lambda: save_artifact(
                state_file, {**state, "agent": {**state["agent"], "updates": "x"}}
            ),
            "does not fit this run (updates must be an integer >= 0 (got 'x'))",
        ),
        "an optimiser state not a dict": (
            lambda: save_artifact(state_file, agent_state(state, "optimizers", "actor", None)),
            "does not fit this run (optimizers.actor must be an optimiser's state dict)",
        ),
    }
    for kind, (make, expected) in cases.items():
        make()
        with pytest.raises(ArtifactError) as err:
            trainer(tmp_path).load_checkpoint()
        message = str(err.value)
        assert str(state_file) in message and "\n" not in message, kind
        assert expected in message, kind


def test_an_old_checkpoint_is_upgraded_and_resumes(tmp_path):
    _, path = checkpointed(tmp_path)
    state = read_state(path)
    del state["replay"]
    torch.save({**state, "format": "dockingrl.checkpoint/1"}, path / "state.pt")
    (path / "replay" / "prefetch.pkl").write_bytes(b"\x80\x04N.")  # what version 1 runs have
    with pytest.raises(ArtifactError, match="dockingrl upgrade"):
        trainer(tmp_path).load_checkpoint()
    assert run(tmp_path / "run") == 0
    fresh = trainer(tmp_path)
    assert fresh.load_checkpoint() and fresh.frames == 16
    assert len(fresh.agent.replay_buffer) == 10


def test_latest_json_cannot_point_out_of_the_checkpoints_folder(tmp_path):
    _, path = checkpointed(tmp_path)
    root = path.parent
    outside = tmp_path / "elsewhere" / "step_1"
    shutil.copytree(path, outside)
    (root / "link").symlink_to(outside)
    latest = root / "latest.json"
    cases = {
        "../../elsewhere/step_1": "leads out of",
        str(outside): "leads out of",
        "link": "leads out of",
        "step_9": "is not a checkpoint folder",
        ".": "leads out of",
    }
    for name, expected in cases.items():
        latest.write_text(json.dumps({"path": name, "frames": 16}))
        with pytest.raises(ArtifactError) as err:
            trainer(tmp_path).load_checkpoint()
        assert str(err.value).startswith(str(latest)) and expected in str(err.value), name
    for text, expected in [
        ("{not json", "not JSON"),
        ("[1, 2]", 'no "path"'),
        ('{"frames": 3}', 'no "path"'),
        ('{"path": 7}', 'no "path"'),
    ]:
        latest.write_text(text)
        with pytest.raises(ArtifactError) as err:
            latest_checkpoint(root)
        assert str(err.value).startswith(str(latest)) and expected in str(err.value), text
    latest.write_text(json.dumps({"path": path.name, "frames": 16}))
    assert latest_checkpoint(root) == path.resolve()
    assert trainer(tmp_path).load_checkpoint()


def test_a_policy_carries_its_learned_filter_whole(tmp_path):
    learned_filter(tmp_path / "f.pt")
    payload = read_filter_params(tmp_path / "f.pt")
    from dockingrl.agents import build_actor

    cfg = config("ppo", "filtered")
    env = make_env("filtered", 1, seed=0, config=DockingConfig(), filter_params=payload)
    actor = build_actor(cfg, 6, env.action_spec[0], 60.0)
    save_policy(tmp_path / "p.pt", actor, cfg, 6, env.action_spec[0], 60.0, filter_params=payload)
    carried = load_policy(tmp_path / "p.pt")[1]["filter_params"]
    assert carried["format"] == "dockingrl.filter_params/5"
    ekf = EKFTransform().load_filter_params(carried)
    torch.testing.assert_close(ekf.process_noise(), env.transform[0].process_noise())
