"""PPO agents reading the hand-tuned and a learned filter, trained and evaluated under
mismatched sensor noise (``dockingrl ppo-filter-comparison``)."""

from __future__ import annotations

import json
from pathlib import Path

from dockingrl.io import atomic_write, write_json


def _train_or_resume(cfg, run_dir: Path, command: str) -> dict:
    """The run of ``cfg`` in ``run_dir``: read back when finished, resumed when interrupted,
    trained otherwise; a folder holding a run of another config is refused."""
    from dockingrl.agents.config_diff import saved_differs
    from dockingrl.training import train

    if not (run_dir / "config.json").exists():
        return train(cfg, progress=False, command=command)
    saved = _run_file(run_dir / "config.json", ())
    differ = saved_differs(saved, cfg)
    if differ:
        raise ValueError(
            f"{run_dir} holds a run of another config ({', '.join(differ)} differ): "
            "remove it or give another --runs folder"
        )
    if (run_dir / "summary.json").exists() and (run_dir / "eval.json").exists():
        return {name: _run_file(run_dir / f"{name}.json", keys) for name, keys in _READ} | {
            "run_dir": str(run_dir)
        }
    return train(None, resume=run_dir, progress=False, command=command)


#: what the comparison reads of a finished run's summary and final evaluation
_READ = (
    ("summary", ("train_wall_clock_s", "frames", "machine")),
    ("eval", ("success_rate", "total_reward", "time_s", "failures")),
)


def _run_file(path: Path, keys: tuple[str, ...]) -> dict:
    """The JSON object of a run's file, with ``keys``; else a one-line ``ValueError`` naming
    it."""
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(
            f"{path}: damaged ({exc}); remove the run folder to train it again"
        ) from None
    if not isinstance(value, dict):
        missing = ["JSON object"]
    else:
        missing = [k for k in keys if k not in value]
    if missing:
        raise ValueError(
            f"{path}: not a finished run's file (no {', '.join(missing)}); "
            "remove the run folder to train it again"
        )
    return value


def ppo_filter_comparison(
    filter_params: str,
    out: str | Path,
    *,
    noise_scale: float = 2.0,
    total_steps: int = 2_000_000,
    runs_dir: str = "runs",
    seeds=(0,),
    extra: dict | None = None,
    overrides: list[str] = (),
    command: str = "",
) -> str:
    """Train PPO ``compound`` agents (``fast`` preset, the fields ``extra`` on top, given on
    the command line as ``overrides``) in the env whose USBL noise is ``noise_scale`` times
    larger, one per seed reading the hand-tuned filter and one the learned ``filter_params``,
    in ``runs_dir``; tabulate their final 500-episode evaluations (``ppo_mismatch.{json,md}`` in
    ``out``) and return the table's text."""
    from dockingrl.agents.config import make_config
    from dockingrl.transforms.params import read_filter_params

    read_filter_params(filter_params)  # a bad file is refused before hours of training
    extra = extra or {}
    rows, results = [], {"command": command, "seeds": list(seeds), "agents": {}}
    for name, params in (("hand-tuned (Tables 1-2)", ""), ("learned", filter_params)):
        label = f"{name}: {params}" if params else name
        runs = {}
        for seed in seeds:
            run_name = "ppo_mismatch_" + ("learned" if params else "handtuned") + f"_s{seed}"
            cfg = make_config(
                "ppo",
                "fast",
                scenario="compound",
                total_steps=total_steps,
                range_noise_scale=noise_scale,
                bearing_noise_scale=noise_scale,
                filter_params=params,
                out=runs_dir,
                run_name=run_name,
                logger="csv",
                seed=seed,
                **extra,
            )
            result = _train_or_resume(cfg, Path(runs_dir) / run_name, command)
            final, summary = result["eval"], result["summary"]
            runs[seed] = {
                "success_rate": final["success_rate"],
                "total_reward": final["total_reward"],
                "time_s": final["time_s"],
                "failures": final["failures"],
                "train_wall_clock_s": summary["train_wall_clock_s"],
                "frames": summary["frames"],
                "machine": summary["machine"],
                "run_dir": result["run_dir"],
            }
            f, r = final["failures"], final["total_reward"]
            rows.append(
                f"| {label} | {seed} | {final['success_rate']:.1f} | "
                f"{r['mean']:.1f} +- {r['std']:.1f} | "
                f"{f['timeout']} / {f['missed_funnel']} / {f['too_fast']} | "
                f"{summary['train_wall_clock_s']:.0f} |"
            )
        rates = [run["success_rate"] for run in runs.values()]
        mean = sum(rates) / len(rates)
        results["agents"][label] = {"runs": runs, "success_rate_mean": mean}
        if len(rates) > 1:
            rows.append(f"| {label} | mean of {len(rates)} | **{mean:.1f}** | | | |")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "ppo_mismatch.json", results)
    text = "\n".join(
        [
            f"# PPO compound agents under mismatched sensor noise (range and bearing x"
            f"{noise_scale:g})",
            "",
            f"Command: `{command}`",
            "",
            f"Each agent: `--preset fast{''.join(f' --set {x}' for x in overrides)}`, "
            f"{total_steps} env steps, trained and evaluated (500 episodes) in the "
            f"mismatched env. Data: `ppo_mismatch.json`. Machine: {summary['machine']}.",
            "",
            "| filter in the compound observation | seed | success % | total reward | "
            "timeouts / missed funnel / too fast | training wall-clock s |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    atomic_write(out / "ppo_mismatch.md", lambda tmp: tmp.write_text(text))
    return text
