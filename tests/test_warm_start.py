"""``init_from`` / ``init_replay``: a run that starts from another run's trained agent (a
fine-tune on another level of the stress ladder), and what it refuses."""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from helpers import tiny_config

from dockingrl import training
from dockingrl.io import ArtifactError
from dockingrl.training.checkpointing import latest_checkpoint, read_state
from dockingrl.training.trainer import Trainer


def _params(state: dict) -> dict:
    return {k: v.clone() for k, v in state["loss"].items() if torch.is_tensor(v)}


def test_sac_starts_from_the_other_runs_networks_and_replay(tiny_runs, tmp_path, short_episodes):
    _, _, source = tiny_runs("sac", "compound")
    saved = read_state(latest_checkpoint(source / "checkpoints"))
    cfg = tiny_config(
        "sac", "compound", tmp_path, init_from=str(source), init_replay=True, train_level="L5"
    )
    trainer = Trainer(cfg, tmp_path / "fine", progress=False)
    fresh = _params(trainer.agent.state_dict())
    started = trainer.warm_start()
    assert started == {"run": str(source), "frames": saved["frames"]}
    loaded = _params(trainer.agent.state_dict())
    differs = [k for k in loaded if not torch.equal(loaded[k], fresh[k])]
    assert differs, "the warm start left the fresh networks as they were"
    for k, v in _params(saved["agent"]).items():
        assert torch.equal(loaded[k], v), k
    assert len(trainer.agent.replay_buffer) == saved["frames"]
    assert (trainer.frames, trainer.agent.updates, trainer.candidates) == (0, 0, [])


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_a_warm_start_keeps_its_own_settings(algo, tiny_runs, tmp_path, short_episodes):
    """The networks and the optimisers' moments come from the source run; the learning rate,
    the discount and SAC's fixed temperature from this run's config (a torch module's or
    optimiser's ``load_state_dict`` alone would restore the source's)."""
    source_cfg, _, source = tiny_runs(algo, "compound")
    saved = read_state(latest_checkpoint(source / "checkpoints"))["agent"]
    lr, gamma = source_cfg.lr / 3, 0.9
    own = {"lr": lr, "gamma": gamma, **({"alpha": 0.1} if algo == "sac" else {})}
    trainer = Trainer(
        tiny_config(algo, "compound", tmp_path, init_from=str(source), **own),
        tmp_path / "fine",
        progress=False,
    )
    trainer.warm_start()
    loss = trainer.agent.loss
    for k, v in _params(saved).items():
        if "network_params" in k:
            assert torch.equal(loss.state_dict()[k], v), k
    assert float(loss._value_estimator.gamma) == pytest.approx(gamma)
    assert float(saved["loss"]["_value_estimator.gamma"]) != pytest.approx(gamma)
    if algo == "sac":
        assert float(loss.log_alpha.exp()) == pytest.approx(0.1)
        assert float(saved["loss"]["log_alpha"].exp()) != pytest.approx(0.1)
    for name, optimizer in trainer.agent.optimizers.items():
        assert [g["lr"] for g in optimizer.param_groups] == [lr] * len(optimizer.param_groups)
        assert [g["lr"] for g in saved["optimizers"][name]["param_groups"]] != [lr]
        moments = optimizer.state_dict()["state"]
        assert moments.keys() == saved["optimizers"][name]["state"].keys() and moments, name
        for i, entry in moments.items():
            expected = saved["optimizers"][name]["state"][i]["exp_avg"]
            assert torch.equal(entry["exp_avg"], expected), (name, i)


def test_without_init_replay_the_buffer_starts_empty(tiny_runs, tmp_path, short_episodes):
    _, _, source = tiny_runs("sac", "compound")
    cfg = tiny_config("sac", "compound", tmp_path, init_from=str(source))
    trainer = Trainer(cfg, tmp_path / "fine", progress=False)
    trainer.warm_start()
    assert len(trainer.agent.replay_buffer) == 0


