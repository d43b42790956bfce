"""The ``sac-ln`` and ``sac-ln-robust-ft`` recipes: what each changes from the recipe it
extends, and that the second stage takes the first stage's run where ``sac-robust-ft`` refuses
it."""

import pytest
from test_recipes import TINY, TINY_ALGO

from dockingrl.cli import main
from dockingrl.recipes import load_recipe


def changed_fields(name: str, base: str) -> dict:
    new, old = load_recipe(name).make_config().to_dict(), load_recipe(base).make_config().to_dict()
    return {k: v for k, v in new.items() if old[k] != v and k != "recipe"}


@pytest.mark.parametrize(
    ("name", "base"), [("sac-ln", "sac"), ("sac-ln-robust-ft", "sac-robust-ft")]
)
def test_each_is_its_base_with_layer_normed_critics_on_one_thread(name, base):
    assert changed_fields(name, base) == {"critic_layer_norm": True, "threads": 1}
    assert load_recipe(name).make_config().recipe == name


def test_the_second_stage_fine_tunes_the_first_at_l5(tmp_path, short_episodes):
    tiny = [*TINY, *TINY_ALGO["sac"], "--scenario", "filtered", "--out", str(tmp_path)]
    tiny[tiny.index("--checkpoint-every") + 1] = "800"
    assert main(["train", "--recipe", "sac-ln", "--run-name", "nominal", *tiny]) == 0
    nominal = str(tmp_path / "nominal")
    with pytest.raises(SystemExit, match="its networks are not this run's"):
        main(
            ["train", "--recipe", "sac-robust-ft", "--init-from", nominal, "--run-name", "x", *tiny]
        )
    argv = ["train", "--recipe", "sac-ln-robust-ft", "--init-from", nominal, "--run-name", "ft"]
    assert main([*argv, *tiny]) == 0
    assert (tmp_path / "ft" / "policy.pt").is_file()
