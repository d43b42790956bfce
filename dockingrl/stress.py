"""The stress ladder: a policy evaluated from the paper's task (L0) to a vehicle whose sensors,
current and dynamics break the paper's assumptions at harsh but realistic values (L1-L5), with
the evaluation's success rate and failure split per level (``dockingrl stress``;
docs/realism.md)."""

from __future__ import annotations

from pathlib import Path

from dockingrl.env import DockingConfig

#: 1 Hz USBL, 0.6 s late, 20 % of the fixes lost in bursts of 3, 5 % outliers 5 m off; a
#: 2.5 Hz DVL
HARSH_SENSORS = {
    "usbl_period": 1.0,
    "usbl_latency": 0.6,
    "usbl_dropout_probability": 0.2,
    "usbl_dropout_burst": 3.0,
    "usbl_outlier_probability": 0.05,
    "usbl_outlier_distance": 5.0,
    "dvl_period": 0.4,
}
#: a current varying by 0.05 m/s over 30 s, believed with a 0.05 m/s bias and 0.02 m/s noise
HARSH_CURRENT = {
    "current_time_constant": 30.0,
    "current_variation_std": 0.05,
    "current_knowledge_bias": 0.05,
    "current_knowledge_noise": 0.02,
}
#: +-30 % mass, damping and PID gains, +-20 % thrust, a response up to 3x slower, 40 % less
#: thrust in reverse and half the surge thrust at full yaw moment
HARSH_DYNAMICS = {
    "mass_scale": (0.7, 1.3),
    "damping_scale": (0.7, 1.3),
    "thrust_scale": (0.8, 1.2),
    "pid_gain_scale": (0.7, 1.3),
    "response_time_scale": (1.0, 3.0),
    "reverse_thrust_loss": 0.4,
    "turning_surge_loss": 0.5,
}
#: the ladder: name -> (what it is, the DockingConfig options it sets)
LEVELS: dict[str, tuple[str, dict]] = {
    "L0": ("the paper's task", {}),
    "L1": ("sensors: 1 Hz USBL, late, dropouts, outliers; slow DVL", HARSH_SENSORS),
    "L2": ("current: varying, known with bias and noise", HARSH_CURRENT),
    "L3": ("dynamics: +-30 % vehicle, 3x slower loops, weak reverse", HARSH_DYNAMICS),
    "L4": ("sensors and current", {**HARSH_SENSORS, **HARSH_CURRENT}),
    "L5": ("sensors, current and dynamics", {**HARSH_SENSORS, **HARSH_CURRENT, **HARSH_DYNAMICS}),
}
FAILURES = ("timeout", "missed_funnel", "too_fast")


def level_config(level: str, base: DockingConfig | None = None) -> DockingConfig:
    """The :class:`DockingConfig` of a ladder level: ``base`` (the paper's) with its options."""
    if level not in LEVELS:
        raise ValueError(f"unknown stress level {level!r}; valid: {', '.join(LEVELS)}")
    return (base or DockingConfig()).replace(**LEVELS[level][1])


