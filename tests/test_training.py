"""Smoke runs of every algorithm on every scenario, checkpoint/resume, saved policies, CLI."""

import json
from pathlib import Path

import pytest
import torch
from helpers import COMMON, SMOKE_EPISODE_STEPS, TINY, tiny_config

from dockingrl.agents.config import PPOConfig, SACConfig, TD3Config, make_config
from dockingrl.agents.saving import load_policy
from dockingrl.cli import main as cli_main
from dockingrl.env import DockingConfig, DockingEnv
from dockingrl.evaluation import evaluate
from dockingrl.io import save_artifact
from dockingrl.training import Trainer, read_curves, train
from dockingrl.training.checkpointing import Checkpoints


@pytest.mark.parametrize("scenario", ["no_noise", "noise", "filtered", "compound"])
@pytest.mark.parametrize("algo", ["sac", "td3", "ppo"])
def test_every_algorithm_trains_on_every_scenario(algo, scenario, tiny_runs):
    cfg, result, run = tiny_runs(algo, scenario)
    s = result["summary"]
    assert s["frames"] >= TINY[algo]["total_steps"] and s["updates"] > 0
    assert result["eval"]["episodes"] == 6
    for name in (
        "config.json",
        "curves.csv",
        "eval.json",
        "summary.json",
        "policy.pt",
        "learning_curve.png",
    ):
        assert (run / name).stat().st_size > 0, name
    curves = read_curves(run)
    assert any(k.startswith("losses/") for k in curves)
    assert "eval/success_rate" in curves and "time/steps_per_s" in curves
    policy, info = load_policy(run / "policy.pt")
    assert info["algo"] == algo and info["scenario"] == scenario
    # the final evaluation is the saved policy's, on the final episodes' seed and in the
    # run's world: the same outcomes to the last bit
    assert result["eval"]["time_all_s"]["mean"] <= SMOKE_EPISODE_STEPS * 0.2
    world = DockingConfig(max_steps=SMOKE_EPISODE_STEPS)
    again = evaluate(policy, scenario, 6, seed=cfg.seed + 10_000, config=world)
    for key in ("success_rate", "total_reward", "time_all_s", "failures"):
        assert again[key] == result["eval"][key], key


@pytest.mark.parametrize("algo", ["sac", "td3", "ppo"])
def test_interrupted_run_resumes_to_the_same_total(algo, tmp_path, monkeypatch, short_episodes):
    total = 2 * TINY[algo]["total_steps"]
    cfg = tiny_config(algo, "compound", tmp_path, total_steps=total, threads=2)
    original = Checkpoints.save
    calls = {"n": 0}

    def save_then_crash(self):
        path = original(self)
        calls["n"] += 1
        if calls["n"] == 1:
            # a crash some time after the checkpoint: a later step was already logged
            (self.run_dir / "curves.csv").open("a").write(
                f"{self.progress.frames + 100},time/updates,1\n"
            )
            raise KeyboardInterrupt("simulated crash after the first checkpoint")
        return path

    monkeypatch.setattr(Checkpoints, "save", save_then_crash)
    with pytest.raises(KeyboardInterrupt):
        train(cfg, progress=False)
    run = tmp_path / f"{algo}_compound"
    latest = json.loads((run / "checkpoints" / "latest.json").read_text())
    assert 0 < latest["frames"] < cfg.total_steps
    assert not (run / "policy.pt").exists()
    state = torch.load(run / "checkpoints" / latest["path"] / "state.pt", weights_only=False)
    assert torch.get_num_threads() == 2
    overrides = {"algo": algo, "threads": 1}  # the same algorithm; another thread count
    result = train(None, resume=run, progress=False, overrides=overrides)
    assert torch.get_num_threads() == 1
    assert result["summary"]["frames"] >= cfg.total_steps
    assert result["summary"]["updates"] > state["agent"]["updates"]
    steps = [s for s, _ in read_curves(run)["time/updates"]]
    assert steps == sorted(steps) and len(set(steps)) == len(steps), "no step logged twice"


def test_sigterm_checkpoints_the_last_batch_then_the_run_resumes(
    tmp_path, monkeypatch, short_episodes
):
    """SIGTERM (a batch scheduler's pre-emption or time limit) stops the loop after the current
    batch with a checkpoint of it, even between two checkpoint intervals; the signal handlers
    are put back, and ``--resume`` completes the run."""
    import os
    import signal

    from dockingrl.agents import OffPolicyAgent
    from dockingrl.training import TrainingInterrupted

    cfg = tiny_config("sac", "compound", tmp_path, checkpoint_every=0)
    original, batches = OffPolicyAgent.learn_batch, []

    def train_then_signal(agent, data, frames, batch_frames):
        batches.append(data.numel())
        if len(batches) == 2:
            os.kill(os.getpid(), signal.SIGTERM)
        return original(agent, data, frames, batch_frames)

    monkeypatch.setattr(OffPolicyAgent, "learn_batch", train_then_signal)
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(TrainingInterrupted, match="SIGTERM at 200 env steps") as stopped:
        train(cfg, progress=False)
    assert stopped.value.frames == sum(batches) == 200 < cfg.total_steps
    assert signal.getsignal(signal.SIGTERM) is before
    run = tmp_path / "sac_compound"
    assert json.loads((run / "checkpoints" / "latest.json").read_text())["frames"] == 200
    assert not (run / "policy.pt").exists()
    monkeypatch.setattr(OffPolicyAgent, "learn_batch", original)
    result = train(None, resume=run, progress=False)
    assert result["summary"]["frames"] == cfg.total_steps
    assert (run / "policy.pt").exists()
    # the command line reports it and exits with 128 + the signal's number

    def interrupted(*args, **kwargs):
        raise TrainingInterrupted(signal.SIGTERM, 200, run)

    monkeypatch.setattr("dockingrl.training.train", interrupted)
    assert cli_main(["train", "--algo", "sac"]) == 128 + signal.SIGTERM


