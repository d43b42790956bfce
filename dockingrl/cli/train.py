"""``dockingrl train`` and ``dockingrl recipes``: the command-line front of
:func:`dockingrl.training.train` and :mod:`dockingrl.recipes`."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

from dockingrl.agents.config import (
    CONFIG_FIELDS,
    CONFIGS,
    PRESETS,
    TrainConfig,
    add_config_arguments,
    config_from_args,
    overrides_from_args,
)
from dockingrl.cli.arguments import UsageError
from dockingrl.provenance import command_line


def add_training_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--recipe",
        metavar="NAME|PATH",
        help="a named recipe (paper-sac, paper-td3, paper-ppo: Tables 3-5 as published; sac, "
        "td3, ppo: dockingrl's recommended ones; see dockingrl recipes) or a recipe YAML file; "
        "options on the command line override its fields",
    )
    parser.add_argument(
        "--algo",
        choices=list(CONFIGS),
        help="algorithm (required unless --recipe or --resume; with --recipe, must match it)",
    )
    parser.add_argument(
        "--preset",
        choices=list(PRESETS),
        default=None,
        help="without --recipe: 'paper' (default): Tables 3-5 as published; 'fast': vectorised "
        "collection sized for a 2-core CPU",
    )
    parser.add_argument(
        "--resume",
        default=None,
        metavar="RUN_DIR",
        help="continue the run in RUN_DIR from its latest checkpoint to the same "
        "total (its config.json is used; only --threads, --device, --total-steps, "
        "--keep-candidates and --select-episodes may change: a larger --total-steps "
        "continues a finished run)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_config_arguments(parser)


def _from_command_line(make: Callable[[], Any]) -> Any:
    """``make()``, its refusal of a value or an option of the command line raised as a
    :class:`~dockingrl.cli.arguments.UsageError`."""
    try:
        return make()
    except ValueError as exc:
        raise UsageError(str(exc)) from exc


def config_from_recipe(args: argparse.Namespace) -> TrainConfig:
    """The config of ``args.recipe`` with the fields given on the command line on top."""
    from dockingrl.recipes import load_recipe

    if args.preset is not None:
        raise UsageError("--preset and --recipe exclude each other")
    recipe = load_recipe(args.recipe, check=False)  # its config is validated once, below
    if args.algo is not None and args.algo != recipe.algo:
        raise UsageError(f"--algo {args.algo} but recipe {recipe.name!r} is {recipe.algo}")
    args.algo = recipe.algo
    overrides = _from_command_line(lambda: overrides_from_args(args))
    try:
        return recipe.make_config(**overrides)
    except ValueError as exc:
        own: ValueError | None = exc  # the recipe's own fields at fault, not the options?
        if overrides:
            try:
                recipe.make_config()
                own = None
            except ValueError as recipe_error:
                own = recipe_error
        if own is not None:
            raise ValueError(f"recipe {args.recipe}: {own}") from None
        raise UsageError(str(exc)) from exc


def cmd_train(args: argparse.Namespace) -> int:
    from dockingrl.training import TrainingInterrupted, train

    if args.resume:
        for flag, value in (("--recipe", args.recipe), ("--preset", args.preset)):
            if value is not None:
                raise UsageError(f"{flag} does not apply to --resume: the run keeps its config")
        cfg, given = (
            None,
            {
                name: value
                for name, value in vars(args).items()
                if value is not None and name in CONFIG_FIELDS
            },
        )
        if args.algo is not None:
            given["algo"] = args.algo
    elif args.recipe:
        cfg, given = config_from_recipe(args), None
    else:
        if args.algo is None:
            raise UsageError("--algo or --recipe is required (unless --resume RUN_DIR)")
        cfg, given = _from_command_line(lambda: config_from_args(args)), None
    start_steps = getattr(cfg, "start_steps", 0)  # off-policy only; no cfg with --resume
    if start_steps and start_steps >= cfg.total_steps:
        raise UsageError(
            f"--start-steps {start_steps} >= --total-steps {cfg.total_steps}: the run would act "
            "at random throughout and never learn; give fewer --start-steps"
        )
    try:
        result = train(
            cfg,
            resume=args.resume,
            progress=not args.no_progress,
            command=command_line(),
            overrides=given,
        )
    except TrainingInterrupted as exc:  # SIGTERM / SIGINT: checkpointed, resumable
        print(exc, file=sys.stderr)
        return 128 + exc.signum
    s, e = result["summary"], result["eval"]
    print(
        f"{s['algo']} {s['scenario']}: {s['frames']} env steps ({s['num_envs']} envs), "
        f"{s['updates']} updates, {s['train_wall_clock_s']:.0f} s; final {e['episodes']}-episode "
        f"success {e['success_rate']:.1f} %, reward {e['total_reward']['mean']:.1f} "
        f"+- {e['total_reward']['std']:.1f}; run folder {result['run_dir']}"
    )
    return 0


def cmd_recipes(args: argparse.Namespace) -> int:
    from dockingrl.recipes import load_recipe, recipe_names

    if args.name:
        recipe = load_recipe(args.name)
        print(f"{recipe.name} ({recipe.algo}): {recipe.description}")
        if recipe.first_stage:
            print(f"first stage: a run of recipe {recipe.first_stage} (--init-from RUN_DIR)")
        for key, value in recipe.make_config().to_dict().items():
            mark = "*" if key in recipe.config else " "
            print(f" {mark} {key} = {value}")
        print("(* set by the recipe; the others are the paper's defaults)")
        return 0
    names = recipe_names()
    width = max(map(len, names), default=0)
    for name in names:
        recipe = load_recipe(name)
        print(f"{name:<{width}}  {recipe.algo:<3}  {recipe.description}")
    return 0


def add_training_commands(sub) -> None:
    """Register ``dockingrl train`` and ``dockingrl recipes`` on the CLI's subparsers ``sub``."""
    tr = sub.add_parser(
        "train",
        help="train SAC, TD3 or PPO on a scenario",
        description="Train an agent; every config field is an option (default: the preset).",
    )
    add_training_arguments(tr)
    tr.set_defaults(func=cmd_train)

    rc = sub.add_parser("recipes", help="list the named recipes, or show one")
    rc.add_argument("name", nargs="?", help="a recipe name or YAML file to show whole")
    rc.set_defaults(func=cmd_recipes)
