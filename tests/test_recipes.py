"""Named recipes: the shipped YAML files, their loading and refusals, and a smoke run of
``dockingrl train --recipe NAME`` for every one of them."""

import json

import pytest
from helpers import recipe_config_json

from dockingrl.agents.config import make_config
from dockingrl.cli import main
from dockingrl.recipes import load_recipe, recipe_names

SIX = ["paper-sac", "paper-td3", "paper-ppo", "sac", "td3", "ppo"]
#: every shipped recipe: one per algorithm and purpose
SHIPPED = [*SIX, "sac-robust", "ppo-robust"]

#: a run of seconds, whatever the recipe: 4 envs, small networks, a few episodes
TINY = [
    "--num-envs",
    "4",
    "--hidden",
    "32",
    "32",
    "--eval-every",
    "1000",
    "--eval-episodes",
    "2",
    "--final-eval-episodes",
    "4",
    "--select-episodes",
    "4",
    "--logger",
    "none",
    "--checkpoint-every",
    "0",
    "--threads",
    "1",
    "--no-progress",
    "--no-compile",
]
TINY_ALGO = {
    "sac": [
        "--total-steps",
        "1600",
        "--start-steps",
        "400",
        "--batch-size",
        "32",
        "--frames-per-batch",
        "200",
        "--no-compile-update",
    ],
    "ppo": ["--total-steps", "1600", "--steps-per-env", "32", "--minibatch-size", "64"],
}
TINY_ALGO["td3"] = TINY_ALGO["sac"]


def test_the_recipes_are_shipped_one_per_purpose_written_in_full():
    assert sorted(recipe_names()) == sorted(SHIPPED)
    from importlib import resources

    import yaml

    for name in SHIPPED:
        text = resources.files("dockingrl.recipes").joinpath(f"{name}.yaml").read_text()
        data = yaml.safe_load(text)
        assert "base" not in data and "first_stage" not in data, name  # no chain of files
        assert text.startswith("# "), name  # a comment that gives its purpose


@pytest.mark.parametrize("algo", ["sac", "td3", "ppo"])
def test_paper_recipes_are_tables_3_to_5(algo):
    recipe = load_recipe(f"paper-{algo}")
    assert recipe.algo == algo and recipe.config == {}
    cfg = recipe.make_config()
    paper = make_config(algo, "paper")
    assert {**cfg.to_dict(), "recipe": ""} == paper.to_dict()
    assert cfg.recipe == f"paper-{algo}"


def test_recommended_recipes_share_the_environment_choices():
    """The TD3 recipe takes the SAC recipe's environment, observation, replay and training
    reward; the robust recipe the SAC recipe's, trained over both vehicles."""
    sac, td3, robust = (load_recipe(n).config for n in ("sac", "td3", "sac-robust"))
    shared = [
        "action_repeat",
        "observe_command",
        "mirror_augment",
        "critic_layer_norm",
        "contact_speed_penalty",
        "contact_speed_penalty_cap",
        "success_bonus",
        "miss_penalty_floor",
        "following_current_fraction",
        "num_envs",
        "updates_per_step",
        "normalize_observation",
    ]
    assert {k: sac[k] for k in shared} == {k: td3[k] for k in shared}
    assert {k: sac[k] for k in shared} == {k: robust[k] for k in shared}
    cfg = load_recipe("sac-robust").make_config()
    assert (cfg.train_curriculum, cfg.train_level, cfg.scenario) == ("L0", "M5F", "filtered")
    assert load_recipe("ppo").make_config().threads == 2  # the main job uses both cores


def test_a_recipe_file_and_overrides(tmp_path):
    path = tmp_path / "mine.yaml"
    path.write_text("algo: td3\nconfig:\n  hidden: [64, 64]\n  lr: 0.001\n")
    recipe = load_recipe(path)
    cfg = recipe.make_config(lr=0.002, scenario="noise")
    assert (cfg.algo, cfg.recipe, cfg.hidden, cfg.lr, cfg.scenario) == (
        "td3",
        "mine",
        (64, 64),
        0.002,
        "noise",
    )