def test_a_finished_run_continues_to_a_larger_total(tmp_path, short_episodes):
    """``--resume RUN --total-steps N`` continues a finished run from its last checkpoint: the
    replay buffer and counters carry on, config.json records the new total, and with
    ``keep_best`` the final policy is the best periodic actor of the whole run (or the best
    on validation episodes of the kept ones, ``keep_candidates`` given at the resume)."""
    cfg = tiny_config("sac", "compound", tmp_path, keep_best=True)
    first = train(cfg, progress=False)
    run = tmp_path / "sac_compound"
    assert first["summary"]["frames"] == cfg.total_steps
    longer = 2 * cfg.total_steps
    result = train(None, resume=run, progress=False, overrides={"total_steps": longer})
    assert result["summary"]["frames"] == longer
    assert result["summary"]["updates"] > first["summary"]["updates"]
    assert json.loads((run / "config.json").read_text())["total_steps"] == longer
    evals = read_curves(run)["eval/success_rate"]
    assert [s for s, _ in evals] == list(range(200, longer + 1, 200)), "no evaluation twice"
    best = max(evals, key=lambda e: e[1])
    assert result["summary"]["policy_periodic_success_rate"] == best[1]
    trainer = Trainer(cfg, run, progress=False)
    assert trainer.load_checkpoint() and len(trainer.agent.replay_buffer) == longer
    # the end-of-run choice may change too: the checkpoint's best actor and those to come
    more = {"total_steps": 3 * cfg.total_steps, "keep_candidates": 3, "select_episodes": 4}
    result = train(None, resume=run, progress=False, overrides=more)
    saved = json.loads((run / "config.json").read_text())
    assert {k: saved[k] for k in more} == more
    assert 1 < len(result["summary"]["selection"]) <= 3
    assert max(c["frames"] for c in result["summary"]["selection"]) > longer
    # resumed once more, finished, only to choose again: one final evaluation in the curves
    train(None, resume=run, progress=False, overrides={"select_episodes": 5})
    finals = read_curves(run)["eval/final_success_rate"]
    assert [s for s, _ in finals] == [
        cfg.total_steps,
        longer,
        3 * cfg.total_steps,
    ]  # a total below the checkpoint, and a new total for an annealed learning rate, are refused
    with pytest.raises(ValueError, match="below the checkpoint"):
        train(None, resume=run, progress=False, overrides={"total_steps": cfg.total_steps})
    ppo = tiny_config("ppo", "noise", tmp_path, lr_schedule="linear")
    train(ppo, progress=False)
    with pytest.raises(ValueError, match="lr_schedule 'linear'"):
        train(
            None,
            resume=tmp_path / "ppo_noise",
            progress=False,
            overrides={"total_steps": 2 * ppo.total_steps},
        )


def test_checkpoint_round_trip_restores_networks_and_buffer(tiny_runs):
    cfg, _, run = tiny_runs("sac", "noise")
    trainer = Trainer(cfg, run, progress=False)
    assert trainer.load_checkpoint()
    saved = torch.load(run / "policy.pt", weights_only=True)["state_dict"]
    # the last checkpoint (frames 400) is the final state: the saved policy equals it
    for key, value in trainer.agent.actor.state_dict().items():
        torch.testing.assert_close(value, saved[key])
    assert len(trainer.agent.replay_buffer) == trainer.frames


def test_paper_presets_match_tables_3_to_5():
    sac, td3, ppo = SACConfig(), TD3Config(), PPOConfig()
    assert (
        sac.alpha,
        sac.batch_size,
        sac.gamma,
        sac.lr,
        sac.buffer_size,
        sac.start_steps,
        sac.tau,
        sac.updates_per_step,
        sac.hidden,
    ) == (0.2, 256, 0.99, 3e-4, 1_000_000, 10_000, 0.005, 1.0, (256, 256))
    assert sac.target_entropy == -2.0 and not sac.learn_alpha
    assert (
        td3.lr,
        td3.start_steps,
        td3.batch_size,
        td3.policy_delay,
        td3.target_policy_noise,
        td3.target_noise_clip,
        td3.exploration_sigma,
        td3.hidden,
    ) == (5e-4, 100, 256, 2, 0.2, 0.5, 0.2, (400, 300))
    assert (
        ppo.lr,
        ppo.steps_per_env,
        ppo.minibatch_size,
        ppo.gae_lambda,
        ppo.clip,
        ppo.entropy_coef,
        ppo.value_coef,
        ppo.max_grad_norm,
        ppo.epochs,
        ppo.hidden,
    ) == (3e-4, 2048, 64, 0.95, 0.2, 0.0, 0.5, 0.5, 10, (256, 256))


def test_impossible_configs_are_refused():
    with pytest.raises(ValueError, match="scenario"):
        make_config("sac", scenario="calm")
    with pytest.raises(ValueError, match="minibatch_size"):
        make_config("ppo", num_envs=1, steps_per_env=16, minibatch_size=64)
    with pytest.raises(ValueError, match="unknown sac option"):
        make_config("sac", steps_per_env=3)
    with pytest.raises(ValueError, match="unknown algorithm"):
        make_config("ddpg")
    with pytest.raises(ValueError, match="total_steps"):
        make_config("td3", total_steps=0)


@pytest.mark.parametrize(
    ("algo", "field", "value"),
    [
        ("sac", "tau", 0.0),
        ("sac", "gamma", 1.5),
        ("td3", "lr", -1e-3),
        ("sac", "start_steps", -5),
        ("td3", "exploration_sigma", -0.1),
        ("ppo", "gae_lambda", 1.2),
        ("ppo", "clip", 0.0),
        ("ppo", "entropy_coef", -0.01),
        ("sac", "frames_per_batch", 8),  # fewer than the 16 envs
        ("sac", "n_steps", 0),
        ("sac", "updates_per_step", 0.0),
        ("td3", "policy_delay", 0),
        ("ppo", "epochs", 0),
        ("sac", "checkpoint_every", -1),
        ("sac", "following_current_fraction", 1.5),
        ("td3", "lateral_current_fraction", -0.5),
        ("ppo", "near_start_fraction", 2.0),
        ("ppo", "train_fossen_fraction", 1.5),
        ("sac", "contact_speed_penalty", float("nan")),  # "must be finite"
    ],
)
def test_out_of_range_hyperparameters_are_refused(algo, field, value):
    with pytest.raises(ValueError, match=f"{field}: must"):
        make_config(algo, num_envs=16, **{field: value})