def test_a_fine_tune_samples_its_own_batch_size_from_the_sources_buffer(
    tiny_runs, tmp_path, short_episodes
):
    """A loaded replay buffer comes back with the batch size it was saved with; a fine-tune
    that asks another one samples batches of its own. The capacity stays the source's."""
    _, _, source = tiny_runs("sac", "compound")
    saved = json.loads((source / "config.json").read_text())
    own = 2 * saved["batch_size"] + 3
    cfg = tiny_config(
        "sac", "compound", tmp_path, init_from=str(source), init_replay=True, batch_size=own
    )
    trainer = Trainer(cfg, tmp_path / "fine", progress=False)
    trainer.warm_start()
    seen = []
    update = trainer.agent._update
    trainer.agent._update = lambda batch: seen.append(batch.shape[0]) or update(batch)
    trainer.agent._off_policy_update()
    assert seen == [own]
    # the buffer itself is the source's: another capacity is refused before anything loads
    size = 2 * saved["buffer_size"]
    cfg = tiny_config(
        "sac", "compound", tmp_path, init_from=str(source), init_replay=True, buffer_size=size
    )
    with pytest.raises(ValueError, match=f"same buffer_size \\(got {size}\\)"):
        Trainer(cfg, tmp_path / "bigger", progress=False).warm_start()


def test_a_fine_tune_trains_and_resumes_from_its_own_checkpoint(
    tiny_runs, tmp_path, short_episodes
):
    _, _, source = tiny_runs("sac", "compound")
    cfg = tiny_config(
        "sac", "compound", tmp_path, init_from=str(source), init_replay=True, start_steps=0
    )
    first = training.train(cfg, progress=False)["summary"]
    run = tmp_path / "sac_compound"
    assert json.loads((run / "config.json").read_text())["init_from"] == str(source)
    assert first["frames"] >= cfg.total_steps and first["updates"] > 0
    again = training.train(
        None, resume=run, progress=False, overrides={"total_steps": cfg.total_steps + 200}
    )["summary"]
    # resumed from its own checkpoint: the update count goes on (a second warm start would
    # have reset it to zero)
    assert again["updates"] > first["updates"]
    assert again["frames"] >= cfg.total_steps + 200


def test_ppo_starts_from_a_ppo_run(tiny_runs, tmp_path, short_episodes):
    _, _, source = tiny_runs("ppo", "noise")
    saved = read_state(latest_checkpoint(source / "checkpoints"))
    cfg = tiny_config("ppo", "noise", tmp_path, init_from=str(source))
    trainer = Trainer(cfg, tmp_path / "fine", progress=False)
    trainer.warm_start()
    for k, v in _params(saved["agent"]).items():
        assert torch.equal(_params(trainer.agent.state_dict())[k], v), k


