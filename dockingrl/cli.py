"""The ``dockingrl`` command line: ``dockingrl eval``, ``dockingrl filter-figure`` (and the
training commands, see ``dockingrl --help``)."""

from __future__ import annotations

import argparse
import shlex
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import torch

from dockingrl.arguments import (
    COUNT,
    FINITE,
    NON_NEGATIVE,
    NON_NEGATIVE_INT,
    POSITIVE,
    Parser,
    UsageError,
    torch_device,
)
from dockingrl.env import DockingConfig
from dockingrl.scenarios import SCENARIOS

#: Figure 10's currents (caption) with a start on each side of the axis: the first of each pair
#: is pushed towards the axis by the lateral current, the second has to work against it.
FIGURE_10_CASES = [
    {"start": (-28.0, 6.0, 0.0), "ocean_current": (0.05, -0.1)},
    {"start": (-28.0, -6.0, 0.0), "ocean_current": (0.05, -0.1)},
    {"start": (-28.0, 6.0, 0.0), "ocean_current": (-0.15, -0.3)},
    {"start": (-28.0, -6.0, 0.0), "ocean_current": (-0.15, -0.3)},
    {"start": (-28.0, 6.0, 0.0), "ocean_current": (0.3, -0.3)},
    {"start": (-28.0, -6.0, 0.0), "ocean_current": (0.3, -0.3)},
]


_ARGV: list[str] = []
DEBUG_HELP = "on an error, show its traceback instead of one line"


def command_line() -> str:
    """The command being run, as a user would type it."""
    return shlex.join(["dockingrl", *_ARGV])


def footer_text(extra: str = "", device: str | None = None) -> str:
    from dockingrl.evaluation import describe_machine

    text = f"{command_line()}  |  {describe_machine(device)}"
    return f"{text}  |  {extra}" if extra else text


def load_policy(spec: str, *, use_filter: bool = False, device: str = "cpu"):
    """``managed_surge`` or the path of a policy saved by training. Returns
    ``(policy, name, scenario or None, make_env options the policy was trained with, its
    ``info`` from :func:`dockingrl.agents.saving.load_policy`, empty for the controller)``."""
    if spec == "managed_surge":
        from dockingrl.agents.managed_surge import ManagedSurgePolicy

        return ManagedSurgePolicy(use_filter=use_filter), "managed_surge", None, {}, {}
    if not Path(spec).exists():
        raise FileNotFoundError(f"--policy {spec!r} is neither 'managed_surge' nor a file")
    from dockingrl.agents.saving import load_policy as load_saved
    from dockingrl.agents.saving import pipeline_options

    policy, meta = load_saved(spec, device=device)
    options = pipeline_options(meta["config"])
    return policy, meta.get("algo", "agent"), meta.get("scenario"), options, meta


def evaluation_world(args: argparse.Namespace, scenario: str, info: dict) -> tuple[dict, str]:
    """The env options of ``dockingrl eval`` beyond the policy's pipeline: the USBL noise
    scales and the learned filter the policy was trained with (``info`` of the saved policy),
    unless the command line sets them; and a line saying what was taken from the policy."""
    from dockingrl.agents.saving import training_filter
    from dockingrl.scenarios import FILTERED_OBSERVATION_KEYS

    trained = info.get("config", {})
    taken = []
    scales = []
    for name in ("range_noise_scale", "bearing_noise_scale"):
        value = getattr(args, name)
        if value is None:
            value = float(trained.get(name, 1.0))
            if value != 1.0:
                taken.append(f"{name} {value:g}")
        scales.append(value)
    config = DockingConfig(contact_speed_tolerance=args.speed_tolerance).scale_usbl_noise(*scales)
    kwargs: dict = {"config": config}
    params = args.filter_params
    if params is None and scenario in FILTERED_OBSERVATION_KEYS and info:
        params = training_filter(info)
        if params is not None:
            taken.append(f"filter_params {trained.get('filter_params')}")
    if params == "none":
        params = None
    elif isinstance(params, str) and not Path(params).is_file():
        raise FileNotFoundError(f"--filter-params {params!r}: no such file")
    if params is not None:
        kwargs["filter_params"] = params
    line = f"as the policy was trained: {', '.join(taken)}" if taken else ""
    return kwargs, line


