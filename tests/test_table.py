"""``dockingrl table``: cells over seeds, intervals, success at 200 k steps, the claims, the
figures and the pruning of policies, from fake finished runs."""

import json
import re

import pytest
from helpers import fake_run
from scipy.stats import trim_mean as scipy_trim_mean

from dockingrl.cli import main
from dockingrl.table import EARLY_STEPS, write_table


def test_the_table_of_three_seeds(tmp_path):
    runs = [
        fake_run(tmp_path, "sac", "sac", "compound", s, v, early=e)
        for s, v, e in ((0, 90.0, 40.0), (1, 94.0, 50.0), (2, 98.0, 60.0))
    ] + [
        fake_run(tmp_path, "sac", "sac", "noise", s, v)
        for s, v in ((0, 60.0), (1, 70.0), (2, 65.0))
    ]
    runs.append(tmp_path / "unfinished")
    runs[-1].mkdir()
    table = write_table(runs, tmp_path / "out", prune_policies=True)
    cells = {(c["recipe"], c["scenario"]): c for c in table["cells"]}
    c = cells[("sac", "compound")]
    assert c["success_mean"] == pytest.approx(94.0) and c["seeds"] == [0, 1, 2]
    # Student's t over the three seeds (mean 94, sd 4), clipped at 100 %: wider than their
    # range, which a percentile bootstrap of three values would give
    t975 = 4.302652729911275  # the 97.5 % quantile of t with 2 degrees of freedom
    assert c["success_ci95_over_seeds"] == pytest.approx([94.0 - t975 * 4 / 3**0.5, 100.0])
    # Wilson's score interval for 1,410 successes in 1,500 episodes, written out
    k, n, z = 1410, 1500, 1.959963984540054
    centre = (k + z * z / 2) / (n + z * z)
    half = z * (k * (n - k) / n + z * z / 4) ** 0.5 / (n + z * z)
    expected = [100 * (centre - half), 100 * (centre + half)]
    assert c["success_ci95_over_episodes"] == pytest.approx(expected, rel=1e-9)
    assert c["paper"]["success"] == 99.4
    # the first periodic evaluation at or after 200 k steps
    assert c["success_at_200k"] == {
        "mean": 50.0,
        "per_seed": [40.0, 50.0, 60.0],
        "steps": [210_000] * 3,
    }
    assert EARLY_STEPS == 200_000
    # time pooled over docked episodes of the three seeds: 470 + 490 + 510 episodes
    assert c["time_docked_s"]["n"] == 1470
    assert c["time_docked_s"]["mean"] == pytest.approx((470 * 40 + 490 * 41 + 510 * 42) / 1470)
    assert c["time_success_s"]["n"] == 1410
    claim = next(x for x in table["claims"] if x["claim"] == "compound >= noise")
    assert claim["difference_points"] == pytest.approx(29.0)
    # every compound seed above every noise seed: rliable's probability of improvement is 1,
    # in every stratified bootstrap resample
    assert claim["verdict"].startswith("holds")
    assert claim["probability_of_improvement"] == {"probability": 1.0, "ci95": [1.0, 1.0]}
    # the IQM of three seeds (trimming 25 % of three values trims none) and of the recipe
    assert c["success_iqm"]["iqm"] == pytest.approx(94.0)
    assert c["success_iqm"]["ci95"][0] <= 94.0 <= c["success_iqm"]["ci95"][1]
    (aggregate,) = table["aggregates"]
    assert aggregate["recipe"] == "sac" and aggregate["scenarios"] == ["compound", "noise"]
    assert aggregate["iqm"] == pytest.approx(scipy_trim_mean([90, 94, 98, 60, 70, 65], 0.25))
    out = tmp_path / "out"
    assert (out / "figures_sac.png").stat().st_size > 10_000
    md = (out / "table.md").read_text()
    assert "| sac | compound | tuning seeds 0-2 | 94.0 (90.0, 94.0, 98.0) |" in md
    # only the best seed of each cell keeps its policy
    kept = sorted(p.parent.name for p in tmp_path.glob("*/policy.pt"))
    assert kept == ["sac__compound__s2", "sac__noise__s1"]