def test_refusals(tiny_runs, tmp_path, short_episodes):
    _, _, sac_run = tiny_runs("sac", "compound")
    _, _, ppo_run = tiny_runs("ppo", "noise")
    with pytest.raises(ValueError, match="init_replay takes .* give --init-from RUN_DIR"):
        training.train(tiny_config("sac", "compound", tmp_path, init_replay=True), progress=False)
    cases = [
        (
            tiny_config("sac", "compound", tmp_path, init_from=str(ppo_run)),
            ValueError,
            "a ppo run, not sac",
        ),
        (
            tiny_config("sac", "compound", tmp_path, init_from=str(tmp_path)),
            ArtifactError,
            "no run folder",
        ),
        (
            tiny_config("sac", "noise", tmp_path, init_from=str(sac_run)),
            ValueError,
            "scenario: compound there, noise here, observations of 12 and 6 numbers",
        ),
        (
            tiny_config("ppo", "noise", tmp_path, init_from=str(ppo_run), init_replay=True),
            ValueError,
            "no replay buffer",
        ),
    ]
    for cfg, error, message in cases:
        trainer = Trainer(cfg, tmp_path / "fine", progress=False)
        with pytest.raises(error, match=message):
            trainer.warm_start()
    unfinished = tmp_path / "unfinished"
    shutil.copytree(sac_run, unfinished)
    (unfinished / "summary.json").unlink()
    trainer = Trainer(
        tiny_config("sac", "compound", tmp_path, init_from=str(unfinished)),
        tmp_path / "u",
        progress=False,
    )
    with pytest.raises(ValueError, match="has not finished .*dockingrl train --resume"):
        trainer.warm_start()
    empty = tmp_path / "no_checkpoint"
    empty.mkdir()
    shutil.copy(sac_run / "config.json", empty / "config.json")
    (empty / "summary.json").write_text("{}")
    trainer = Trainer(
        tiny_config("sac", "compound", tmp_path, init_from=str(empty)),
        tmp_path / "f",
        progress=False,
    )
    with pytest.raises(ArtifactError, match="holds no checkpoint"):
        trainer.warm_start()
    hidden = json.loads((sac_run / "config.json").read_text())["hidden"]
    for options, says in [
        ({"hidden": (48, 48)}, rf"hidden: \[{hidden[0]}, {hidden[1]}\] there, \[48, 48\] here"),
        ({"critic_layer_norm": True}, "critic_layer_norm: False there, True here"),
        ({"critic_dropout": 0.01}, "critic_dropout: 0.0 there, 0.01 here"),
    ]:
        other = tiny_config("sac", "compound", tmp_path, init_from=str(sac_run), **options)
        with pytest.raises(ValueError, match=f"its networks are not this run's \\({says}\\)"):
            Trainer(other, tmp_path / "w", progress=False).warm_start()
    # a config.json older than a network field trained with the field's default
    for name, options, says in [
        ("critic_dropout", {"critic_dropout": 0.01}, "critic_dropout: 0.0 there, 0.01 here"),
        ("critic_layer_norm", {"critic_layer_norm": True}, "critic_layer_norm: False there"),
    ]:
        older = tmp_path / f"older_{name}"
        shutil.copytree(sac_run, older)
        config = json.loads((older / "config.json").read_text())
        del config[name]
        (older / "config.json").write_text(json.dumps(config))
        dropped = tiny_config("sac", "compound", tmp_path, init_from=str(older), **options)
        with pytest.raises(ValueError, match=f"\\({says}"):
            Trainer(dropped, tmp_path / "w", progress=False).warm_start()
    # a checkpoint whose networks are not those its config.json says
    mislabelled = tmp_path / "mislabelled"
    shutil.copytree(sac_run, mislabelled)
    config = json.loads((mislabelled / "config.json").read_text())
    (mislabelled / "config.json").write_text(json.dumps({**config, "hidden": [48, 48]}))
    wider = tiny_config("sac", "compound", tmp_path, init_from=str(mislabelled), hidden=(48, 48))
    with pytest.raises(ArtifactError, match="does not fit this run"):
        Trainer(wider, tmp_path / "w", progress=False).warm_start()


def test_an_averaging_run_starts_its_average_at_the_loaded_actor(
    tiny_runs, tmp_path, short_episodes
):
    _, _, source = tiny_runs("sac", "compound")
    cfg = tiny_config("sac", "compound", tmp_path, init_from=str(source), actor_average=0.99)
    trainer = Trainer(cfg, tmp_path / "avg", progress=False)
    fresh = {k: v.clone() for k, v in trainer.agent.average.module.state_dict().items()}
    trainer.warm_start()
    live, averaged = trainer.agent.actor.state_dict(), trainer.agent.average.module.state_dict()
    assert live.keys() == averaged.keys() == fresh.keys()
    for key in live:
        assert torch.equal(live[key], averaged[key]), key
    assert any(not torch.equal(averaged[k], fresh[k]) for k in fresh), "the average was not moved"
