"""``dockingrl eval`` and ``dockingrl export``: the command-line front of
:mod:`dockingrl.evaluation` and :mod:`dockingrl.onboard`."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from dockingrl.cli.arguments import (
    COUNT,
    EPISODES,
    NON_NEGATIVE,
    SEED,
    UsageError,
    filter_params_file,
    policy_from_args,
    results_folder,
    torch_device,
)
from dockingrl.env.realism_options import VEHICLES
from dockingrl.provenance import command_line, footer_text

#: episodes drawn in a ``--video`` unless ``--video-episodes`` says otherwise
VIDEO_EPISODES = 3


def cmd_eval(args: argparse.Namespace) -> int:
    """``dockingrl eval``: a policy's evaluation, success map, trajectories and video."""
    from dockingrl.evaluation import evaluate, success_map, table_row, trajectories
    from dockingrl.io import write_json
    from dockingrl.plots import plot_success_map, plot_trajectories
    from dockingrl.policies import FIGURE_10_CASES, evaluation_world
    from dockingrl.scenarios import layout_options, mirror_signs

    policy, name, scenario, options, trained = policy_from_args(args)
    if trained:
        from dockingrl.agents.layout import check_env_layout

        check_env_layout(trained, scenario, options)
    if args.mirrored:
        if not trained:
            raise UsageError("--mirrored needs a saved agent (--policy PATH)")
        from dockingrl.agents import MirroredPolicy

        signs = mirror_signs(scenario, **layout_options(options))
        policy, name = MirroredPolicy(policy, signs), f"{name} mirrored"
    world, taken = evaluation_world(
        scenario,
        trained,
        range_noise_scale=args.range_noise_scale,
        bearing_noise_scale=args.bearing_noise_scale,
        speed_tolerance=args.speed_tolerance,
        filter_params=args.filter_params,
        vehicle=args.vehicle,
    )
    if taken:
        print(taken)
    env_kwargs = {"device": args.device, **options, **world}
    out = Path(args.out) if args.out else None
    if args.map_trials is not None and not args.map:
        raise UsageError("--map-trials applies to a --map only")
    if args.stochastic and not trained:
        raise UsageError("--stochastic samples a saved agent's actions; give --policy PATH")
    if args.video_episodes is not None and not args.video:
        raise UsageError("--video-episodes applies to a --video only")
    if args.video:
        from dockingrl.render import VIDEO_SUFFIXES

        if Path(args.video).suffix.lower() not in VIDEO_SUFFIXES:
            raise UsageError(f"--video {args.video}: the suffix must be one of .gif, .mp4")
        if Path(args.video).is_dir():
            raise UsageError(f"--video {args.video}: a folder; give a file's path")
        _refuse_file_under_a_file("--video", Path(args.video))
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
    lateral = ", ".join(
        f"{t['abs_oc_y']} {t['success_rate']:.1f} %"
        for t in metrics["by_current_y"]
        if t["episodes"]
    )
    print(
        f"success by oc_x: {thirds}; by |oc_y|: {lateral}; timeouts ending beyond the "
        f"station: {metrics['timeouts_beyond_station']}"
    )
    if out is not None:
        write_json(out / "eval.json", metrics)
    if args.map:
        result = success_map(
            policy,
            scenario,
            seed=args.seed,
            progress=not args.quiet,
            **({} if args.map_trials is None else {"trials": args.map_trials}),
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
            policy,
            scenario,
            args.video,
            episodes=args.video_episodes or VIDEO_EPISODES,
            seed=args.seed,
            **env_kwargs,
        )
        print(f"video: {video}")
    wall = time.perf_counter() - start
    print(f"wall-clock {wall:.1f} s" + (f"; results in {out}/" if out else ""))
    return 0


def _refuse_file_under_a_file(option: str, path: Path) -> None:
    """Refuse up front, not after the work, a file to write whose folder is a file."""
    from dockingrl.io import file_in_the_way

    blocker = file_in_the_way(path.parent)
    if blocker is not None:
        raise UsageError(f"{option} {path}: cannot be written ({blocker} is a file)")


#: ``dockingrl export --format``: the suffix of each format's file
EXPORT_SUFFIXES = {"pt2": ".pt2", "onnx": ".onnx"}


