"""Table 6 as markdown: the cells beside the paper's values, the success per third of the
current, the periodic success per fifth of the budget and the claims (``table.md``)."""

from __future__ import annotations


def _fmt_ci(ci) -> str:
    return "-" if ci is None else f"[{ci[0]:.1f}, {ci[1]:.1f}]"


def _early(early: dict) -> str:
    """Success at 200 k env steps and the (latest) step its seeds were read at."""
    if early["mean"] is None:
        return "-"
    return f"{early['mean']:.1f} ({max(early['steps']) / 1000:.0f} k)"


def _rate(value) -> str:
    return "-" if value is None else f"{value:.1f}"


def _improvement(result) -> str:
    """rliable's probability of improvement with its interval, or ``-``."""
    if result is None:
        return "-"
    low, high = result["ci95"]
    return f"{result['probability']:.2f} [{low:.2f}, {high:.2f}]"


def markdown(table: dict) -> str:
    lines = [
        "| recipe | scenario | seeds | success % (mean) | 95 % CI over seeds | 95 % CI over "
        "episodes | paper % | time s (docked) | paper time s | reward | paper reward | "
        "success % at 200 k steps |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in table["cells"]:
        p = c["paper"] or {}
        t, rw = c["time_docked_s"], c["total_reward"]
        lines.append(
            f"| {c['recipe']} | {c['scenario']} | {c['seeds_label']} | "
            f"{c['success_mean']:.1f} ({', '.join(f'{s:.1f}' for s in c['success_per_seed'])}) | "
            f"{_fmt_ci(c['success_ci95_over_seeds'])} | "
            f"{_fmt_ci(c['success_ci95_over_episodes'])} | {p.get('success', '-')} | "
            + (f"{t['mean']:.1f} +- {t['std']:.1f} | " if t["n"] else "- | ")
            + (f"{p['time_mean']} +- {p['time_std']}" if p else "-")
            + f" | {rw['mean']:.1f} +- {rw['std']:.1f} | "
            + (f"{p['reward_mean']} +- {p['reward_std']}" if p else "-")
            + f" | {_early(c['success_at_200k'])} |"
        )
    commits = sorted({x for c in table["cells"] for x in c["code"]})
    machines = sorted({x for c in table["cells"] for x in c["machine"]})
    hours = sum(sum(c["train_wall_clock_s"]) for c in table["cells"]) / 3600
    lines += [
        "",
        f"Code: commit {', '.join(x[:10] or '(unknown)' for x in commits)}. Machine: "
        f"{'; '.join(machines)}. Training: {hours:.1f} h in all.",
        "",
        table["statistics"] + ".",
        "",
    ]
    lines += by_current_markdown(table["cells"])
    lines += by_fifth_markdown(table["cells"])
    if table.get("aggregates"):
        lines += [
            "| recipe | scenarios | seeds | IQM success % | 95 % CI (stratified bootstrap) |",
            "|---|---|---|---|---|",
        ]
        for a in table["aggregates"]:
            lines.append(
                f"| {a['recipe']} | {', '.join(a['scenarios'])} | {a['seeds']} | "
                f"{a['iqm']:.1f} | {_fmt_ci(a['ci95'])} |"
            )
        lines.append("")
    lines += [
        "| claim | recipe | difference | P(improvement) [95 % CI] | the paper's difference "
        "| verdict |",
        "|---|---|---|---|---|---|",
    ]
    for c in table["claims"]:
        if "compared" in c:
            values = ", ".join(f"{k} {v:.1f} %" for k, v in sorted(c["values"].items()))
            mine, rest = c["compared"]
            lines.append(
                f"| {c['claim']} | {c['recipe']} | {mine} - {rest} "
                f"{c['difference_points']:+.1f} points ({values}) | "
                f"{_improvement(c['probability_of_improvement'])} | - | "
                f"{c['verdict']} |"
            )
        elif "difference_points" in c:
            paper = c.get("paper_difference_points")
            lines.append(
                f"| {c['claim']} | {c['recipe']} | {c['difference_points']:+.1f} points | "
                f"{_improvement(c['probability_of_improvement'])} | "
                f"{'-' if paper is None else f'{paper:+.1f} points'} | "
                f"{c['verdict']} |"
            )
        elif "difference_s" in c:
            lines.append(
                f"| {c['claim']} | {c['recipe']} | {c['difference_s']:+.1f} s "
                f"({c['time_s']:.1f} s over {c['episodes']} successes against "
                f"{c['baseline_time_s']:.1f} over {c['baseline_episodes']}) | Welch p "
                + (f"= {c['p_value']:.2g}" if c["p_value"] > 0 else "< 1e-300")
                + f" | - | {c['verdict']} |"
            )
    return "\n".join(lines) + "\n"


def by_current_markdown(cells: list[dict]) -> list[str]:
    """The success of each cell per third of the along-axis current, as markdown lines."""
    rows = [c for c in cells if c.get("success_by_current_x")]
    if not rows:
        return []
    parts = rows[0]["success_by_current_x"]
    head = " | ".join(
        f"{p['oc_x']} ({p['range'][0]:+.1f} to {p['range'][1]:+.1f} m/s)" for p in parts
    )
    lines = [
        "Success % per third of the along-axis current (positive: towards the station), pooled "
        "over the seeds' final-evaluation episodes, each seed's in brackets; timeouts of the "
        "third after the slash:",
        "",
        f"| recipe | scenario | {head} |",
        "|---|---|" + "---|" * len(parts),
    ]
    for c in rows:
        cols = " | ".join(
            f"{_rate(p['success_rate'])} ({', '.join(map(_rate, p['per_seed']))}) / {p['timeouts']}"
            for p in c["success_by_current_x"]
        )
        lines.append(f"| {c['recipe']} | {c['scenario']} | {cols} |")
    return lines + [""]


def by_fifth_markdown(cells: list[dict]) -> list[str]:
    """The periodic success of each cell per fifth of its env steps, as markdown lines."""
    rows = [c for c in cells if c.get("periodic_success_by_fifth")]
    if not rows:
        return []
    lines = [
        "Periodic success % per fifth of each run's env steps (a seed's periodic evaluations "
        "in the fifth averaged, then the seeds); the last column counts the seeds whose last "
        "fifth is above every earlier one, still rising when their budget ended:",
        "",
        "| recipe | scenario | 1st fifth | 2nd | 3rd | 4th | 5th | seeds still rising |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in rows:
        f = c["periodic_success_by_fifth"]
        lines.append(
            f"| {c['recipe']} | {c['scenario']} | {' | '.join(map(_rate, f['mean']))} | "
            f"{f['seeds_still_rising']} of {len(f['per_seed'])} |"
        )
    return lines + [""]
