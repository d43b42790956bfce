import json

import numpy as np
import pytest
import torch

from dockingrl.cli import main as cli_main
from dockingrl.env import DockingConfig
from dockingrl.filter_comparison import ppo_filter_comparison
from dockingrl.filter_learning import (
    FilterFit,
    evaluate_filter,
    fit_filter,
    mismatched_config,
    record_rollouts,
    run_filter,
)
from dockingrl.scenarios import make_filter
from dockingrl.transforms import EKFTransform, MeasurementNoise, ProcessNoise
from dockingrl.upgrade import upgrade_file


@pytest.fixture(scope="module")
def rollouts():
    return record_rollouts(16, 120, seed=0)


def test_rollouts_mark_episode_starts(rollouts):
    assert rollouts.shape == (120, 16)
    assert (rollouts["step_count"][0] == 0).all()
    assert torch.equal(
        rollouts["step_count"][1:] - rollouts["step_count"][:-1],
        torch.ones(119, 16, dtype=torch.int64),
    )


@pytest.mark.parametrize("objective", ["nll", "supervised", "mse"])
def test_a_few_steps_reduce_the_objective(objective, rollouts):
    ekf = make_filter(DockingConfig())
    fit = FilterFit(objective=objective, window=40, epochs=1, lr=0.05)
    with torch.no_grad():
        before = run_filter(ekf, rollouts[:40], objective=objective)[3].item()
    history = fit_filter(ekf, fit, data=rollouts[:40].clone())
    for _ in range(5):
        history += fit_filter(ekf, fit, data=rollouts[:40].clone())
    with torch.no_grad():
        after = run_filter(ekf, rollouts[:40], objective=objective)[3].item()
    assert history[0] == pytest.approx(before, rel=1e-5)
    assert after < before
    assert not any(p.requires_grad for p in ekf.noise_parameters()), "frozen again after fitting"


def test_positive_definite_parameterisation_survives_any_parameters():
    gen = torch.Generator().manual_seed(0)
    q, r = ProcessNoise(), MeasurementNoise()
    for _ in range(500):  # sigmas from 1e-3 to 7, random correlations
        with torch.no_grad():
            q.log_diag.copy_(torch.rand(5, generator=gen) * 9 - 7)
            q.off_diag.copy_(torch.randn(10, generator=gen) * 0.5)
            r.log_std.copy_(torch.rand(6, generator=gen) * 9 - 7)
        Q = q().double()
        assert torch.equal(Q, Q.T)
        assert torch.linalg.eigvalsh(Q).min() > 0
        assert (r(torch.rand(7) * 30).double() > 0).all()


def test_learned_parameters_round_trip_through_the_cli(tmp_path):
    out = tmp_path / "nll"
    code = cli_main(
        [
            "learn-filter",
            "--objective",
            "nll",
            "--num-envs",
            "8",
            "--steps",
            "80",
            "--window",
            "20",
            "--epochs",
            "1",
            "--out",
            str(out),
            "--logger",
            "csv",
            "--threads",
            "1",
        ]
    )
    assert code == 0
    report = json.loads((out / "eval.json").read_text())
    loaded = EKFTransform().load_filter_params(out / "filter_params.pt")
    torch.testing.assert_close(loaded.measurement_noise.std(), torch.tensor(report["R_sigma"]))
    torch.testing.assert_close(
        loaded.process_noise().diagonal().sqrt(), torch.tensor(report["Q_sigma"])
    )
    assert (out / "curves.csv").stat().st_size > 0