def cmd_export(args: argparse.Namespace) -> int:
    """``dockingrl export``: a policy and its filter as a torch.export or ONNX program."""
    from dockingrl.onboard import OnboardPolicy, export_onboard, export_onnx
    from dockingrl.onboard.export import onnx_names

    if args.policy == "managed_surge":
        raise UsageError("--policy managed_surge: only a trained policy.pt is exported")
    out = Path(args.out)
    if out.is_dir():
        raise UsageError(
            f"--out {out}: a folder; give the program's file, e.g. {out / 'policy.onnx'}"
        )
    fmt = args.format or next((f for f, x in EXPORT_SUFFIXES.items() if x == out.suffix), None)
    if fmt is None or out.suffix != EXPORT_SUFFIXES[fmt]:
        expected = EXPORT_SUFFIXES.get(fmt) or " or ".join(EXPORT_SUFFIXES.values())
        raise UsageError(f"--out {out}: a {fmt or 'program'} file ends in {expected}")
    _refuse_file_under_a_file("--out", out)
    policy = OnboardPolicy.from_file(args.policy, filter_params=args.filter_params)
    if fmt == "onnx":
        try:
            path = export_onnx(policy, out, batch=args.batch)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        inputs, outputs = onnx_names(policy)
        print(
            f"wrote {path}: ONNX opset 18, ({', '.join(inputs)}) -> ({', '.join(outputs)}), "
            f"{args.batch} vehicle(s), scenario {policy.scenario}; age -1 starts an approach "
            "(docs/onboard.md)"
        )
        return 0
    ekf = policy.step.ekf
    sensor_age = ekf is not None and ekf.latency_steps > 0
    path = export_onboard(policy, out, batch=args.batch, sensor_age=sensor_age)
    extra = ", sensor_age, history" if sensor_age else ""
    print(
        f"wrote {path}: torch.export.load(path).module()(z, current, mean, cov, command, age"
        f"{extra}) -> (command, mean, cov, age{', history' if sensor_age else ''}), "
        f"{args.batch} vehicle(s), scenario {policy.scenario}; age -1 starts an approach"
    )
    return 0


def add_evaluation_commands(sub) -> None:
    """Register ``dockingrl eval`` and ``dockingrl export`` on the CLI's subparsers ``sub``."""
    from dockingrl.scenarios import SCENARIOS

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
    ev.add_argument(
        "--episodes", type=EPISODES, default=500, help="number of episodes (paper: 500)"
    )
    ev.add_argument(
        "--vehicle",
        choices=list(VEHICLES),
        default="paper",
        help="the vehicle flown: the paper's model, the Fossen Sparus II-class model "
        "(docs/vehicles.md) or either per episode",
    )
    ev.add_argument("--seed", type=SEED, default=0, help="evaluation seed")
    ev.add_argument("--out", type=results_folder, default=None, help="results folder (JSON + PNG)")
    ev.add_argument("--map", action="store_true", help="also the 9x9 success map (Figure 9)")
    ev.add_argument(
        "--map-trials",
        type=COUNT,
        default=None,
        help="episodes per map cell (default 10, success_map's)",
    )
    ev.add_argument("--trajectories", action="store_true", help="also Figure-10 trajectories")
    ev.add_argument(
        "--video",
        metavar="PATH",
        default=None,
        help="also a GIF (.gif) or MP4 (.mp4) of --video-episodes episodes, drawn as Figure 10",
    )
    ev.add_argument(
        "--video-episodes",
        type=COUNT,
        default=None,
        help=f"episodes in the --video (default {VIDEO_EPISODES})",
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
        type=filter_params_file,
        default=None,
        help="learned Q/R file for the EKF; default: the agent's training file (if any), "
        "'none': Table 1's filter",
    )
    for sensor in ("range", "bearing"):
        ev.add_argument(
            f"--{sensor}-noise-scale",
            type=NON_NEGATIVE,
            default=None,
            help=f"env's USBL {sensor} noise x this (0: none, as training accepts; at most 5); "
            "default: the agent's training value (1)",
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
        "treats both sides alike scores the same (dockingrl.agents.MirroredPolicy)",
    )
    ev.add_argument("--threads", type=COUNT, default=2, help="torch CPU threads")
    ev.add_argument(
        "--device", type=torch_device, default="cpu", help="torch device of the envs and the policy"
    )
    ev.add_argument("--quiet", action="store_true", help="no progress bar")
    ev.set_defaults(func=cmd_eval)

    ex = sub.add_parser(
        "export",
        help="write a trained policy with its filter as one ONNX or torch.export program for a "
        "vehicle",
    )
    ex.add_argument("--policy", required=True, help="policy.pt written by training")
    ex.add_argument("--out", required=True, help="the program's file (.onnx or .pt2)")
    ex.add_argument(
        "--format",
        choices=sorted(EXPORT_SUFFIXES),
        default=None,
        help="onnx (ONNX Runtime, C++ or Python) or pt2 (torch.export, libtorch); default: "
        "from --out's suffix",
    )
    ex.add_argument("--batch", type=COUNT, default=1, help="vehicles per call")
    ex.add_argument(
        "--filter-params",
        type=filter_params_file,
        default=None,
        help="learned Q/R file for the EKF; default: the agent's training file (if any), "
        "'none': Table 1's filter",
    )
    ex.set_defaults(func=cmd_export)