def test_an_overlapping_difference_is_not_a_finding(tmp_path):
    runs = [fake_run(tmp_path, "td3", "td3", "compound", s, v) for s, v in enumerate((80, 95, 88))]
    runs += [fake_run(tmp_path, "td3", "td3", "filtered", s, v) for s, v in enumerate((85, 90, 86))]
    table = write_table(runs, tmp_path / "out")
    claim = next(x for x in table["claims"] if x["claim"] == "compound >= filtered")
    assert claim["verdict"].startswith("not resolved")


def test_table_command_without_finished_runs_is_one_line(tmp_path):
    with pytest.raises(SystemExit, match="no finished run"):
        main(["table", str(tmp_path), "--out", str(tmp_path / "out")])


def test_the_managed_surge_claim_and_the_papers_margin(tmp_path):
    runs = [fake_run(tmp_path, "sac", "sac", "compound", s, 90.0 + s) for s in (0, 1)]
    runs += [fake_run(tmp_path, "sac", "sac", "noise", s, 60.0 + s) for s in (0, 1)]
    surge = tmp_path / "surge.json"
    surge.write_text(json.dumps({"time_success_s": {"n": 120, "mean": 59.2, "std": 5.0}}))
    table = write_table(runs, tmp_path / "out", baseline=surge)
    margin = next(x for x in table["claims"] if x["claim"] == "compound >= noise")
    # Table 6: SAC compound 99.4 %, noise 73.4 %
    assert margin["paper_difference_points"] == pytest.approx(26.0)
    faster = {x["claim"]: x for x in table["claims"] if "difference_s" in x}
    compound = faster["docks faster than the managed surge controller (compound)"]
    # the fake runs dock successfully in 42 s (seed 0) and 43 s (seed 1); their faster
    # contacts that fail do not count
    assert compound["time_s"] == pytest.approx((450 * 42 + 455 * 43) / 905)
    assert compound["episodes"] == 905 and compound["baseline_episodes"] == 120
    assert compound["difference_s"] == pytest.approx(compound["time_s"] - 59.2)
    assert compound["difference_s"] < -16 and compound["p_value"] < 1e-6
    assert compound["verdict"] == "holds: faster"
    slow = tmp_path / "slow.json"
    slow.write_text(json.dumps({"time_success_s": {"n": 120, "mean": 30.0, "std": 5.0}}))
    table = write_table(runs, tmp_path / "out2", baseline=slow)
    verdicts = {x["verdict"] for x in table["claims"] if "difference_s" in x}
    assert verdicts == {"fails: slower"}
    assert "Welch p" in (tmp_path / "out2" / "table.md").read_text()


def test_a_baseline_without_times_is_one_line(tmp_path):
    run = fake_run(tmp_path, "sac", "sac", "compound", 0, 90.0)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"success_rate": 25.4}))
    with pytest.raises(SystemExit, match="baseline .*bad.json: not an evaluation's eval.json"):
        main(["table", str(run), "--out", str(tmp_path / "out"), "--baseline", str(bad)])


@pytest.mark.parametrize(
    "file, field, value, says",
    [
        ("config", "scenario", "calm", "scenario must be one of no_noise"),
        ("config", "seed", "1", "seed must be an integer >= 0 (got '1')"),
        ("summary", "frames", "3e6", "frames must be an integer >= 0"),
        ("eval", "success_rate", float("nan"), "success_rate must be a number in [0, 100]"),
        ("eval", "success_rate", 150.0, "success_rate must be a number in [0, 100]"),
        ("eval", "episodes", 0, "episodes must be an integer >= 1"),
        ("eval", "time_s", "x", "time_s must be {n, mean, std}"),
    ],
)
def test_a_run_file_field_the_table_cannot_use_is_one_line_naming_it(
    tmp_path, file, field, value, says
):
    run = fake_run(tmp_path, "sac", "sac", "compound", 0, 90.0)
    path = run / f"{file}.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), field: value}))
    with pytest.raises(SystemExit, match=f"{file}.json: " + re.escape(says)):
        main(["table", str(run), "--out", str(tmp_path / "out")])