def test_learn_filter_on_a_stress_level_fits_on_its_asynchronous_sensors(
    tmp_path, monkeypatch, capsys
):
    from dockingrl import filter_experiments

    recorded = []
    record = filter_experiments.record_rollouts
    monkeypatch.setattr(
        filter_experiments,
        "record_rollouts",
        lambda *a, **k: recorded.append(k["config"]) or record(*a, **k),
    )
    out = tmp_path / "l1"
    argv = ["learn-filter", "--level", "L1", "--num-envs", "8", "--steps", "60", "--window"]
    argv += ["20", "--epochs", "1", "--out", str(out), "--logger", "none", "--threads", "1"]
    assert cli_main(argv) == 0
    report = json.loads((out / "eval.json").read_text())
    assert report["level"] == "L1"
    assert recorded and all(c.usbl_period == 1.0 and c.sensor_timing for c in recorded)
    assert report["held_out_learned"]["rmse_position_m"] > 0
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        cli_main(["learn-filter", "--level", "L9", "--out", str(out)])
    assert exit_.value.code == 2
    assert "argument --level: invalid choice: 'L9'" in capsys.readouterr().err


def by_hand(means, covs, rollouts, skip=10):
    """The state errors, their covariances and the NEES after the first ``skip`` steps of
    every episode, in numpy: ``(error, cov, nees)`` flattened, and ``nees`` per env."""
    truth = rollouts["true_state"].double().numpy()
    estimate = means.double().numpy()
    error = estimate - truth[..., [0, 1, 2, 3, 5]]  # x, y, heading, surge, yaw rate
    error[..., 2] = (error[..., 2] + np.pi) % (2 * np.pi) - np.pi
    cov = covs.double().numpy()
    nees = np.einsum("tni,tnij,tnj->tn", error, np.linalg.inv(cov), error)
    keep = (rollouts["step_count"] >= skip).numpy()
    per_env = [nees[keep[:, n], n].mean() for n in range(keep.shape[1])]
    return error[keep], cov[keep], nees[keep], np.array(per_env)


def test_filter_evaluation_reports_rmse_and_nees(rollouts):
    from scipy.stats import chi2

    ekf = make_filter(DockingConfig())
    report = evaluate_filter(ekf, rollouts)
    with torch.no_grad():
        means, covs, _, _ = run_filter(ekf, rollouts)
    error, cov, nees, per_env = by_hand(means, covs, rollouts)
    n = len(nees)
    assert report["samples"] == n == 16 * (120 - 10)
    close = {"rel": 1e-5}  # the report subtracts in float32, this in float64
    assert report["rmse_position_m"] == pytest.approx(
        np.sqrt((error[:, :2] ** 2).sum(-1).mean()), **close
    )
    for i, key in ((2, "rmse_heading_rad"), (3, "rmse_surge_m_s"), (4, "rmse_yaw_rate_rad_s")):
        assert report[key] == pytest.approx(np.sqrt((error[:, i] ** 2).mean()), **close), key
    assert report["nees_mean"] == pytest.approx(nees.mean(), **close)
    assert report["normalized_error_per_component"] == pytest.approx(
        (error**2 / np.diagonal(cov, axis1=-2, axis2=-1)).mean(0), **close
    )
    # the 95 % region of the mean of n chi-square(5) samples, and of one sample (the report's
    # quantiles are Wilson and Hilferty's approximation, 4 % low in the lower tail of 5 dof)
    assert report["nees_mean_bounds_95"] == pytest.approx(chi2.ppf([0.025, 0.975], 5 * n) / n)
    assert report["nees_step_bounds_95"] == pytest.approx(chi2.ppf([0.025, 0.975], 5), rel=0.05)
    low, high = report["nees_step_bounds_95"]
    inside = ((nees >= low) & (nees <= high)).mean()
    assert report["nees_fraction_in_step_bounds"] == pytest.approx(inside, abs=1e-12)
    # the 95 % interval of the mean over the 16 independent runs (envs)
    half = 1.96 * per_env.std(ddof=1) / np.sqrt(len(per_env))
    expected = [per_env.mean() - half, per_env.mean() + half]
    assert report["nees_mean_ci95_over_runs"] == pytest.approx(expected, **close)