def cmd_eval(args: argparse.Namespace) -> int:
    from dockingrl.evaluation import evaluate, success_map, table_row, trajectories
    from dockingrl.io import write_json
    from dockingrl.plots import plot_success_map, plot_trajectories

    torch.set_num_threads(args.threads)
    policy, name, trained_scenario, options, trained = load_policy(
        args.policy, use_filter=args.use_filter, device=args.device
    )
    scenario = args.scenario or trained_scenario or "noise"
    if trained:
        from dockingrl.onboard import check_env_layout

        check_env_layout(trained, scenario, options)
    if args.mirrored:
        if not trained:
            raise UsageError("--mirrored needs a saved agent (--policy PATH)")
        from dockingrl.agents.algorithms import MirroredPolicy
        from dockingrl.scenarios import mirror_signs

        flags = {k: bool(options.get(k)) for k in ("observe_current", "observe_command")}
        policy, name = MirroredPolicy(policy, mirror_signs(scenario, **flags)), f"{name} mirrored"
    world, taken = evaluation_world(args, scenario, trained)
    if taken:
        print(taken)
    env_kwargs = {"device": args.device, **options, **world}
    out = Path(args.out) if args.out else None
    if out is not None and out.exists() and not out.is_dir():
        raise NotADirectoryError(f"--out {out}: a file, not a folder")
    if args.video:
        from dockingrl.render import VIDEO_SUFFIXES

        if Path(args.video).suffix.lower() not in VIDEO_SUFFIXES:
            raise UsageError(f"--video {args.video}: the suffix must be one of .gif, .mp4")
    start = time.perf_counter()
    metrics = evaluate(
        policy,
        scenario,
        args.episodes,
        seed=args.seed,
        progress=not args.quiet,
        stochastic=args.stochastic,
        **env_kwargs,
    )
    metrics.update(policy=args.policy, command=command_line())
    print(table_row(name, scenario, metrics))
    speed, success_time = metrics["contact_speed"], metrics["time_success_s"]
    line = f"failures: {metrics['failures']}"
    if speed["n"]:
        line += f"; contact speed {speed['mean']:.3f} +- {speed['std']:.3f} m/s"
    if success_time["n"]:
        line += f"; time over successes {success_time['mean']:.1f} +- {success_time['std']:.1f} s"
    print(line)
    thirds = ", ".join(
        f"{t['oc_x']} {t['success_rate']:.1f} %" for t in metrics["by_current_x"] if t["episodes"]
    )
    print(
        f"success by oc_x: {thirds}; timeouts ending beyond the station: "
        f"{metrics['timeouts_beyond_station']}"
    )
    if out is not None:
        write_json(out / "eval.json", metrics)
    if args.map:
        result = success_map(
            policy,
            scenario,
            trials=args.map_trials,
            seed=args.seed,
            progress=not args.quiet,
            **env_kwargs,
        )
        result.update(policy=args.policy, command=command_line())
        print(f"success map: mean {result['mean_success_rate']:.1f} %")
        if out is not None:
            write_json(out / "success_map.json", result)
            plot_success_map(
                result,
                out / "success_map.png",
                title=f"{name}, {scenario}: success (%) per current",
                footer=footer_text(device=args.device),
            )
    if args.trajectories:
        cases = trajectories(policy, FIGURE_10_CASES, scenario, seed=args.seed, **env_kwargs)
        if out is not None:
            write_json(out / "trajectories.json", {"command": command_line(), "cases": cases})
            plot_trajectories(
                cases, out / "trajectories.png", footer=footer_text(device=args.device)
            )
    if args.video:
        from dockingrl.render import write_video

        video = write_video(
            policy, scenario, args.video, episodes=args.video_episodes, seed=args.seed, **env_kwargs
        )
        print(f"video: {video}")
    wall = time.perf_counter() - start
    print(f"wall-clock {wall:.1f} s" + (f"; results in {out}/" if out else ""))
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from dockingrl.onboard import OnboardPolicy, export_onboard

    policy = OnboardPolicy.from_file(args.policy, filter_params=args.filter_params)
    path = export_onboard(policy, args.out, batch=args.batch)
    print(
        f"wrote {path}: torch.export.load(path).module()(z, current, mean, cov, command, age) "
        f"-> (command, mean, cov, age), {args.batch} vehicle(s), scenario {policy.scenario}; "
        "age -1 starts an approach"
    )
    return 0