@pytest.mark.parametrize(
    "time",
    [
        {"n": 5, "mean": float("nan"), "std": 1.0},
        {"n": 5.0, "mean": 30.0, "std": 1.0},
        {"n": 5, "mean": 30.0, "std": -1.0},
        [5, 30.0, 1.0],
    ],
)
def test_a_baseline_of_no_finite_time_is_refused_as_a_run_field_is(tmp_path, time):
    run = fake_run(tmp_path, "sac", "sac", "compound", 0, 90.0)
    bad = tmp_path / "nan.json"
    bad.write_text(json.dumps({"time_success_s": time}))
    with pytest.raises(SystemExit, match="baseline .*nan.json: time_success_s must be .*finite"):
        main(["table", str(run), "--out", str(tmp_path / "out"), "--baseline", str(bad)])


def test_success_per_third_of_the_current_pooled_over_seeds(tmp_path):
    split = {
        0: [(100, 100.0, 0), (100, 90.0, 2), (300, 50.0, 140)],
        1: [(200, 99.0, 1), (100, 80.0, 5), (200, 25.0, 150)],
    }
    runs = [
        fake_run(tmp_path, "sac", "sac", "compound", s, 80.0, by_current=split[s]) for s in (0, 1)
    ]
    table = write_table(runs, tmp_path / "out")
    parts = table["cells"][0]["success_by_current_x"]
    assert [p["oc_x"] for p in parts] == ["opposing", "weak", "following"]
    # pooled over episodes: following = (150 + 50) / 500, not the mean of 50 and 25
    assert [p["episodes"] for p in parts] == [300, 200, 500]
    assert [p["success_rate"] for p in parts] == pytest.approx([298 / 3, 85.0, 40.0])
    assert parts[2]["per_seed"] == [50.0, 25.0] and parts[2]["timeouts"] == 290
    md = (tmp_path / "out" / "table.md").read_text()
    assert "| sac | compound | 99.3 (100.0, 99.0) / 1 | 85.0 (90.0, 80.0) / 7 | " in md
    assert "40.0 (50.0, 25.0) / 290 |" in md


def test_runs_without_the_current_split_leave_it_out(tmp_path):
    runs = [fake_run(tmp_path, "sac", "sac", "noise", 0, 70.0)]
    runs.append(fake_run(tmp_path, "sac", "sac", "noise", 1, 75.0, by_current=[(1, 1.0, 0)] * 3))
    table = write_table(runs, tmp_path / "out")
    assert table["cells"][0]["success_by_current_x"] is None
    assert "per third of the along-axis current" not in (tmp_path / "out" / "table.md").read_text()