def test_mismatched_condition_and_bad_options():
    cfg = mismatched_config(2.0)
    base = DockingConfig()
    assert cfg.range_noise_fraction == 2 * base.range_noise_fraction
    assert cfg.bearing_noise == 2 * base.bearing_noise
    assert cfg.heading_noise == base.heading_noise
    with pytest.raises(ValueError, match="objective"):
        fit_filter(make_filter(base), FilterFit(objective="l1"))
    with pytest.raises(ValueError, match="behaviour"):
        record_rollouts(2, 10, behaviour="drunk")


def test_run_averaged_nees_test_accepts_consistent_and_rejects_overconfident_errors():
    from dockingrl.filter_learning import run_averaged_nees_test

    gen = torch.Generator().manual_seed(0)
    chi2 = torch.randn(400, 128, 5, generator=gen, dtype=torch.float64).pow(2).sum(-1)
    keep = torch.rand(400, 128, generator=gen) > 0.05
    consistent = run_averaged_nees_test(chi2, keep)
    assert 0.92 <= consistent <= 0.98
    assert run_averaged_nees_test(1.3 * chi2, keep) < 0.2  # covariance 30 % too small
    assert run_averaged_nees_test(0.7 * chi2, keep) < 0.2  # 30 % too large


def test_supervised_objective_is_the_gaussian_likelihood_of_the_truth():
    from dockingrl.filter_learning import gaussian_nll

    gen = torch.Generator().manual_seed(1)
    A = torch.randn(7, 5, 5, generator=gen, dtype=torch.float64)
    cov = A @ A.transpose(-1, -2) + 0.1 * torch.eye(5, dtype=torch.float64)
    residual = torch.randn(7, 5, generator=gen, dtype=torch.float64)
    reference = torch.distributions.MultivariateNormal(torch.zeros(5, dtype=torch.float64), cov)
    constant = 2.5 * torch.log(torch.tensor(2 * torch.pi, dtype=torch.float64))
    torch.testing.assert_close(
        gaussian_nll(residual, cov), -reference.log_prob(residual) - constant
    )


def test_ppo_filter_comparison_trains_both_agents_and_writes_the_table(tmp_path):
    params = tmp_path / "nll.pt"
    from dockingrl.transforms.params import save_filter_params

    save_filter_params(make_filter(DockingConfig()), params, objective="nll")
    tiny = ["num_envs=4", "steps_per_env=32", "minibatch_size=64", "epochs=1"]
    tiny += ["eval_every=10000", "final_eval_episodes=4", "threads=1", "checkpoint_every=0"]
    code = cli_main(
        ["ppo-filter-comparison", "--filter-params", str(params), "--total-steps", "128"]
        + ["--out", str(tmp_path / "res"), "--runs", str(tmp_path / "runs"), "--seeds", "0", "1"]
        + ["--set", *tiny]
    )
    assert code == 0
    report = json.loads((tmp_path / "res" / "ppo_mismatch.json").read_text())
    assert len(report["agents"]) == 2
    for agent in report["agents"].values():
        assert sorted(agent["runs"]) == ["0", "1"]
        rates = [run["success_rate"] for run in agent["runs"].values()]
        assert all(run["frames"] >= 128 for run in agent["runs"].values())
        assert agent["success_rate_mean"] == pytest.approx(sum(rates) / 2)
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == [
        "ppo_mismatch_handtuned_s0",
        "ppo_mismatch_handtuned_s1",
        "ppo_mismatch_learned_s0",
        "ppo_mismatch_learned_s1",
    ]
    table = (tmp_path / "res" / "ppo_mismatch.md").read_text()
    assert "| learned: " in table and "mean of 2" in table
    # run again: the finished runs are read back, not trained again, and give the same table
    argv = ["ppo-filter-comparison", "--filter-params", str(params), "--total-steps", "128"]
    argv += ["--out", str(tmp_path / "res"), "--runs", str(tmp_path / "runs"), "--seeds", "0", "1"]
    policies = sorted((tmp_path / "runs").glob("*/policy.pt"))
    assert len(policies) == 4
    stamps = [p.stat().st_mtime_ns for p in policies]
    assert cli_main(argv + ["--set", *tiny]) == 0
    assert [p.stat().st_mtime_ns for p in policies] == stamps
    assert json.loads((tmp_path / "res" / "ppo_mismatch.json").read_text()) == report
    with pytest.raises(SystemExit, match="holds a run of another config \\(epochs differ\\)"):
        cli_main(argv + ["--set", *tiny[:3], "epochs=2", *tiny[4:]])
    with pytest.raises(SystemExit, match="--seeds 0 0: a seed is named twice"):
        cli_main(argv[:-2] + ["0", "0", "--set", *tiny])
    summary = tmp_path / "runs" / "ppo_mismatch_learned_s1" / "summary.json"
    summary.write_text("{}")  # a finished run's file emptied: named, not a KeyError
    with pytest.raises(SystemExit, match="learned_s1/summary.json: not a finished run's file"):
        cli_main(argv + ["--set", *tiny])
    (summary.parent / "config.json").write_text('{"algo": "pp')  # torn
    with pytest.raises(SystemExit, match="learned_s1/config.json: damaged"):
        cli_main(argv + ["--set", *tiny])
    junk = tmp_path / "junk.pt"
    junk.write_text("not a filter")
    with pytest.raises(ValueError, match="junk.pt"):
        ppo_filter_comparison(str(junk), tmp_path / "res2", runs_dir=str(tmp_path / "runs2"))
    assert not (tmp_path / "runs2").exists()  # refused before any training
    with pytest.raises(SystemExit, match="hidden"):
        cli_main(["ppo-filter-comparison", "--filter-params", str(params), "--set", "hidden=3x"])
    with pytest.raises(SystemExit, match="seed"):
        cli_main(["ppo-filter-comparison", "--filter-params", str(params), "--set", "seed=4"])