def test_curricula_reach_the_training_env_only():
    from dockingrl.training import TRAINING_DRAWS, env_kwargs, training_draws

    plain = make_config("sac")
    base = env_kwargs(plain)["config"]
    assert training_draws(plain, base) == base == DockingConfig()  # all off: Sec. 4.1
    values = dict(zip(TRAINING_DRAWS, (0.5, 0.25, 0.1), strict=True))
    cfg = make_config("sac", **values)
    train_config = training_draws(cfg, env_kwargs(cfg)["config"])
    assert {name: getattr(train_config, name) for name in TRAINING_DRAWS} == values
    assert env_kwargs(cfg)["config"] == DockingConfig()  # what evaluations build on


def test_the_fossen_share_reaches_mixed_training_envs_only():
    from dockingrl.training import env_kwargs, training_draws

    cfg = make_config("ppo", train_level="M0", train_fossen_fraction=0.75)
    evaluation = env_kwargs(cfg)["config"]
    assert evaluation.vehicle == "mixed" and evaluation.fossen_fraction == 0.5
    assert training_draws(cfg, evaluation).fossen_fraction == 0.75
    # a level of one vehicle keeps its config: the share means nothing there
    single = make_config("ppo", train_fossen_fraction=0.75)
    assert training_draws(single, env_kwargs(single)["config"]) == DockingConfig()
    # the share is what the training env flies: all Fossen at 1.0
    everyone = make_config("ppo", train_level="M0", train_fossen_fraction=1.0)
    env = DockingEnv(64, config=training_draws(everyone, evaluation), seed=0)
    env.reset()
    assert env.on_fossen.all()