def cmd_filter_figure(args: argparse.Namespace) -> int:
    """One episode of the managed surge controller (on the EKF estimate) in the compound
    scenario: raw, filtered and true rho, psi, alpha (Figure 5)."""
    from dockingrl.agents.managed_surge import ManagedSurgePolicy
    from dockingrl.env import observation_from_state
    from dockingrl.evaluation import base_env
    from dockingrl.io import write_json
    from dockingrl.plots import plot_filter_episode
    from dockingrl.scenarios import make_env

    env = make_env("compound", 1, seed=args.seed)
    base_env(env).set_initial_state(
        pose=torch.tensor(args.start), ocean_current=torch.tensor(args.current)
    )
    policy = ManagedSurgePolicy(use_filter=True)
    with torch.no_grad():
        td = env.rollout(600, policy)
    nxt = td["next"][0]
    x, y, alpha, u, v, r = nxt["true_state"].unbind(-1)
    true = observation_from_state(x, y, alpha, u, v, r, nxt["ocean_current"]).numpy()
    raw = nxt["observation"][:, :6].numpy()
    filtered = nxt["filtered_observation"].numpy()
    seconds = nxt["step_count"].squeeze(-1).numpy() * base_env(env).config.dt

    def rmse(a):
        e = a - true
        e[:, 1:3] = (e[:, 1:3] + np.pi) % (2 * np.pi) - np.pi
        return np.sqrt((e**2).mean(0))[:3].tolist()

    out = Path(args.out)
    plot_filter_episode(
        seconds, raw, filtered, true, out / "filter_episode.png", footer=footer_text()
    )
    write_json(
        out / "filter_episode.json",
        {
            "command": command_line(),
            "start": args.start,
            "ocean_current": args.current,
            "steps": len(seconds),
            "rmse_raw": dict(zip(["rho", "psi", "alpha"], rmse(raw), strict=True)),
            "rmse_filtered": dict(zip(["rho", "psi", "alpha"], rmse(filtered), strict=True)),
        },
    )
    print(f"wrote {out}/filter_episode.png ({len(seconds)} steps)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="dockingrl",
        description="AUV docking with deep RL: evaluation and training. An error is one line "
        "on stderr and exit status 1 (2: a bad command line, 130: interrupted).",
    )
    parser.add_argument("--debug", action="store_true", help=DEBUG_HELP)
    sub = parser.add_subparsers(dest="command", required=True)

    ev = sub.add_parser(
        "eval",
        help="evaluate the managed surge controller or a saved agent (Tables 6-7, Figs. 9-10)",
        description="Evaluate a policy on N episodes run as one batch; prints a Table 6/7 row "
        "beside the paper's and writes eval.json (+ success_map, trajectories) to --out.",
    )
    ev.add_argument(
        "--policy",
        default="managed_surge",
        help="'managed_surge' or the path of a saved agent (policy.pt)",
    )
    ev.add_argument(
        "--scenario",
        choices=list(SCENARIOS),
        default=None,
        help="default: the agent's training scenario, or 'noise' for the controller",
    )
    ev.add_argument("--episodes", type=COUNT, default=500, help="number of episodes (paper: 500)")
    ev.add_argument("--seed", type=NON_NEGATIVE_INT, default=0, help="evaluation seed")
    ev.add_argument("--out", default=None, help="results folder (JSON + PNG)")
    ev.add_argument("--map", action="store_true", help="also the 9x9 success map (Figure 9)")
    ev.add_argument("--map-trials", type=COUNT, default=10, help="episodes per map cell")
    ev.add_argument("--trajectories", action="store_true", help="also Figure-10 trajectories")
    ev.add_argument(
        "--video",
        metavar="PATH",
        default=None,
        help="also a GIF (.gif) or MP4 (.mp4) of --video-episodes episodes, drawn as Figure 10",
    )
    ev.add_argument(
        "--video-episodes", type=COUNT, default=3, help="episodes in the --video (default 3)"
    )
    ev.add_argument(
        "--use-filter",
        action="store_true",
        help="managed surge reads the EKF estimate (filtered/compound scenarios)",
    )
    ev.add_argument(
        "--speed-tolerance",
        type=NON_NEGATIVE,
        default=0.0,
        help="m/s added to the 0.3 m/s contact-speed limit of the success test",
    )
    ev.add_argument(
        "--filter-params",
        default=None,
        help="learned Q/R file for the EKF; default: the agent's training file (if any), "
        "'none': Table 1's filter",
    )
    for sensor in ("range", "bearing"):
        ev.add_argument(
            f"--{sensor}-noise-scale",
            type=POSITIVE,
            default=None,
            help=f"env's USBL {sensor} noise x this; default: the agent's training value (1)",
        )
    ev.add_argument(
        "--stochastic",
        action="store_true",
        help="sample the agent's actions as in training instead of taking their mode "
        "(the 500-episode evaluation only; map and trajectories stay deterministic)",
    )
    ev.add_argument(
        "--mirrored",
        action="store_true",
        help="evaluate the agent mirrored through the docking axis (y -> -y): a policy that "
        "treats both sides alike scores the same (dockingrl.agents.algorithms.MirroredPolicy)",
    )
    ev.add_argument("--threads", type=COUNT, default=2, help="torch CPU threads")
    ev.add_argument(
        "--device", type=torch_device, default="cpu", help="torch device of the envs and the policy"
    )
    ev.add_argument("--quiet", action="store_true", help="no progress bar")
    ev.set_defaults(func=cmd_eval)

    ff = sub.add_parser("filter-figure", help="raw vs filtered vs true observation (Figure 5)")
    ff.add_argument("--out", default="results/filter", help="results folder")
    ff.add_argument("--seed", type=NON_NEGATIVE_INT, default=0)
    ff.add_argument(
        "--start", type=FINITE, nargs=3, default=[-28.0, 5.0, 0.3], metavar=("X", "Y", "ALPHA")
    )
    ff.add_argument(
        "--current", type=FINITE, nargs=2, default=[0.1, -0.1], metavar=("OC_X", "OC_Y")
    )
    ff.set_defaults(func=cmd_filter_figure)

    ex = sub.add_parser(
        "export",
        help="write a trained policy with its filter as a torch.export program for a vehicle",
    )
    ex.add_argument("--policy", required=True, help="policy.pt written by training")
    ex.add_argument("--out", required=True, help="the program's file (.pt2)")
    ex.add_argument("--batch", type=COUNT, default=1, help="vehicles per call")
    ex.add_argument("--filter-params", default=None, help="learned Q/R file for the EKF")
    ex.set_defaults(func=cmd_export)

    from dockingrl.filter_cli import add_filter_commands
    from dockingrl.grid_cli import add_grid_commands
    from dockingrl.stress import add_stress_command
    from dockingrl.train_cli import add_training_commands
    from dockingrl.upgrade_cli import add_upgrade_command

    add_training_commands(sub)
    add_grid_commands(sub)
    add_filter_commands(sub)
    add_stress_command(sub)
    add_upgrade_command(sub)
    for command in sub.choices.values():  # --debug also after the command's name
        command.add_argument(
            "--debug", action="store_true", default=argparse.SUPPRESS, help=DEBUG_HELP
        )
    return parser