def stress_ladder(
    policy,
    scenario: str,
    *,
    episodes: int = 1000,
    levels: tuple[str, ...] = tuple(LEVELS),
    seed: int = 0,
    base: DockingConfig | None = None,
    gate: float | None = None,
    **env_kwargs,
) -> dict:
    """Evaluate ``policy`` on ``scenario`` at each ladder level (``episodes`` each, the same
    seed, so that every level starts from the same poses and currents).

    Keyword Args:
        base: the config each level starts from (the paper's by default).
        gate: the EKF's chi-square innovation gate in filtered scenarios (``None``: none).
        env_kwargs: more :func:`~dockingrl.make_env` options (``observe_current``, ...).

    Returns:
        ``{"scenario", "episodes", "seed", "gate", "levels": [...]}``, each level with its
        ``name``, ``description``, ``options`` and :func:`~dockingrl.evaluation.evaluate`'s
        metrics (``success_rate``, ``failures``, ...).
    """
    from dockingrl.evaluation import evaluate
    from dockingrl.scenarios import FILTERED_OBSERVATION_KEYS

    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    for level in levels:
        level_config(level, base)  # refuse an unknown level before the first evaluation
    if gate is not None:
        if scenario not in FILTERED_OBSERVATION_KEYS:
            raise ValueError(f"gate applies to the filtered scenarios only, not {scenario!r}")
        env_kwargs["ekf_kwargs"] = {**env_kwargs.get("ekf_kwargs", {}), "gate": gate}
    rows = []
    for level in levels:
        metrics = evaluate(
            policy, scenario, episodes, seed=seed, config=level_config(level, base), **env_kwargs
        )
        description, options = LEVELS[level]
        rows.append({"name": level, "description": description, "options": options, **metrics})
    return {"scenario": scenario, "episodes": episodes, "seed": seed, "gate": gate, "levels": rows}


def stress_table(result: dict, name: str = "policy") -> str:
    """The ladder as a markdown table: success and the failure split per level."""
    lines = [
        f"Stress ladder of {name} on `{result['scenario']}`, {result['episodes']} episodes a "
        f"level, seed {result['seed']}"
        + (f", EKF gate {result['gate']:g}" if result["gate"] else ""),
        "",
        "| level | what breaks | success % | timeout | missed funnel | too fast |",
        "|---|---|---|---|---|---|",
    ]
    for row in result["levels"]:
        failures = row["failures"]
        lines.append(
            f"| {row['name']} | {row['description']} | {row['success_rate']:.1f} | "
            + " | ".join(str(failures[k]) for k in FAILURES)
            + " |"
        )
    return "\n".join(lines) + "\n"


def plot_stress(result: dict, path: str | Path, *, title: str = "", footer: str = "") -> Path:
    """Stacked bars per level: the share of successes and of each failure kind (%)."""
    from dockingrl.plots import _save, plt

    rows = result["levels"]
    names = [row["name"] for row in rows]
    fig, ax = plt.subplots(figsize=(7.2, 3.6))
    bottom = [0.0] * len(rows)
    series = [("success", [row["success_rate"] for row in rows], "tab:green")]
    colours = ("tab:gray", "tab:red", "tab:orange")
    for kind, colour in zip(FAILURES, colours, strict=True):
        share = [100.0 * row["failures"][kind] / row["episodes"] for row in rows]
        series.append((kind.replace("_", " "), share, colour))
    for label, values, colour in series:
        ax.bar(names, values, bottom=bottom, label=label, color=colour)
        bottom = [b + v for b, v in zip(bottom, values, strict=True)]
    for i, row in enumerate(rows):
        ax.text(i, row["success_rate"] / 2, f"{row['success_rate']:.1f}", ha="center", fontsize=8)
    ax.set_ylim(0, 100)
    ax.set_ylabel("episodes (%)")
    ax.set_title(title or f"stress ladder, {result['scenario']}")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    return _save(fig, path, footer)


def write_stress(result: dict, out: str | Path, name: str = "policy") -> list[Path]:
    """``stress.json``, ``stress.md`` and ``stress.png`` in the folder ``out``; the table and
    the figure name the result's ``command``, ``machine`` and ``wall_clock_s`` if it has them."""
    from dockingrl.io import atomic_write, write_json

    out = Path(out)
    table = stress_table(result, name)
    footer = "  |  ".join(
        text
        for text in (
            result.get("command", ""),
            result.get("machine", ""),
            f"{result['wall_clock_s']:.0f} s" if "wall_clock_s" in result else "",
        )
        if text
    )
    if footer:
        table += f"\n{footer}\n"
    return [
        write_json(out / "stress.json", result),
        atomic_write(out / "stress.md", lambda tmp: tmp.write_text(table)),
        plot_stress(result, out / "stress.png", title=f"{name}: stress ladder", footer=footer),
    ]
