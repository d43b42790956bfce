"""The held-out protocol: seed roles, the labels figures carry, the refusal of tuning seeds in
a reported table, and evaluation seeds that never meet the ones choices were made on."""

import pytest

from dockingrl.evaluation.protocol import (
    FINAL_EVAL_OFFSET,
    HELD_OUT_FROM,
    TUNING_SEEDS,
    level_eval_seed,
    require_held_out,
    seed_role,
    seeds_label,
)


def test_seed_roles():
    assert [seed_role(s) for s in (0, 9, 10, 99, 100, 104)] == [
        "tuning",
        "tuning",
        "unassigned",
        "unassigned",
        "held-out",
        "held-out",
    ]


def test_labels_name_the_seeds_and_their_role():
    assert seeds_label([100, 101, 102, 103, 104]) == "held-out seeds 100-104"
    assert seeds_label([102, 100, 104, 100]) == "held-out seeds 100, 102, 104"
    assert seeds_label([0]) == "tuning seed 0"
    assert seeds_label([0, 1, 100]) == "seeds 0-1, 100 (held-out and tuning)"
    assert seeds_label([]) == "no seeds"


def test_a_reported_figure_refuses_tuning_seeds_in_one_line():
    require_held_out([100, 104], "table")
    with pytest.raises(ValueError, match=r"^table: training seed\(s\) 0-2, 50 are not held out"):
        require_held_out([100, 0, 1, 2, 50], "table")


def test_evaluation_seeds_of_held_out_runs_meet_no_tuning_evaluation():
    """A held-out run's final and level evaluations never draw the episodes of a tuning
    run's evaluations of either kind."""
    tuning = {s + FINAL_EVAL_OFFSET for s in TUNING_SEEDS} | {
        level_eval_seed(s) for s in TUNING_SEEDS
    }
    held_out = range(HELD_OUT_FROM, HELD_OUT_FROM + 1000)
    reported = {s + FINAL_EVAL_OFFSET for s in held_out} | {level_eval_seed(s) for s in held_out}
    assert not tuning & reported