def test_cli_train_then_eval_the_saved_policy(tmp_path, capsys, short_episodes):
    args = [
        "train",
        "--algo",
        "ppo",
        "--scenario",
        "filtered",
        "--total-steps",
        "256",
        "--num-envs",
        "8",
        "--steps-per-env",
        "32",
        "--minibatch-size",
        "64",
        "--epochs",
        "1",
        "--hidden",
        "16",
        "16",
        "--eval-every",
        "256",
        "--eval-episodes",
        "2",
        "--final-eval-episodes",
        "4",
        "--logger",
        "none",
        "--out",
        str(tmp_path),
        "--run-name",
        "cli",
        "--no-progress",
        "--threads",
        "1",
        "--observe-current",
    ]
    assert cli_main(args) == 0
    assert "final 4-episode success" in capsys.readouterr().out
    out = tmp_path / "eval"
    assert (
        cli_main(
            [
                "eval",
                "--policy",
                str(tmp_path / "cli" / "policy.pt"),
                "--episodes",
                "5",
                "--out",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    metrics = json.loads((out / "eval.json").read_text())
    assert metrics["scenario"] == "filtered" and metrics["episodes"] == 5
    # the saved policy reads 6 + 2 numbers: eval rebuilt the env with the current appended
    _, info = load_policy(tmp_path / "cli" / "policy.pt")
    assert info["config"]["observe_current"] is True
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        cli_main(["train", "--algo", "ppo", "--start-steps", "5"])  # a SAC/TD3 option
    assert exit_.value.code == 2
    assert "--start-steps does not apply to ppo" in capsys.readouterr().err
    # a resumed run keeps its config: only where and how fast it runs (and how long) may change
    run = str(tmp_path / "cli")
    for extra, message in (
        (["--seed", "3"], "not seed"),
        (["--algo", "sac"], "not algo"),
        (["--lr", "1e-3", "--threads", "1"], "not lr"),
    ):
        with pytest.raises(SystemExit, match=message):
            cli_main(["train", "--resume", run, *extra])
    with pytest.raises(SystemExit, match="no run"):
        cli_main(["train", "--resume", str(tmp_path / "nothing")])
    with pytest.raises(SystemExit, match="--algo or --recipe is required"):
        cli_main(["train", "--total-steps", "256"])


def test_wandb_offline_logging(tmp_path, monkeypatch, short_episodes):
    monkeypatch.setenv("WANDB_SILENT", "true")
    cfg = tiny_config("ppo", "noise", tmp_path, logger="wandb", total_steps=256)
    train(cfg, progress=False)
    offline = list((tmp_path / "ppo_noise" / "wandb").glob("offline-run-*"))
    assert offline, "wandb wrote no offline run"


def collect_once(env, policy, frames: int):
    """One batch of ``frames`` env steps collected by ``policy``."""
    from torchrl.collectors import Collector

    collector = Collector(
        env,
        policy,
        frames_per_batch=frames,
        total_frames=frames,
        auto_register_policy_transforms=False,
    )
    data = next(iter(collector))
    collector.shutdown()
    return data


def test_ppo_reward_scale_scales_the_learning_signal_not_the_data(tmp_path):
    """``reward_scale`` multiplies the rewards GAE and the critic see; the collected data (and
    so the logged episode rewards) keep the paper's scale."""
    from dockingrl.agents import make_agent
    from dockingrl.scenarios import make_env

    def critic_loss(scale):
        torch.manual_seed(0)
        cfg = tiny_config("ppo", "compound", tmp_path, reward_scale=scale, epochs=1)
        env = make_env("compound", 8, seed=1)
        agent = make_agent(cfg, 12, env.action_spec[0].clone(), 30.0)
        data = collect_once(env, agent.exploration_policy, 256)
        reward = data["next", "reward"].clone()
        losses = agent.learn(data)
        assert torch.equal(data["next", "reward"], reward)
        return losses["loss_critic"]

    # with the same networks and data, the value targets shrink by the scale
    assert critic_loss(0.1) < 0.2 * critic_loss(1.0)


def test_ppo_trains_with_reward_scale_and_contact_speed_penalty(tmp_path, short_episodes):
    cfg = tiny_config("ppo", "compound", tmp_path, reward_scale=0.1, contact_speed_penalty=2000.0)
    result = train(cfg, progress=False)
    assert result["summary"]["updates"] > 0
    saved = json.loads((tmp_path / "ppo_compound" / "config.json").read_text())
    assert saved["contact_speed_penalty"] == 2000.0 and saved["reward_scale"] == 0.1


@pytest.mark.parametrize("every_epoch", [True, False])
def test_ppo_estimates_advantages_every_epoch_or_once_per_rollout(
    every_epoch, tmp_path, monkeypatch, short_episodes
):
    from torchrl.objectives.value import GAE

    calls = []
    forward = GAE.forward
    monkeypatch.setattr(
        GAE, "forward", lambda self, *a, **k: calls.append(1) or forward(self, *a, **k)
    )
    cfg = tiny_config("ppo", "noise", tmp_path, advantage_every_epoch=every_epoch)
    result = train(cfg, progress=False)
    rollouts = cfg.total_steps // (cfg.num_envs * cfg.steps_per_env)
    assert result["summary"]["frames"] == cfg.total_steps and rollouts >= 2 and cfg.epochs >= 2
    assert len(calls) == rollouts * (cfg.epochs if every_epoch else 1)


@pytest.mark.parametrize("algo", ["ppo", "sac", "td3"])
def test_linear_lr_schedule_falls_with_progress(tmp_path, algo):
    """``lr_schedule="linear"`` sets every optimiser's rate (SAC's temperature's too) to
    ``lr (1 - progress)`` before the updates of a batch; ``late-linear`` keeps ``lr`` over the
    first half, then ``2 lr (1 - progress)``; ``constant`` keeps ``lr``; an unknown schedule
    is refused."""
    from dockingrl.agents import make_agent
    from dockingrl.scenarios import make_env

    env = make_env("noise", 4, seed=1)
    extra = {"ppo": {"epochs": 1}, "sac": {"learn_alpha": True}, "td3": {}}[algo]
    rates = {}
    for schedule in ("constant", "linear", "late-linear"):
        cfg = tiny_config(algo, "noise", tmp_path, lr=1e-3, lr_schedule=schedule, **extra)
        agent = make_agent(cfg, 6, env.action_spec[0].clone(), 30.0)
        data = collect_once(env, agent.exploration_policy, 64)
        for progress in (0.0, 0.25, 0.75):
            updates = {} if algo == "ppo" else {"num_updates": 1}
            losses = agent.learn(data, progress=progress, **updates)
            groups = [g for o in agent.optimizers.values() for g in o.param_groups]
            assert len({g["lr"] for g in groups}) == 1
            rates[schedule, progress] = groups[0]["lr"]
            if algo == "ppo":
                assert losses["lr"] == pytest.approx(rates[schedule, progress])
        assert len(agent.optimizers) == {"ppo": 1, "sac": 3, "td3": 2}[algo]
    assert rates["constant", 0.0] == rates["constant", 0.75] == pytest.approx(1e-3)
    assert rates["linear", 0.0] == pytest.approx(1e-3)
    assert rates["linear", 0.75] == pytest.approx(2.5e-4)
    assert rates["late-linear", 0.0] == rates["late-linear", 0.25] == pytest.approx(1e-3)
    assert rates["late-linear", 0.75] == pytest.approx(5e-4)
    with pytest.raises(ValueError, match="lr_schedule"):
        tiny_config(algo, "noise", tmp_path, lr_schedule="cosine")


def test_keep_best_ends_with_the_actor_of_the_best_periodic_evaluation(
    tmp_path, monkeypatch, short_episodes
):
    """Periodic evaluations score 50, 90, 10 %: the saved policy and the final evaluation use
    the actor of the second one; the checkpoint carries it for a resumed run."""
    from dockingrl.agents.saving import load_policy
    from dockingrl.training import selection

    real_evaluate, scores, seen = selection.evaluate, iter([50.0, 90.0, 10.0]), []

    def scripted(policy, scenario, num_episodes, **kwargs):
        metrics = real_evaluate(policy, scenario, num_episodes, **kwargs)
        if num_episodes == COMMON["eval_episodes"]:  # a periodic evaluation
            metrics["success_rate"] = next(scores)
            seen.append({k: v.clone() for k, v in policy.state_dict().items()})
        else:
            seen.append("final")
            final_state = {k: v.clone() for k, v in policy.state_dict().items()}
            for k, v in seen[1].items():
                torch.testing.assert_close(final_state[k], v)
        return metrics

    monkeypatch.setattr(selection, "evaluate", scripted)
    cfg = tiny_config("ppo", "noise", tmp_path, total_steps=768, eval_every=256, keep_best=True)
    result = train(cfg, progress=False)
    assert seen[-1] == "final" and len(seen) == 4
    assert result["summary"]["policy_from_frames"] == 512
    assert result["summary"]["policy_periodic_success_rate"] == 90.0
    _, info = load_policy(tmp_path / "ppo_noise" / "policy.pt")
    assert info["metadata"]["policy_from_frames"] == 512
    run = tmp_path / "ppo_noise"
    latest = json.loads((run / "checkpoints" / "latest.json").read_text())
    state = torch.load(run / "checkpoints" / latest["path"] / "state.pt", weights_only=False)
    assert state["best"]["frames"] == 512 and state["best"]["success"] == 90.0


def test_keep_candidates_ends_with_the_best_actor_on_validation_episodes(
    tmp_path, monkeypatch, short_episodes
):
    """Periodic evaluations score 50, 90, 70 %; the two best actors (90, 70) are scored again
    on the same validation episodes (95 and 80 %): the run ends with the first (loaded again
    after the second was scored), policy.pt holds it, and the validation seed differs from
    every periodic and final one. A checkpoint of before the candidates (only ``best``)
    still loads."""
    from dockingrl.agents.saving import load_policy
    from dockingrl.training import selection

    real_evaluate, periodic, validation = selection.evaluate, iter([50.0, 90.0, 70.0]), {}
    actors, seeds = {}, {"periodic": [], "select": [], "final": []}

    def scripted(policy, scenario, num_episodes, **kwargs):
        metrics = real_evaluate(policy, scenario, num_episodes, **kwargs)
        state = {k: v.clone() for k, v in policy.state_dict().items()}
        if num_episodes == COMMON["eval_episodes"]:
            metrics["success_rate"] = next(periodic)
            actors[metrics["success_rate"]] = state
            seeds["periodic"].append(kwargs["seed"])
        elif num_episodes == 5:  # select_episodes
            match = [s for s, a in actors.items() if all(torch.equal(a[k], state[k]) for k in a)]
            metrics["success_rate"] = {90.0: 95.0, 70.0: 80.0}[match[0]]
            validation[match[0]] = metrics["success_rate"]
            seeds["select"].append(kwargs["seed"])
        else:
            seeds["final"].append(kwargs["seed"])
            for k, v in actors[90.0].items():
                torch.testing.assert_close(state[k], v)
        return metrics

    monkeypatch.setattr(selection, "evaluate", scripted)
    cfg = tiny_config(
        "ppo",
        "noise",
        tmp_path,
        total_steps=768,
        eval_every=256,
        keep_best=True,
        keep_candidates=2,
        select_episodes=5,
    )
    summary = train(cfg, progress=False)["summary"]
    assert validation == {90.0: 95.0, 70.0: 80.0}, "both kept actors, and only they, validated"
    assert summary["policy_from_frames"] == 512
    assert summary["policy_periodic_success_rate"] == 90.0
    assert summary["policy_validation_success_rate"] == 95.0
    assert [c["frames"] for c in summary["selection"]] == [512, 768]
    saved = load_policy(tmp_path / "ppo_noise" / "policy.pt")[0].state_dict()
    for k, v in actors[90.0].items():
        torch.testing.assert_close(saved[k], v)
    assert len(set(seeds["select"])) == 1 and len(seeds["final"]) == 1
    assert not set(seeds["select"]) & set(seeds["periodic"] + seeds["final"])
    with pytest.raises(ValueError, match="keep_candidates"):
        tiny_config("ppo", "noise", tmp_path, keep_best=True, keep_candidates=0)
    with pytest.raises(ValueError, match="set keep_best"):
        tiny_config("ppo", "noise", tmp_path, keep_candidates=2)
    # an older checkpoint holds only the best actor: it is the one candidate
    run = tmp_path / "ppo_noise"
    path = (
        run / "checkpoints" / json.loads((run / "checkpoints" / "latest.json").read_text())["path"]
    )
    state = torch.load(path / "state.pt", weights_only=True)
    del state["candidates"]
    save_artifact(path / "state.pt", state)
    trainer = Trainer(cfg, run, progress=False)
    assert trainer.load_checkpoint() and len(trainer.candidates) == 1
    assert trainer.candidates[0]["frames"] == state["best"]["frames"] == 512


def test_runs_with_an_averaged_actor_evaluate_and_save_it(tmp_path, monkeypatch, short_episodes):
    """With ``actor_average`` every evaluation sees the averaged actor (never the live one
    that explores), and policy.pt holds the averaged weights of the last checkpoint."""
    from dockingrl.agents.saving import load_policy
    from dockingrl.training import selection

    real_evaluate, seen = selection.evaluate, []

    def spy(policy, scenario, num_episodes, **kwargs):
        seen.append(all(not p.requires_grad for p in policy.parameters()))
        return real_evaluate(policy, scenario, num_episodes, **kwargs)

    monkeypatch.setattr(selection, "evaluate", spy)
    cfg = tiny_config("sac", "compound", tmp_path, actor_average=0.9)
    train(cfg, progress=False)
    assert seen == [True, True, True], "two periodic evaluations and the final one"
    run = tmp_path / "sac_compound"
    latest = json.loads((run / "checkpoints" / "latest.json").read_text())
    assert latest["frames"] == cfg.total_steps
    state = torch.load(run / "checkpoints" / latest["path"] / "state.pt", weights_only=False)
    saved = load_policy(run / "policy.pt")[0].state_dict()
    averaged = state["agent"]["averaged"]
    assert set(saved) == set(averaged)
    for k, v in averaged.items():
        assert torch.equal(saved[k], v), k


def test_time_budget_stops_training_early_and_says_so(tmp_path, short_episodes):
    cfg = tiny_config("ppo", "noise", tmp_path, total_steps=2048, time_budget_s=1e-6)
    result = train(cfg, progress=False)
    summary = result["summary"]
    assert summary["frames"] == 256 < cfg.total_steps, "one rollout, then the budget is spent"
    assert summary["stopped_by_time_budget"] is True
    assert result["eval"]["episodes"] == COMMON["final_eval_episodes"]
    with pytest.raises(ValueError, match="time_budget_s"):
        tiny_config("ppo", "noise", tmp_path, time_budget_s=-1.0)


def test_train_level_sets_the_whole_world_of_the_run(tmp_path, short_episodes, monkeypatch):
    from dockingrl import training
    from dockingrl.env.levels import LEVELS
    from dockingrl.training import collection

    built = []
    make_env = collection.make_env
    monkeypatch.setattr(
        collection, "make_env", lambda *a, **k: built.append(k["config"]) or make_env(*a, **k)
    )
    cfg = tiny_config("sac", "compound", tmp_path, train_level="L5")
    world = training.env_kwargs(cfg)["config"]
    assert world.realistic and world.usbl_period == LEVELS["L5"][1]["usbl_period"]
    assert world.mass_scale == LEVELS["L5"][1]["mass_scale"]
    assert not training.env_kwargs(tiny_config("sac", "compound", tmp_path))["config"].realistic
    result = train(cfg, progress=False)
    assert built and all(config.realistic for config in built)  # probe and training envs
    saved = json.loads((Path(result["run_dir"]) / "config.json").read_text())
    assert saved["train_level"] == "L5"
    assert result["eval"]["level"] == "L5"  # the final evaluation names its world
    with pytest.raises(ValueError, match="train_level: unknown stress level; valid: L0, L1"):
        tiny_config("sac", "compound", tmp_path, train_level="L9")


def test_train_curriculum_steps_the_training_world_through_its_levels(
    tmp_path, short_episodes, monkeypatch
):
    """``train_curriculum="L0,L3"`` at ``train_level`` L5: the training env of each third of
    the run is built at its level (from the first batch at or past the stage's start), the
    evaluations stay at L5; without a curriculum one env, at ``train_level``, trains the run;
    an unknown level is refused, named."""
    from dockingrl.env.levels import LEVELS
    from dockingrl.evaluation import runs as evaluation_runs
    from dockingrl.training import options, trainer

    built, evaluated = [], []
    training_env = trainer.training_env
    monkeypatch.setattr(
        trainer,
        "training_env",
        lambda cfg, kwargs, frames: (
            built.append((frames, kwargs["config"])) or training_env(cfg, kwargs, frames)
        ),
    )
    make_env = evaluation_runs.make_env
    monkeypatch.setattr(
        evaluation_runs,
        "make_env",
        lambda *a, **k: evaluated.append(k["config"]) or make_env(*a, **k),
    )
    cfg = tiny_config("sac", "compound", tmp_path, train_level="L5", train_curriculum="L0,L3")
    assert options.curriculum_stages(cfg) == [("L0", 133), ("L3", 266), ("L5", 400)]
    assert [options.stage_at(cfg, f)[0] for f in (0, 132, 133, 300, 399, 400, 500)] == [
        "L0",
        "L0",
        "L3",
        "L5",
        "L5",
        "L5",
        "L5",
    ]
    result = train(cfg, progress=False)
    assert result["summary"]["frames"] == cfg.total_steps == 400
    assert [frames for frames, _ in built] == [0, 200, 300]  # batches of 100 env steps
    l0, l3, l5 = (world for _, world in built)
    assert not l0.realistic
    assert l3.mass_scale == LEVELS["L3"][1]["mass_scale"] and l3.usbl_period == l0.usbl_period
    assert l5.usbl_period == LEVELS["L5"][1]["usbl_period"] and l5.mass_scale == l3.mass_scale
    assert evaluated and all(world == options.env_kwargs(cfg)["config"] for world in evaluated)
    saved = json.loads((Path(result["run_dir"]) / "config.json").read_text())
    assert saved["train_curriculum"] == "L0,L3"
    with pytest.raises(ValueError, match="train_curriculum 'L0,L3' shares out its total_st"):
        train(None, resume=result["run_dir"], progress=False, overrides={"total_steps": 800})
    built.clear()
    train(tiny_config("sac", "compound", tmp_path / "flat", train_level="L5"), progress=False)
    assert [frames for frames, _ in built] == [0] and built[0][1].realistic
    with pytest.raises(ValueError, match="train_curriculum: unknown stress level 'L7'"):
        tiny_config("sac", "compound", tmp_path, train_curriculum="L1,L7")
    with pytest.raises(ValueError, match="4 stages of total_steps // 4 = 100 env steps, short"):
        tiny_config(
            "sac",
            "compound",
            tmp_path,
            train_curriculum="L1,L2,L3",
            total_steps=400,
            frames_per_batch=200,
        )
    with pytest.raises(ValueError, match="train_curriculum: not with time_budget_s"):
        tiny_config("sac", "compound", tmp_path, train_curriculum="L1", time_budget_s=60.0)


def test_a_new_stage_restarts_the_n_step_window(tmp_path, short_episodes, monkeypatch):
    """With ``n_steps`` 3, the steps waiting for the next collection are dropped when a
    curriculum stage builds its env (its episodes start afresh), and only then."""
    from dockingrl.agents.off_policy import OffPolicyAgent
    from dockingrl.training import trainer

    tails = []
    restart = OffPolicyAgent.restart_episodes
    training_env = trainer.training_env

    def spy(self):
        tails.append(self.window.tail is not None)
        restart(self)
        assert self.window.tail is None

    monkeypatch.setattr(OffPolicyAgent, "restart_episodes", spy)
    cfg = tiny_config("sac", "compound", tmp_path, train_curriculum="L3", n_steps=3)
    result = train(cfg, progress=False)
    assert result["summary"]["frames"] == cfg.total_steps
    # at the first stage nothing waits; at the second the last batch's two steps did
    assert tails == [False, True] and training_env is trainer.training_env


def test_off_policy_runs_anneal_their_rate_over_the_run(tmp_path, short_episodes):
    """A SAC run with ``lr_schedule="linear"`` ends with every optimiser at the rate of its
    last batch, ``lr (1 - progress)``: the training loop passes its progress to SAC."""
    from dockingrl.training import Trainer

    cfg = tiny_config("sac", "noise", tmp_path, lr=1e-3, lr_schedule="linear")
    result = train(cfg, progress=False)
    trainer = Trainer(cfg, Path(result["run_dir"]), progress=False)
    assert trainer.load_checkpoint()
    last_batch = cfg.total_steps - cfg.frames_per_batch
    rates = [g["lr"] for o in trainer.agent.optimizers.values() for g in o.param_groups]
    assert len(rates) == 2
    assert rates == pytest.approx([1e-3 * (1 - last_batch / cfg.total_steps)] * 2)


def test_compensate_latency_reaches_the_training_filter_and_the_saved_policy(
    tmp_path, short_episodes
):
    from dockingrl import training
    from dockingrl.onboard import OnboardPolicy
    from dockingrl.policies import resolve_policy
    from dockingrl.stress import stress_ladder

    cfg = tiny_config("sac", "compound", tmp_path, train_level="L1", compensate_latency=True)
    kwargs = training.env_kwargs(cfg)
    assert kwargs["ekf_kwargs"] == {"compensate_latency": True}
    assert "ekf_kwargs" not in training.env_kwargs(tiny_config("sac", "compound", tmp_path))
    from dockingrl.scenarios import make_env

    env = make_env("compound", 2, seed=0, **kwargs)
    ekf = next(t for t in env.transform if type(t).__name__ == "EKFTransform")
    assert ekf.latency_steps == kwargs["config"].usbl_latency_steps > 0
    result = train(cfg, progress=False)
    path = Path(result["run_dir"]) / "policy.pt"
    assert OnboardPolicy.from_file(path).step.ekf.latency_steps == 0  # L0: no latency
    vehicle = OnboardPolicy.from_file(path, config=kwargs["config"])  # the vehicle's latency
    assert vehicle.step.ekf.latency_steps == kwargs["config"].usbl_latency_steps
    policy, _, scenario, options, _ = resolve_policy(str(path))
    ladder = stress_ladder(policy, scenario, episodes=4, levels=("L1",), **options)
    assert ladder["compensate_latency"] is True
    with pytest.raises(ValueError, match="compensate_latency: scenario 'noise' has no filter"):
        tiny_config("sac", "noise", tmp_path, compensate_latency=True)


def test_ppo_stable_baselines3_style_policy_options(tmp_path, short_episodes):
    """``state_independent_scale``: one learned scale per action, the same for every
    observation; ``orthogonal_init``: orthogonal layers, a near-zero policy output; ``tanh``
    activations; the saved policy rebuilds them; an unknown activation is refused."""
    from tensordict import TensorDict

    from dockingrl.agents import build_actor, make_agent
    from dockingrl.scenarios import make_env

    env = make_env("compound", 2, seed=0)
    spec = env.action_spec[0].clone()
    cfg = tiny_config(
        "ppo",
        "compound",
        tmp_path,
        activation="tanh",
        state_independent_scale=True,
        orthogonal_init=True,
    )
    agent = make_agent(cfg, 12, spec, 30.0)
    actor = agent.exploration_policy
    assert any(isinstance(m, torch.nn.Tanh) for m in actor.modules())
    assert not any(isinstance(m, torch.nn.ReLU) for m in actor.modules())
    observations = torch.randn(64, 12) * torch.tensor([10.0, 1, 1, 0.3, 0.3, 0.1] * 2)
    params = actor.module[0](TensorDict({"observation": observations}, [64]))
    assert torch.allclose(params["scale"], params["scale"][:1].expand(64, -1))
    assert params["loc"].abs().max() < 0.1  # output gain 0.01
    linears = [m for m in actor.modules() if isinstance(m, torch.nn.Linear)]
    w = linears[0].weight  # 32 x 12: orthonormal columns times sqrt(2)
    assert torch.allclose(w.T @ w, 2.0 * torch.eye(12), atol=1e-5)
    assert all((m.bias == 0).all() for m in linears)
    # the default keeps a state-dependent scale and ReLU
    plain = build_actor(tiny_config("ppo", "compound", tmp_path), 12, spec, 30.0)
    params = plain.module[0](TensorDict({"observation": observations}, [64]))
    assert not torch.allclose(params["scale"], params["scale"][:1].expand(64, -1))
    # train briefly, save, load: the loaded actor has the same layers and the learned scale
    result = train(cfg, progress=False)
    loaded, info = load_policy(Path(result["run_dir"]) / "policy.pt")
    assert info["config"]["state_independent_scale"] is True
    assert any(isinstance(m, torch.nn.Tanh) for m in loaded.modules())
    (learned,) = [p for n, p in loaded.named_parameters() if n.endswith("state_independent_scale")]
    assert learned.abs().max() > 0  # moved from its initial 0 by the updates
    with pytest.raises(ValueError, match="activation"):
        tiny_config("ppo", "compound", tmp_path, activation="gelu")


def test_field_value_overrides_are_typed_and_checked():
    from dockingrl.agents.config import parse_overrides

    parsed = parse_overrides(
        "ppo", ["gamma=0.995", "contact_speed_penalty_cap=false", "hidden=64,32", "num_envs=32"]
    )
    assert parsed == {
        "gamma": 0.995,
        "contact_speed_penalty_cap": False,
        "hidden": (64, 32),
        "num_envs": 32,
    }
    assert make_config("ppo", "fast", **parsed).hidden == (64, 32)
    for bad in ("num_envs=2.5", "keep_best=maybe", "alpha=0.1", "gamma", "hidden=3x"):
        with pytest.raises(ValueError, match=bad.partition("=")[0]):
            parse_overrides("ppo", [bad])


def test_privileged_critic_run_checkpoints_its_buffer_and_saves_an_observation_only_policy(
    tmp_path, short_episodes
):
    cfg = tiny_config("sac", "compound", tmp_path, privileged_critic=True, final_eval_episodes=4)
    train(cfg, progress=False)
    run = tmp_path / "sac_compound"
    # a resumed run reloads the replay buffer with the privileged entries of both steps
    saved = json.loads((run / "config.json").read_text())
    saved["hidden"] = tuple(saved["hidden"])
    trainer = Trainer(SACConfig(**saved), run, progress=False)
    assert trainer.load_checkpoint()
    stored = trainer.agent.replay_buffer.sample()
    for key in ("true_state", "ocean_current", ("next", "true_state"), ("next", "ocean_current")):
        assert key in stored.keys(include_nested=True)
    # the saved policy reads the compound observation and nothing else
    policy, _ = load_policy(run / "policy.pt")
    from dockingrl.scenarios import make_env

    td = make_env("compound", 3, seed=1).reset().select("observation")
    assert policy(td)["action"].shape == (3, 2)


def test_eval_rebuilds_the_training_world_of_a_mismatch_run(tmp_path, capsys, short_episodes):
    """``dockingrl eval`` of a policy trained with scaled USBL noise and a learned filter
    file evaluates it in that world (and reproduces the run's own final evaluation);
    ``--filter-params none`` and the noise flags put it back in the paper's."""
    from helpers import smoke_config

    from dockingrl.onboard import OnboardPolicy
    from dockingrl.scenarios import make_filter

    ekf = make_filter(DockingConfig())
    with torch.no_grad():
        ekf.measurement_noise.log_std.add_(0.7)
    ekf_log_std = ekf.measurement_noise.log_std.detach().clone()
    ekf.save_filter_params(tmp_path / "filter.pt")
    cfg = smoke_config(
        "sac",
        "compound",
        tmp_path,
        "mismatch",
        total_steps=128,
        start_steps=64,
        frames_per_batch=64,
        eval_every=128,
        final_eval_episodes=3,
        range_noise_scale=3.0,
        filter_params=str(tmp_path / "filter.pt"),
    )
    result = train(cfg, progress=False)
    policy = str(tmp_path / "mismatch" / "policy.pt")
    base = ["eval", "--policy", policy, "--episodes", "3", "--seed", "10000", "--quiet"]
    assert cli_main([*base, "--out", str(tmp_path / "same")]) == 0
    said = capsys.readouterr().out
    assert "as the policy was trained: range_noise_scale 3, filter_params" in said
    same = json.loads((tmp_path / "same" / "eval.json").read_text())
    assert same["total_reward"] == result["eval"]["total_reward"]
    paper = ["--filter-params", "none", "--range-noise-scale", "1", "--out", str(tmp_path / "p")]
    assert cli_main([*base, *paper]) == 0
    assert "as the policy was trained" not in capsys.readouterr().out
    other = json.loads((tmp_path / "p" / "eval.json").read_text())
    assert other["total_reward"] != same["total_reward"]
    with pytest.raises(SystemExit, match="no such file"):
        cli_main([*base, "--filter-params", str(tmp_path / "missing.pt")])
    # the policy carries its filter: with the file gone, eval and the onboard policy still
    # filter with the learned Q and R
    (tmp_path / "filter.pt").unlink()
    assert cli_main([*base, "--out", str(tmp_path / "again")]) == 0
    again = json.loads((tmp_path / "again" / "eval.json").read_text())
    assert again["total_reward"] == same["total_reward"]
    onboard = OnboardPolicy.from_file(policy)
    torch.testing.assert_close(onboard.step.ekf.measurement_noise.log_std, ekf_log_std)


def test_the_summary_names_the_code_a_run_started_on_and_what_ran_it_before(
    tmp_path, short_episodes, monkeypatch
):
    from dockingrl.training import trainer as trainer_module

    first_code, later_code = ({"commit": c * 40, "dirty": False} for c in "ab")
    versions = iter([first_code, later_code])
    # read once per process, when training starts: a third read would raise StopIteration
    monkeypatch.setattr(trainer_module, "code_version", lambda: next(versions))
    cfg = tiny_config("sac", "compound", tmp_path)
    first = train(cfg, progress=False)["summary"]
    assert first["code"] == first_code and "code_history" not in first
    again = train(
        None,
        resume=tmp_path / "sac_compound",
        progress=False,
        overrides={"total_steps": cfg.total_steps + 200},
    )["summary"]
    assert again["code"] == later_code
    assert again["code_history"] == [first_code, later_code]


def test_periodic_evaluations_log_success_per_third_of_the_current(
    tmp_path, monkeypatch, short_episodes
):
    """Each periodic evaluation logs the success of each third of the along-axis current that
    has episodes (eval/success_opposing, _weak, _following), the evaluation's own numbers; an
    empty third is left out rather than logged as a rate."""
    from dockingrl.training import selection

    real_evaluate, thirds = selection.evaluate, iter([(20.0, None, 60.0), (30.0, 40.0, 50.0)])

    def scripted(policy, scenario, num_episodes, **kwargs):
        metrics = real_evaluate(policy, scenario, num_episodes, **kwargs)
        if num_episodes == COMMON["eval_episodes"]:
            for third, rate in zip(metrics["by_current_x"], next(thirds), strict=True):
                third["success_rate"] = rate
        return metrics

    monkeypatch.setattr(selection, "evaluate", scripted)
    cfg = tiny_config("ppo", "noise", tmp_path, total_steps=512, eval_every=256)
    train(cfg, progress=False)
    curves = read_curves(tmp_path / "ppo_noise")
    assert [v for _, v in curves["eval/success_opposing"]] == [20.0, 30.0]
    assert [v for _, v in curves["eval/success_weak"]] == [40.0]
    assert [v for _, v in curves["eval/success_following"]] == [60.0, 50.0]
    assert [s for s, _ in curves["eval/success_weak"]] == [
        s for s, _ in curves["eval/success_rate"]
    ][1:]


def test_the_progress_bar_shows_success_only_once_an_evaluation_has_run():
    from dockingrl.training.trainer import progress_fields

    before = progress_fields({"time/steps_per_s": 1234.4}, float("nan"))
    assert before == {"sps": "1234"}
    assert progress_fields({"time/steps_per_s": 10.0}, 97.6) == {"sps": "10", "success": "98%"}


def test_a_training_command_builds_and_validates_its_config_once_and_its_env_once(
    tmp_path, monkeypatch
):
    """From ``dockingrl train --recipe ppo`` to its first gradient step the run's config is
    checked once (the recipe's, the options' and the trainer's checks are one) and one env is
    built: the one the agent is sized from is the one it trains in."""
    import torch

    from dockingrl.agents.config import PPOConfig
    from dockingrl.cli import CommandFailed, main
    from dockingrl.env.docking import DockingEnv

    checks, envs = [], []
    check, build = PPOConfig._check_config, DockingEnv.__init__
    monkeypatch.setattr(PPOConfig, "_check_config", lambda self: checks.append(1) or check(self))
    monkeypatch.setattr(
        DockingEnv, "__init__", lambda self, *a, **k: envs.append(1) or build(self, *a, **k)
    )

    class FirstStep(Exception):
        pass

    def first_step(self, *args, **kwargs):
        raise FirstStep

    monkeypatch.setattr(torch.optim.Adam, "step", first_step)
    argv = ["train", "--recipe", "ppo", "--threads", "1", "--num-envs", "8"]
    argv += ["--minibatch-size", "256", "--out", str(tmp_path), "--logger", "none"]
    with pytest.raises(CommandFailed, match="FirstStep"):
        main([*argv, "--no-progress"])
    assert (len(checks), len(envs)) == (1, 1)
    cfg = PPOConfig(num_envs=8)
    cfg.validate()
    cfg.validate()  # unchanged: not checked again
    cfg.num_envs = 0
    with pytest.raises(ValueError, match="num_envs"):
        cfg.validate()  # changed: checked again
    assert len(checks) == 3