class CommandFailed(SystemExit):
    """How a failed ``dockingrl`` command ends, after printing its one line on stderr:
    ``code`` is the exit status, ``str()`` the line."""

    def __init__(self, line: str, code: int) -> None:
        super().__init__(code)
        self.line = line

    def __str__(self) -> str:
        return self.line


def _raised_by_dockingrl(exc: BaseException) -> bool:
    """Whether the innermost frame of ``exc``'s traceback is dockingrl's own code."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    package = Path(__file__).resolve().parent
    return tb is not None and package in Path(tb.tb_frame.f_code.co_filename).resolve().parents


def error_line(exc: BaseException, command: str | None) -> tuple[str, int]:
    """The one line (after ``dockingrl: error: ``) and the exit status that report ``exc``:
    2 for a bad command line, 130 for an interrupt, 1 otherwise. Errors of bad input (values,
    files, the checks of dockingrl's own code) say their message; anything else is a bug and
    says so."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, UsageError):
        return f"{text} (see {exc.prog or f'dockingrl {command}'} --help)", 2
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted", 130
    if isinstance(exc, (ValueError, OSError)) or (
        isinstance(exc, RuntimeError) and _raised_by_dockingrl(exc)
    ):
        return text, 1
    if len(text) > 300:
        text = text[:297] + "..."
    gist = f"{type(exc).__name__}: {text}" if text != type(exc).__name__ else text
    return f"{gist} (unexpected: run with --debug for the traceback)", 1


def main(argv: list[str] | None = None) -> int:
    """Run ``dockingrl`` with ``argv`` (default: the process's arguments) and return its exit
    status. An error prints one line on stderr (with ``--debug``: its traceback) and raises
    :class:`CommandFailed`, a ``SystemExit`` with the status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    _ARGV[:] = argv
    debug, command = "--debug" in argv, None
    try:
        args, extra = build_parser().parse_known_args(argv)
        debug, command = args.debug, args.command
        if extra:
            raise UsageError(f"unrecognized arguments: {' '.join(extra)}")
        return args.func(args)
    except BaseException as exc:
        if isinstance(exc, SystemExit) and not isinstance(exc.code, str):
            raise
        if debug:
            traceback.print_exc()
        line, code = error_line(exc, command)
        print(f"dockingrl: error: {line}", file=sys.stderr)
        raise CommandFailed(f"dockingrl: error: {line}", code) from None


if __name__ == "__main__":
    raise SystemExit(main())