def test_runs_that_split_the_current_differently_are_refused(tmp_path):
    runs = [
        fake_run(tmp_path, "sac", "sac", "noise", s, 70.0, by_current=[(1, 1.0, 0)] * 3)
        for s in (0, 1)
    ]
    data = json.loads((runs[1] / "eval.json").read_text())
    data["by_current_x"][0]["oc_x"] = "against"
    (runs[1] / "eval.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="split the current differently"):
        write_table(runs, tmp_path / "out")


def test_cells_that_split_the_current_differently_are_refused(tmp_path):
    runs = [
        fake_run(tmp_path, "sac", "sac", scenario, 0, 70.0, by_current=[(1, 1.0, 0)] * 3)
        for scenario in ("noise", "compound")
    ]
    data = json.loads((runs[1] / "eval.json").read_text())
    data["by_current_x"][2]["range"] = [0.1, 0.5]
    (runs[1] / "eval.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="split the current differently"):
        write_table(runs, tmp_path / "out")
    assert not (tmp_path / "out").exists()  # nothing written


def test_a_difference_within_three_seeds_spread_is_not_a_finding(tmp_path):
    # compound 3 points above on average, but its seeds spread over 10: a seed of compound
    # beats one of noise 6 times in 9, and the bootstrap interval of that holds 1/2
    runs = [fake_run(tmp_path, "ppo", "ppo", "compound", s, v) for s, v in enumerate((85, 80, 90))]
    runs += [fake_run(tmp_path, "ppo", "ppo", "noise", s, v) for s, v in enumerate((83, 81, 82))]
    table = write_table(runs, tmp_path / "out")
    claim = next(x for x in table["claims"] if x["claim"] == "compound >= noise")
    improvement = claim["probability_of_improvement"]
    assert claim["verdict"].startswith("not resolved")
    assert improvement["probability"] == pytest.approx(6 / 9)
    assert improvement["ci95"][0] < 0.5 < improvement["ci95"][1]


def test_seeds_that_agree_give_no_interval(tmp_path):
    runs = [fake_run(tmp_path, "td3", "td3", "compound", s, 90.0) for s in (0, 1)]
    runs += [fake_run(tmp_path, "td3", "td3", "noise", s, 70.0) for s in (0, 1)]
    table = write_table(runs, tmp_path / "out")
    assert table["cells"][0]["success_ci95_over_seeds"] is None
    claim = next(x for x in table["claims"] if x["claim"] == "compound >= noise")
    assert claim["probability_of_improvement"] is None
    assert claim["verdict"] == "too few seeds to tell"


def test_per_seed_values_follow_the_seeds_whatever_the_order_given(tmp_path):
    runs = [fake_run(tmp_path, "sac", "sac", "noise", s, v) for s, v in ((10, 70.0), (2, 60.0))]
    runs.append(fake_run(tmp_path, "sac", "sac", "noise", 1, 50.0))
    c = write_table(runs, tmp_path / "out")["cells"][0]  # given as seeds 10, 2, 1
    assert c["seeds"] == [1, 2, 10] and c["success_per_seed"] == [50.0, 60.0, 70.0]


def test_a_seed_given_twice_or_budgets_that_differ_are_refused(tmp_path):
    a = fake_run(tmp_path, "sac", "sac", "noise", 0, 60.0)
    b = fake_run(tmp_path, "sac", "sac", "noise", 0, 61.0, name="copy_of_s0")
    with pytest.raises(SystemExit, match="cell sac noise: seed 0 given twice"):
        main(["table", str(a), str(b), "--out", str(tmp_path / "out")])
    c = fake_run(tmp_path, "sac", "sac", "noise", 1, 61.0, config={"total_steps": 1_000_000})
    with pytest.raises(SystemExit, match="different total_steps"):
        main(["table", str(a), str(c), "--out", str(tmp_path / "out")])
    # a `--algo sac` run (no recipe) and a `--recipe sac` one share the key sac: not seeds
    d = fake_run(tmp_path, "sac", "sac", "noise", 2, 70.0, config={"action_repeat": 4})
    e = fake_run(
        tmp_path,
        "sac",
        "sac",
        "noise",
        3,
        71.0,
        config={"threads": 2, "out": "x", "init_from": "first/s3"},
    )
    with pytest.raises(SystemExit, match=r"cell sac noise: its runs differ in action_repeat "):
        main(["table", str(a), str(d), "--out", str(tmp_path / "out")])
    main(["table", str(a), str(e), "--out", str(tmp_path / "out")])  # one config


def test_a_third_of_the_current_without_episodes_in_a_run(tmp_path):
    splits = {
        0: [(250, 80.0, 0), (250, 40.0, 3), (0, None, 0)],  # no following current in seed 0
        1: [(200, 80.0, 0), (200, 40.0, 3), (100, 60.0, 1)],
    }
    runs = [
        fake_run(tmp_path, "sac", "sac", "noise", seed, 60.0, by_current=split)
        for seed, split in splits.items()
    ]
    table = write_table(runs, tmp_path / "out")
    following = table["cells"][0]["success_by_current_x"][2]
    assert following["episodes"] == 100 and following["success_rate"] == pytest.approx(60.0)
    assert following["per_seed"] == [None, 60.0]
    assert "60.0 (-, 60.0) / 1" in (tmp_path / "out" / "table.md").read_text()


def test_the_claims_on_success_at_200k_steps(tmp_path):
    runs = [
        fake_run(tmp_path, "sac", "sac", "compound", s, 90.0, early=e)
        for s, e in enumerate((60.0, 62.0, 64.0))
    ]
    runs += [
        fake_run(tmp_path, "sac", "sac", "noise", s, 60.0, early=e)
        for s, e in enumerate((30.0, 35.0, 40.0))
    ]
    runs += [
        fake_run(tmp_path, "ppo", "ppo", "compound", s, 80.0, early=e)
        for s, e in enumerate((20.0, 40.0, 63.0))
    ]
    claims = {c["claim"]: c for c in write_table(runs, tmp_path / "out")["claims"]}
    fastest = claims["compound learns fastest (sac: success at 200 k env steps)"]
    assert fastest["compared"] == ["compound", "noise"]
    assert fastest["difference_points"] == pytest.approx(27.0)
    assert fastest["verdict"] == "holds: compound ahead"
    assert fastest["probability_of_improvement"]["ci95"][0] > 0.5
    # ppo's seeds spread over 43 points: SAC's 20-point lead is not a finding
    efficient = claims["SAC most sample-efficient (success at 200 k env steps, compound)"]
    assert efficient["compared"] == ["sac", "ppo"] and efficient["recipe"] == "sac"
    assert efficient["verdict"].startswith("not resolved")
    assert efficient["probability_of_improvement"]["ci95"][0] < 0.5
    md = (tmp_path / "out" / "table.md").read_text()
    assert "| sac | compound - noise +27.0 points (compound 62.0 %, noise 35.0 %) |" in md


def test_periodic_success_per_fifth_of_the_budget(tmp_path):
    """Each seed's periodic evaluations averaged per fifth of its 500 k env steps (the fake
    runs evaluate at 100, 190, 210 and 500 k: fifths 1, 2, 3 and 5), then over the seeds; a
    fifth without an evaluation has no value, and a seed counts as still rising when its last
    fifth is above every earlier one (not when it only ties them)."""
    runs = [
        fake_run(tmp_path, "td3", "td3", "noise", 0, 80.0, early=60.0),
        fake_run(tmp_path, "td3", "td3", "noise", 1, 40.0, early=70.0),
        fake_run(tmp_path, "td3", "td3", "filtered", 0, 30.0, early=30.0),
    ]
    table = write_table(runs, tmp_path / "out")
    cells = {c["scenario"]: c["periodic_success_by_fifth"] for c in table["cells"]}
    assert cells["filtered"]["seeds_still_rising"] == 0  # 10, 30, 30, -, 30
    fifths = cells["noise"]
    assert fifths["per_seed"] == [[10.0, 30.0, 60.0, None, 80.0], [10.0, 30.0, 70.0, None, 40.0]]
    assert fifths["mean"] == [10.0, 30.0, 65.0, None, 60.0]
    assert fifths["seeds_still_rising"] == 1
    md = (tmp_path / "out" / "table.md").read_text()
    assert "| td3 | noise | 10.0 | 30.0 | 65.0 | - | 60.0 | 1 of 2 |" in md


def test_the_faster_claim_is_welchs_test_of_the_episodes():
    import numpy as np
    from scipy.stats import ttest_ind

    from dockingrl.table.claims import faster_than_baseline

    rng = np.random.default_rng(0)
    agent, controller = rng.normal(50, 9, 8), rng.normal(60, 12, 5)

    def stats(v):  # as an evaluation writes them: the std over its episodes, ddof=0
        return {"n": v.size, "mean": float(v.mean()), "std": float(v.std())}

    cells = {("sac", "compound"): {"time_success_s": stats(agent)}}
    [claim] = faster_than_baseline(cells, {"time_success_s": stats(controller)})
    expected = ttest_ind(agent, controller, equal_var=False).pvalue
    assert claim["p_value"] == pytest.approx(expected, rel=1e-9)


def test_cells_name_their_seeds_and_held_out_refuses_tuning_seeds(tmp_path):
    held = [fake_run(tmp_path, "sac", "sac", "compound", s, 99.0) for s in (100, 101, 102)]
    table = write_table(held, tmp_path / "out", held_out=True)
    assert table["cells"][0]["seeds_label"] == "held-out seeds 100-102"
    assert "| sac | compound | held-out seeds 100-102 |" in (tmp_path / "out/table.md").read_text()
    tuning = fake_run(tmp_path, "sac", "sac", "noise", 0, 60.0)
    with pytest.raises(ValueError, match=r"training seed\(s\) 0 are not held out"):
        write_table([*held, tuning], tmp_path / "out2", held_out=True)
    with pytest.raises(SystemExit, match="are not held out"):
        main(["table", *map(str, held), str(tuning), "--out", str(tmp_path / "o3"), "--held-out"])


def test_a_recipe_without_periodic_evaluations_is_drawn_from_its_training_episodes(tmp_path):
    """``ppo`` logs no periodic evaluation: its figure draws the training episodes' success and
    reward and says so, rather than three empty axes; a recipe with them draws them."""
    from dockingrl.table import _read, figure_curves

    run = fake_run(tmp_path, "ppo", "ppo", "compound", 100, 92.0)
    (run / "curves.csv").write_text(
        "step,key,value\n"
        + "".join(f"{s},train/success_rate,{s / 1e4}\n" for s in (100_000, 200_000))
        + "".join(f"{s},train/episode_reward,{-s / 1e3}\n" for s in (100_000, 200_000))
    )
    keys, what = figure_curves([_read(run)])
    assert [k for k, _ in keys] == ["train/success_rate", "train/episode_reward"]
    assert what.startswith("training episodes (no periodic evaluation")
    assert _read(run)["curves"]["train/success_rate"] == [(100_000, 10.0), (200_000, 20.0)]
    sac = fake_run(tmp_path, "sac", "sac", "compound", 100, 99.0)
    keys, what = figure_curves([_read(sac)])
    assert keys[0][0] == "eval/success_rate" and what == "periodic evaluations"
    write_table([run], tmp_path / "out")
    assert (tmp_path / "out" / "figures_ppo.png").stat().st_size > 10_000


def test_a_figure_footer_names_a_grid_s_trials_by_their_folder(tmp_path):
    """The footer of ``dockingrl table results/table6/trials/* ...`` gives the glob, not every
    trial (61 of them overran the figure); a part of a folder is counted, a few stay named."""
    from dockingrl.provenance import shorten_folders

    trials = [tmp_path / "trials" / f"t{k}" for k in range(5)]
    for t in trials:
        t.mkdir(parents=True)
    command = "dockingrl table " + " ".join(map(str, trials)) + " --out 'a b'"
    assert shorten_folders(command, trials) == f"dockingrl table {tmp_path}/trials/* --out 'a b'"
    part = "dockingrl table " + " ".join(map(str, trials[:4])) + " --held-out"
    shown = shorten_folders(part, trials[:4])
    assert shown == f"dockingrl table {tmp_path}/trials/<4 folders> --held-out"
    few = "dockingrl table " + " ".join(map(str, trials[:2]))
    assert shorten_folders(few, trials[:2]) == few


def test_the_bootstrap_intervals_repeat_and_leave_numpy_s_generator_alone():
    """rliable draws its resamples from NumPy's global generator, not from the random state it
    is given: the table seeds that generator for each interval, so a table made twice is the
    same table, and gives the caller's generator back as it was."""
    import numpy as np

    from dockingrl.table.reliable import compare, iqm, scores_matrix

    scores = scores_matrix([[90.0, 70.0, 95.0, 60.0, 99.0], [80.0, 85.0, 50.0, 97.0, 91.0]])
    np.random.seed(1)
    first = (iqm(scores), compare([90, 70, 95, 60, 99], [80, 85, 50, 97, 91]))
    after = np.random.random()
    np.random.seed(2)
    assert (iqm(scores), compare([90, 70, 95, 60, 99], [80, 85, 50, 97, 91])) == first
    np.random.seed(1)  # the caller's draw after the intervals is its first draw after seed 1
    assert np.random.random() == after