def test_manoeuvre_q_is_the_constant_q_at_zero_gap_grows_with_it_and_stays_pd():
    gen = torch.Generator().manual_seed(1)
    q = ProcessNoise(manoeuvre=True)
    mean = torch.zeros(64, 5)
    mean[:, 3:] = torch.randn(64, 2, generator=gen) * 0.3
    torch.testing.assert_close(q(mean, mean[:, 3:]), q().expand(64, 5, 5))
    gap = torch.tensor([[0.0, 0.0], [0.2, 0.0], [0.8, 0.0], [0.0, 0.3]])
    Q = q(torch.zeros(4, 5), gap).diagonal(dim1=-2, dim2=-1)
    assert (Q[2] > Q[1]).all() and (Q[1] > Q[0]).all() and (Q[3] > Q[0]).all()
    for _ in range(300):  # any parameters, any gap: symmetric positive-definite
        with torch.no_grad():
            q.log_diag.copy_(torch.rand(5, generator=gen) * 9 - 7)
            q.off_diag.copy_(torch.randn(10, generator=gen) * 0.5)
            q.log_manoeuvre_gain.copy_(torch.rand(2, 5, generator=gen) * 12 - 9)
        Q = q(torch.randn(8, 5, generator=gen), torch.randn(8, 2, generator=gen)).double()
        assert torch.equal(Q, Q.transpose(-1, -2))
        assert torch.linalg.eigvalsh(Q).min() > 0
    with pytest.raises(ValueError, match="action"):
        q(mean)


