"""The stress ladder: a policy evaluated from the paper's task (L0) to a vehicle whose sensors,
current and dynamics break the paper's assumptions at harsh but realistic values (L1-L5), with
the evaluation's success rate and failure split per level (``dockingrl stress``;
docs/realism.md)."""

from __future__ import annotations

from pathlib import Path

from dockingrl.env import DockingConfig
from dockingrl.env.levels import LEVELS, level_config
from dockingrl.table.claims import episodes_ci

FAILURES = ("timeout", "missed_funnel", "too_fast")


def stress_ladder(
    policy,
    scenario: str,
    *,
    episodes: int = 1000,
    levels: tuple[str, ...] = tuple(LEVELS),
    seed: int = 0,
    base: DockingConfig | None = None,
    gate: float | None = None,
    compensate_latency: bool = False,
    estimate_current: bool = False,
    **env_kwargs,
) -> dict:
    """Evaluate ``policy`` on ``scenario`` at each ladder level (``episodes`` each, the same
    seed, so that every level starts from the same poses and currents).

    Keyword Args:
        base: the config each level starts from (the paper's by default).
        gate: the EKF's chi-square innovation gate in filtered scenarios (``None``: none, or
            the gate that ``env_kwargs`` (a policy's, trained with ``filter_gate``) carry).
        compensate_latency: the EKF of a filtered scenario compensates each level's USBL
            latency (:func:`~dockingrl.scenarios.make_filter`); on too where ``env_kwargs``
            (a policy's, trained with ``compensate_latency``) carry it.
        estimate_current: the EKF of a filtered scenario estimates the current's error
            (:class:`~dockingrl.transforms.current_filter.CurrentEstimatingEKF`).
        env_kwargs: more :func:`~dockingrl.make_env` options (``observe_current``, ...).

    Returns:
        ``{"scenario", "episodes", "seed", "gate", "compensate_latency", "estimate_current",
        "levels": [...]}``,
        each level with its
        ``name``, ``description``, ``options`` and :func:`~dockingrl.evaluation.evaluate`'s
        metrics (``success_rate``, ``failures``, ...).
    """
    from dockingrl.evaluation import evaluate
    from dockingrl.scenarios import FILTERED_OBSERVATION_KEYS

    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    for level in levels:
        level_config(level, base)  # refuse an unknown level before the first evaluation
    for name, value, option in (
        ("gate", gate is not None, {"gate": gate}),
        ("compensate_latency", compensate_latency, {"compensate_latency": True}),
        ("estimate_current", estimate_current, {"estimate_current": True}),
    ):
        if not value:
            continue
        if scenario not in FILTERED_OBSERVATION_KEYS:
            raise ValueError(f"{name} applies to the filtered scenarios only, not {scenario!r}")
        env_kwargs["ekf_kwargs"] = {**env_kwargs.get("ekf_kwargs", {}), **option}
    filter_options = env_kwargs.get("ekf_kwargs", {})
    gate = filter_options.get("gate")
    compensate_latency = bool(filter_options.get("compensate_latency"))
    estimate_current = bool(filter_options.get("estimate_current"))
    rows = []
    for level in levels:
        metrics = evaluate(
            policy, scenario, episodes, seed=seed, config=level_config(level, base), **env_kwargs
        )
        description, options = LEVELS[level]
        rows.append({"name": level, "description": description, "options": options, **metrics})
    return {
        "scenario": scenario,
        "episodes": episodes,
        "seed": seed,
        "gate": gate,
        "compensate_latency": compensate_latency,
        "estimate_current": estimate_current,
        "levels": rows,
    }


def stress_table(result: dict, name: str = "policy") -> str:
    """The ladder as a markdown table: success with its 95 % Wilson interval over the episodes,
    the failure split and the success under strong lateral currents (``by_current_y``'s top
    third) per level."""
    lines = [
        f"Stress ladder of {name} on `{result['scenario']}`, {result['episodes']} episodes a "
        f"level, seed {result['seed']}"
        + (f", EKF gate {result['gate']:g}" if result["gate"] else "")
        + (", EKF compensating the USBL latency" if result.get("compensate_latency") else "")
        + (", EKF estimating the current" if result.get("estimate_current") else ""),
        "",
        "A strong lateral current: |oc_y| at the start in the top third of its range (0.2-0.3 "
        "m/s in the paper's draw), where the drift alone nears the 0.3 m/s contact limit.",
        "",
        "| level | what breaks | success % | 95 % interval | timeout | missed funnel | too fast | "
        "strong lateral current: success % (episodes) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in result["levels"]:
        failures = row["failures"]
        low, high = episodes_ci([row["success_rate"]], [row["episodes"]])
        lines.append(
            f"| {row['name']} | {row['description']} | {row['success_rate']:.1f} | "
            f"[{low:.1f}, {high:.1f}] | "
            + " | ".join(str(failures[k]) for k in FAILURES)
            + f" | {_strong_lateral(row)} |"
        )
    return "\n".join(lines) + "\n"


def _strong_lateral(row: dict) -> str:
    """``success (episodes)`` over a level's strongest third of ``|oc_y|``; a ladder written
    before that split has ``-``."""
    strong = next((t for t in row.get("by_current_y", ()) if t["abs_oc_y"] == "strong"), None)
    if strong is None:
        return "-"
    if not strong["episodes"]:
        return "n/a (0)"
    return f"{strong['success_rate']:.1f} ({strong['episodes']})"


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