@pytest.mark.parametrize(
    "text, message",
    [
        ("algo: dqn\n", "algo must be one of"),
        ("algo: sac\nconfig:\n  no_such_field: 1\n", "no_such_field"),
        ("algo: sac\nconfig:\n  num_envs: many\n", "num_envs"),
        ("algo: sac\nconfig:\n  keep_best: 1\n", "keep_best"),
        ("algo: sac\nconfig:\n  gamma: 2.0\n", "gamma"),
        ("algo: sac\nrecipe_of: x\n", "unknown key"),
        ("[1, 2]\n", "expected a mapping"),
        ("base: sac\nalgo: ppo\n", "differs from its base's"),
        ("base: no-such-recipe\n", "its base: unknown recipe 'no-such-recipe'"),
        ("algo: sac\nconfig: [\n", "not valid YAML"),
        (
            "algo: sac\nfirst_stage: no-such-recipe\n",
            "its first_stage: unknown recipe 'no-such-recipe'",
        ),
        ("algo: sac\nfirst_stage: ppo\n", "first_stage 'ppo' is a ppo recipe, not sac"),
    ],
)
def test_bad_recipe_files_are_one_line_errors(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        load_recipe(path)
    assert "\n" not in str(info.value)


def test_a_recipe_file_starts_from_its_base(tmp_path, monkeypatch):
    mine = tmp_path / "mine.yaml"
    mine.write_text("base: sac-robust\nconfig:\n  lr: 0.001\n")
    cfg = load_recipe(mine).make_config()
    assert (cfg.lr, cfg.train_level, cfg.action_repeat, cfg.recipe) == (0.001, "M5F", 4, "mine")
    (tmp_path / "sub").mkdir()  # a base file is read beside the recipe, wherever it runs
    (tmp_path / "sub" / "second.yaml").write_text("base: ../mine.yaml\nconfig:\n  gamma: 0.9\n")
    monkeypatch.chdir("/")
    cfg = load_recipe(tmp_path / "sub" / "second.yaml").make_config()
    assert (cfg.lr, cfg.gamma, cfg.train_level) == (0.001, 0.9, "M5F")
    loop = tmp_path / "loop.yaml"
    loop.write_text(f"base: {loop}\n")
    with pytest.raises(ValueError, match="nest deeper than 8"):
        load_recipe(loop)


def test_an_unknown_recipe_name_lists_the_shipped_ones():
    with pytest.raises(ValueError, match="paper-sac"):
        load_recipe("no-such-recipe")


@pytest.mark.parametrize("name", SHIPPED)
def test_train_with_every_recipe(name, tmp_path, capsys, short_episodes):
    algo = load_recipe(name).algo
    argv = [
        "train",
        "--recipe",
        name,
        "--scenario",
        "filtered" if name.endswith("-robust") else "noise",
        "--seed",
        "1",
        "--out",
        str(tmp_path),
        "--run-name",
        "r",
        *TINY,
        *TINY_ALGO[algo],
    ]
    assert main(argv) == 0
    config = json.loads((tmp_path / "r" / "config.json").read_text())
    recipe = load_recipe(name)
    # the recipe's fields, except those the command line set, are in the run's config
    given = {a.lstrip("-").removeprefix("no-").replace("-", "_") for a in argv if a[:2] == "--"}
    for key, value in recipe.config.items():
        if key not in given:
            assert config[key] == value, key
    assert (config["recipe"], config["algo"], config["seed"]) == (name, algo, 1)
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["frames"] >= 1600 and set(summary["code"]) == {"commit", "dirty"}
    assert "success" in capsys.readouterr().out


def test_train_refuses_a_recipe_of_another_algorithm_and_a_preset(tmp_path):
    with pytest.raises(SystemExit, match="recipe 'sac' is sac"):
        main(["train", "--recipe", "sac", "--algo", "ppo", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="exclude each other"):
        main(["train", "--recipe", "sac", "--preset", "fast", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="does not apply to sac"):
        main(["train", "--recipe", "sac", "--epochs", "3", "--out", str(tmp_path)])


def test_recipes_command_lists_and_shows(capsys):
    assert main(["recipes"]) == 0
    listing = capsys.readouterr().out
    assert all(name in listing for name in SIX)
    # one column each for the names, the algorithms and the descriptions, however long a name
    rows = listing.splitlines()
    assert len({row.index(load_recipe(row.split()[0]).description) for row in rows}) == 1
    assert main(["recipes", "td3"]) == 0
    shown = capsys.readouterr().out
    assert "* updates_per_step = 0.5" in shown and "  policy_delay = 2" in shown
    assert len(rows) <= 10


def test_a_fine_tune_file_names_its_first_stage_and_inherits_it(tmp_path):
    assert all(load_recipe(name).first_stage == "" for name in SHIPPED)
    (tmp_path / "stage.yaml").write_text("base: sac\nconfig:\n  lr: 0.001\n")
    (tmp_path / "ft.yaml").write_text("base: sac\nfirst_stage: stage.yaml\n")
    (tmp_path / "ft2.yaml").write_text("base: ft.yaml\nconfig:\n  total_steps: 1000\n")
    assert load_recipe(tmp_path / "ft2.yaml").first_stage == str(tmp_path / "stage.yaml")


@pytest.mark.parametrize("name", recipe_names())
def test_a_shipped_fine_tune_takes_the_runs_of_its_first_stage(name):
    """A recipe that loads a replay buffer names the recipe it starts from (a fine-tune may
    name one without loading a buffer), and the first stage's networks are the fine-tune's
    (else ``--init-from`` would refuse every run of it)."""
    from dockingrl.training.checkpointing import network_differences

    recipe = load_recipe(name)
    if recipe.config.get("init_replay"):
        assert recipe.first_stage
    if not recipe.first_stage:
        return
    assert recipe.first_stage in recipe_names()
    stage = recipe_config_json(recipe.first_stage)  # as a run of it writes its config.json
    assert network_differences(stage, recipe.make_config()) == []