def test_manoeuvre_q_is_fitted_saved_and_loaded_into_any_filter(tmp_path, rollouts):
    """Its gains get gradients from both objectives; a file fixes whether a loaded filter
    uses them; the env's transform and ``run_filter`` agree step by step."""
    from dockingrl.transforms.params import save_filter_params

    ekf = make_filter(DockingConfig(), manoeuvre_noise=True)
    fit = FilterFit(objective="nll", window=40, epochs=1, lr=0.05)
    with torch.no_grad():
        before = run_filter(ekf, rollouts[:40], objective="nll")[3].item()
    gains = ekf.process_noise.log_manoeuvre_gain.detach().clone()
    for _ in range(4):
        fit_filter(ekf, fit, data=rollouts[:40].clone())
    with torch.no_grad():
        after = run_filter(ekf, rollouts[:40], objective="nll")[3].item()
    assert after < before
    assert not torch.equal(gains, ekf.process_noise.log_manoeuvre_gain)
    save_filter_params(ekf, tmp_path / "m.pt")
    plain = make_filter(DockingConfig()).load_filter_params(tmp_path / "m.pt")
    assert plain.process_noise.manoeuvre
    mean, action = torch.randn(3, 5), torch.randn(3, 2)
    torch.testing.assert_close(plain.process_noise(mean, action), ekf.process_noise(mean, action))
    save_filter_params(make_filter(DockingConfig()), tmp_path / "c.pt")
    assert not plain.load_filter_params(tmp_path / "c.pt").process_noise.manoeuvre

    from torchrl.envs import TransformedEnv

    from dockingrl.env import DockingEnv

    env = TransformedEnv(DockingEnv(4, seed=3), plain.load_filter_params(tmp_path / "m.pt"))
    steps = env.rollout(30, break_when_any_done=False).transpose(0, 1)  # (30, 4)
    td = steps.select("observation", "action", "ocean_current").clone()
    td["step_count"] = steps["step_count"].squeeze(-1)
    means = run_filter(env.transform, td, dt=0.2)[0]
    torch.testing.assert_close(means[1:], steps["next", "ekf_mean"][:-1], atol=1e-4, rtol=1e-4)


def test_context_noise_starts_as_the_constant_filter_and_keeps_q_and_r_positive():
    from dockingrl.transforms import NoiseContext

    gen = torch.Generator().manual_seed(2)
    plain = make_filter(DockingConfig())
    ekf = make_filter(DockingConfig(), context_noise=True)
    mean, action = torch.randn(16, 5, generator=gen), torch.randn(16, 2, generator=gen)
    z = torch.rand(16, 6, generator=gen) * 30
    age = torch.randint(0, 700, (16,), generator=gen)
    Q0, R0 = plain.noise_covariances(mean, action, z, age)
    Q1, R1 = ekf.noise_covariances(mean, action, z, age)
    torch.testing.assert_close(Q1, Q0.expand(16, 5, 5))
    torch.testing.assert_close(R1, R0)
    for _ in range(200):  # any weights, any context: Q symmetric positive-definite, R > 0
        with torch.no_grad():
            ekf.noise_context.q_weight.copy_(torch.randn(7, 5, generator=gen) * 4)
            ekf.noise_context.r_weight.copy_(torch.randn(7, 6, generator=gen) * 4)
        Q, R = ekf.noise_covariances(
            torch.randn(8, 5, generator=gen) * 3,
            torch.randn(8, 2, generator=gen),
            torch.rand(8, 6, generator=gen) * 40,
            torch.randint(0, 900, (8,), generator=gen),
        )
        Q = Q.double()
        assert torch.equal(Q, Q.transpose(-1, -2))
        assert torch.linalg.eigvalsh(Q).min() > 0
        assert (R > 0).all() and torch.isfinite(R).all()
    assert NoiseContext.features(mean, action, z[:, 0], age).shape == (16, 7)


def test_context_noise_is_fitted_saved_loaded_and_agrees_with_the_env_transform(tmp_path, rollouts):
    """Both weight matrices get gradients; a file fixes whether a loaded filter uses a context
    model; the env's transform (its ``ekf_age`` state) and ``run_filter`` agree step by step."""
    from torchrl.envs import TransformedEnv

    from dockingrl.env import DockingEnv
    from dockingrl.transforms.params import save_filter_params

    ekf = make_filter(DockingConfig(), context_noise=True)
    fit = FilterFit(objective="supervised", window=40, epochs=1, lr=0.05)
    with torch.no_grad():
        before = run_filter(ekf, rollouts[:40], objective="supervised")[3].item()
    for _ in range(4):
        fit_filter(ekf, fit, data=rollouts[:40].clone())
    with torch.no_grad():
        after = run_filter(ekf, rollouts[:40], objective="supervised")[3].item()
    assert after < before
    assert ekf.noise_context.q_weight.abs().sum() > 0
    assert ekf.noise_context.r_weight.abs().sum() > 0
    save_filter_params(ekf, tmp_path / "ctx.pt")
    loaded = make_filter(DockingConfig()).load_filter_params(tmp_path / "ctx.pt")
    assert loaded.context_noise
    torch.testing.assert_close(loaded.noise_context.q_weight, ekf.noise_context.q_weight)
    save_filter_params(make_filter(DockingConfig()), tmp_path / "plain.pt")
    assert (
        not make_filter(DockingConfig(), context_noise=True)
        .load_filter_params(tmp_path / "plain.pt")
        .context_noise
    )

    env = TransformedEnv(DockingEnv(4, seed=5), loaded)
    steps = env.rollout(30, break_when_any_done=False).transpose(0, 1)  # (30, 4)
    assert torch.equal(
        steps["next", "ekf_age"].squeeze(-1), steps["next", "step_count"].squeeze(-1).float()
    )
    td = steps.select("observation", "action", "ocean_current").clone()
    td["step_count"] = steps["step_count"].squeeze(-1)
    means, covs = run_filter(env.transform, td, dt=0.2)[:2]
    torch.testing.assert_close(means[1:], steps["next", "ekf_mean"][:-1], atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(covs[1:], steps["next", "ekf_cov"][:-1], atol=1e-6, rtol=1e-4)


def test_filter_ablation_cli_adds_context_rows_started_from_the_constant_fit(tmp_path):
    args = ["filter-ablation", "--num-envs", "6", "--steps", "60", "--window", "20"]
    args += ["--epochs", "1", "--context-epochs", "1", "--threads", "1", "--context-noise"]
    args += ["--range-noise-from", "estimate", "--learn-r", "usbl"]
    assert cli_main([*args, "--out", str(tmp_path)]) == 0
    table = (tmp_path / "table.md").read_text()
    assert table.count("| learned, supervised, context Q and R |") == 2  # both conditions
    assert table.count("| hand-tuned, R from the estimated range |") == 2
    assert "range and bearing; heading, DVL and IMU keep Table 2's" in table
    assert "its 95 % CI over the runs" in table
    ctx = make_filter(DockingConfig()).load_filter_params(
        tmp_path / "mismatched_supervised_context.pt"
    )
    constant = make_filter(DockingConfig()).load_filter_params(
        tmp_path / "mismatched_supervised.pt"
    )
    assert ctx.context_noise and not constant.context_noise
    assert ctx.range_noise_from == constant.range_noise_from == "estimate"
    table2 = make_filter(DockingConfig()).measurement_noise.log_std
    torch.testing.assert_close(ctx.measurement_noise.log_std[2:], table2[2:], rtol=0, atol=0)
    # one more pass from the constant fit: close to it, not equal
    gap = (ctx.measurement_noise.log_std - constant.measurement_noise.log_std)[:2].abs().max()
    assert 0 < gap < 0.2
    report = json.loads((tmp_path / "ablation.json").read_text())
    assert "learned, nll, context Q and R" in report["conditions"]["nominal"]["filters"]


def test_nis_is_the_normalised_innovation_of_each_prediction(rollouts):
    from dockingrl.transforms.ekf import (
        ekf_predict,
        innovation,
        innovation_covariance,
        measurement_jacobian,
    )

    ekf = make_filter(DockingConfig())
    nis: list[torch.Tensor] = []
    with torch.no_grad():
        means, covs, _, _ = run_filter(ekf, rollouts[:6], nis=nis)
    assert len(nis) == 5 and nis[0].shape == (16,)
    data, t = rollouts, 3  # by hand: predict from the estimate after step t - 1, then y, S
    applied = ekf._applied_action(data["action"][t - 1])
    Q, R = ekf.noise_covariances(means[t - 1], applied, data["observation"][t], None)
    prior, prior_cov = ekf_predict(
        means[t - 1], covs[t - 1], applied, data["ocean_current"][t], Q, 0.2
    )
    H = measurement_jacobian(prior, data["ocean_current"][t])
    S = innovation_covariance(prior_cov, H, torch.diag_embed(R)).double()
    y = innovation(prior, data["observation"][t], data["ocean_current"][t]).double()
    expected = y.unsqueeze(-1).transpose(-1, -2) @ torch.linalg.inv(S) @ y.unsqueeze(-1)
    torch.testing.assert_close(nis[t - 1].double(), expected[..., 0, 0], rtol=1e-4, atol=1e-4)
    # the report's NIS statistics over every step after the first 10 of an episode
    from scipy.stats import chi2

    report = evaluate_filter(ekf, rollouts)
    every: list[torch.Tensor] = []
    with torch.no_grad():
        run_filter(ekf, rollouts, nis=every)
    values = torch.stack(every).double().numpy()  # (T - 1, N): steps 1 ... T - 1
    keep = (rollouts["step_count"][1:] >= 10).numpy()
    kept = values[keep]
    assert report["nis_mean"] == pytest.approx(kept.mean(), rel=1e-9)
    per_env = np.array([values[keep[:, n], n].mean() for n in range(keep.shape[1])])
    half = 1.96 * per_env.std(ddof=1) / np.sqrt(len(per_env))
    assert report["nis_mean_ci95_over_runs"] == pytest.approx(
        [per_env.mean() - half, per_env.mean() + half], rel=1e-9
    )
    assert report["nis_step_bounds_95"] == pytest.approx(chi2.ppf([0.025, 0.975], 6), rel=0.05)
    low, high = report["nis_step_bounds_95"]
    inside = ((kept >= low) & (kept <= high)).mean()
    assert report["nis_fraction_in_step_bounds"] == pytest.approx(inside, abs=1e-12)


def test_innovation_whiteness_tells_white_from_correlated_innovations():
    from dockingrl.filter_learning import innovation_whiteness

    gen = torch.Generator().manual_seed(2)
    T, N, m = 50, 256, 6
    white = torch.randn(T, N, m, generator=gen, dtype=torch.float64)
    valid = torch.ones(T, N, dtype=torch.bool)
    valid[0] = False  # no innovation at an episode's first step
    valid[20, :128] = False  # a new episode starts here in half the envs
    correlated = white.clone()
    for t in range(1, T):
        correlated[t] = 0.6 * correlated[t - 1] + 0.8 * white[t]
    noise_floor = 5 * m * m / (T * N)  # expected sum of squares of 5 lags' sample means
    assert innovation_whiteness(white, valid, 5) < 2 * noise_floor
    # lag-k correlation 0.6^k on the diagonal: sum_k m 0.36^k ~ 3.4
    assert innovation_whiteness(correlated, valid, 5) > 3.0
    # pairs across an episode start (steps 19 and 21 around the new episode's step 20) do
    # not count
    spliced = white.clone()
    spliced[19, :128] = 5.0
    spliced[21, :128] = 5.0
    across = innovation_whiteness(spliced, torch.ones_like(valid), 2)
    assert innovation_whiteness(spliced, valid, 2) < 2 * noise_floor < across


def test_whiteness_is_an_option_of_the_nll_objective_only():
    ekf = make_filter(DockingConfig())
    data = record_rollouts(8, 40, seed=0)
    with pytest.raises(ValueError, match="nll objective only"):
        fit_filter(ekf, FilterFit(objective="supervised", whiteness=1.0, window=10), data=data)
    with pytest.raises(ValueError, match="lags"):
        fit_filter(ekf, FilterFit(whiteness=1.0, window=10, lags=10), data=data)
    history = fit_filter(
        ekf, FilterFit(whiteness=10.0, window=10, lags=3, epochs=3, lr=0.05), data=data
    )
    assert history[-1] < history[0]


def test_range_sigma_from_the_estimate_does_not_depend_on_the_reading():
    mean = torch.tensor([[-12.0, 5.0, 0.3, 0.5, 0.0]]).expand(3, 5)
    action, age = torch.zeros(3, 2), torch.zeros(3)
    z = torch.zeros(3, 6)
    z[:, 0] = torch.tensor([10.0, 13.0, 16.0])  # three range readings of the same estimate
    _, measured = make_filter(DockingConfig()).noise_covariances(mean, action, z, age)
    torch.testing.assert_close(measured[:, 0], (0.025 * z[:, 0]) ** 2, rtol=1e-5, atol=0)
    ekf = make_filter(DockingConfig(), range_noise_from="estimate")
    _, estimated = ekf.noise_covariances(mean, action, z, age)
    torch.testing.assert_close(estimated[:, 0], torch.full((3,), (0.025 * 13.0) ** 2))
    torch.testing.assert_close(estimated[:, 1:], measured[:, 1:])
    with pytest.raises(ValueError, match="range_noise_from"):
        EKFTransform(range_noise_from="truth")


def test_range_sigma_from_the_measurement_biases_the_range_short_and_the_estimate_does_not():
    # range noise x4 (10 % of the range): the measured-range R weighs short readings more, a
    # bias of about -2 sigma_rel^2 = -2 % of the range; the estimate's range removes it
    config = mismatched_config(4.0)
    data = record_rollouts(16, 120, config=config, seed=0)
    truth = data["true_state"][..., :2].norm(dim=-1)
    keep = data["step_count"] >= 10
    bias = {}
    for mode in ("measurement", "estimate"):
        with torch.no_grad():
            means = run_filter(make_filter(config, range_noise_from=mode), data)[0]
        bias[mode] = float(((means[..., :2].norm(dim=-1) - truth) / truth)[keep].mean())
    assert bias["measurement"] < -0.01
    assert abs(bias["estimate"]) < 0.008


@pytest.mark.parametrize("context", [False, True])
def test_learn_r_usbl_fits_range_and_bearing_and_keeps_the_other_sigmas(context, rollouts):
    ekf = make_filter(DockingConfig(), context_noise=context, range_noise_from="estimate")
    before = ekf.measurement_noise.log_std.detach().clone()
    fit = FilterFit(window=20, epochs=2, lr=0.05, learn_r="usbl")
    fit_filter(ekf, fit, data=rollouts[:60].clone())
    after = ekf.measurement_noise.log_std.detach()
    assert torch.equal(after[2:], before[2:])
    assert (after[:2] != before[:2]).all()
    if context:
        weights = ekf.noise_context.r_weight.detach()
        assert (weights[:, 2:] == 0).all() and (weights[:, :2] != 0).any()
    with pytest.raises(ValueError, match="learn_r"):
        fit_filter(ekf, FilterFit(window=20, learn_r="dvl"), data=rollouts[:60].clone())


def test_range_noise_from_round_trips_and_older_files_read_as_measured(tmp_path):
    path = tmp_path / "params.pt"
    make_filter(DockingConfig(), range_noise_from="estimate").save_filter_params(path)
    assert make_filter(DockingConfig()).load_filter_params(path).range_noise_from == "estimate"
    payload = torch.load(path, weights_only=True)
    payload["format"] = "dockingrl.filter_params/3"
    del payload["range_noise_from"]
    torch.save(payload, path)
    upgrade_file(path)
    ekf = make_filter(DockingConfig(), range_noise_from="estimate").load_filter_params(path)
    assert ekf.range_noise_from == "measurement"
