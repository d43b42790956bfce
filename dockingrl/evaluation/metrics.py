"""The metrics of the paper's Tables 6-7 from a batch's outcomes, and a table row beside the
paper's numbers."""

from __future__ import annotations

from typing import Any

import torch

#: Tables 6 and 7 of the paper (500 trials each): success %, time mean/std (s), reward mean/std.
PAPER_RESULTS: dict[tuple[str, str], tuple[float, float, float, float, float]] = {
    ("sac", "no_noise"): (97.0, 47.1, 11.4, 42.7, 63.1),
    ("sac", "noise"): (73.4, 48.3, 11.0, -23.3, 99.5),
    ("sac", "filtered"): (88.4, 46.9, 12.7, 0.7, 78.1),
    ("sac", "compound"): (99.4, 44.5, 11.0, 36.7, 80.1),
    ("td3", "no_noise"): (98.0, 44.1, 10.8, 50.8, 48.3),
    ("td3", "noise"): (69.0, 47.4, 9.8, -44.1, 106.9),
    ("td3", "filtered"): (97.2, 45.3, 15.5, -0.1, 61.0),
    ("td3", "compound"): (99.8, 44.4, 9.7, 36.1, 30.6),
    ("ppo", "no_noise"): (88.2, 50.7, 15.6, -41.0, 93.9),
    ("ppo", "noise"): (64.2, 68.4, 21.5, -94.1, 112.5),
    ("ppo", "filtered"): (90.8, 45.7, 11.0, 2.4, 83.6),
    ("ppo", "compound"): (94.2, 45.5, 11.2, 23.6, 65.3),
    ("managed_surge", "noise"): (73.7, 59.2, 7.7, -115.8, 114.2),
}


def _stats(values: torch.Tensor, over: str) -> dict[str, Any]:
    v = values.double().numpy()
    if v.size == 0:
        return {"over": over, "n": 0, "mean": None, "std": None}
    return {"over": over, "n": int(v.size), "mean": float(v.mean()), "std": float(v.std())}


def _failures(docked, score, speed, speed_limit) -> dict[str, int]:
    return {
        "timeout": int((~docked).sum()),
        "missed_funnel": int((docked & (score <= 0)).sum()),
        "too_fast": int((docked & (score > 0) & (speed > speed_limit)).sum()),
    }


def summarize(
    outcomes: dict[str, torch.Tensor],
    dt: float,
    speed_limit: float,
    current_range: tuple[float, float] = (-0.3, 0.3),
    entrance_x: float = 0.0,
) -> dict:
    """Table 6/7 metrics from :func:`run_episodes` outcomes.

    - ``success_rate`` (%): docked within the time limit with ``g > 0`` and ground speed
      ``<= v_max``.
    - ``time_s``: episode time over the **docked** episodes (every contact, successful or
      not), which is how the paper's Table 6 reads; ``time_success_s`` over successful episodes
      only; ``time_all_s`` over all episodes (a timeout counts as the full 120 s).
    - ``total_reward``: over all episodes.
    - ``contact_score`` (``g``) and ``contact_speed`` (m/s): over docked episodes.
    - ``failures``: ``timeout`` (no contact in time), ``missed_funnel`` (contact with
      ``g <= 0``), ``too_fast`` (contact with ``g > 0`` above the speed limit).
    - ``timeouts_beyond_station``: timeouts that ended at ``x > entrance_x``, past the
      station's entrance plane (the AUV starts at ``x < 0`` and docks moving in ``+x``).
    - ``by_current_x``: episodes, success rate and failures split by ``oc_x`` at the thirds
      of ``current_range``: ``opposing`` (the lowest third: the current carries the AUV away
      from the station), ``weak`` (the middle third) and ``following`` (the highest: it
      carries the AUV towards the station); a current outside the range counts in the outer
      third on its side, so the three add up to the totals.
    - ``by_current_y``: the same split by ``|oc_y|`` at the thirds of ``[0, max |range|]``:
      ``weak``, ``moderate`` and ``strong`` lateral currents (the last takes any larger
      ``|oc_y|``). A lateral current drifts the AUV sideways at the contact, where a strong
      one leaves little of the speed limit for the approach. Both splits read the true current
      at the episode's start; one that varies in time (``current_time_constant``) moves
      away from it during the episode.

    Standard deviations are population ones (``ddof = 0``).
    """
    success, docked = outcomes["success"], outcomes["docked"]
    n = int(success.numel())
    seconds = outcomes["steps"].double() * dt
    score, speed = outcomes["contact_score"], outcomes["contact_speed"]
    return {
        "episodes": n,
        "success_rate": 100.0 * float(success.double().mean()),
        "time_s": _stats(seconds[docked], "docked episodes"),
        "time_success_s": _stats(seconds[success], "successful episodes"),
        "time_all_s": _stats(seconds, "all episodes"),
        "total_reward": _stats(outcomes["total_reward"], "all episodes"),
        "contact_score": _stats(score[docked], "docked episodes"),
        "contact_speed": _stats(speed[docked], "docked episodes"),
        "failures": _failures(docked, score, speed, speed_limit),
        "timeouts_beyond_station": int((~docked & (outcomes["end"][:, 0] > entrance_x)).sum()),
        "by_current_x": _by_current_x(outcomes, speed_limit, current_range),
        "by_current_y": _by_current_y(outcomes, speed_limit, current_range),
    }


def _by_current_x(outcomes, speed_limit, current_range) -> list[dict]:
    low, high = current_range
    edges = [round(low + (high - low) * k / 3, 12) for k in range(4)]
    names = ("opposing", "weak", "following")
    return _split(outcomes, outcomes["ocean_current"][:, 0], edges, "oc_x", names, speed_limit)


def _by_current_y(outcomes, speed_limit, current_range) -> list[dict]:
    top = max(abs(v) for v in current_range)
    edges = [round(top * k / 3, 12) for k in range(4)]
    names = ("weak", "moderate", "strong")
    value = outcomes["ocean_current"][:, 1].abs()
    return _split(outcomes, value, edges, "abs_oc_y", names, speed_limit)


def _split(outcomes, value, edges, key, names, speed_limit) -> list[dict]:
    """Episodes, success and failures per third of ``value`` between ``edges`` (4 numbers),
    each third named ``names[k]`` under ``key``; a value outside them counts in the outer
    third on its side."""
    masks = (value < edges[1], (value >= edges[1]) & (value < edges[2]), value >= edges[2])
    thirds = []
    for k, (name, mask) in enumerate(zip(names, masks, strict=True)):
        n = int(mask.sum())
        thirds.append(
            {
                key: name,
                "range": [edges[k], edges[k + 1]],
                "episodes": n,
                "success_rate": 100.0 * float(outcomes["success"][mask].double().mean())
                if n
                else None,
                "failures": _failures(
                    outcomes["docked"][mask],
                    outcomes["contact_score"][mask],
                    outcomes["contact_speed"][mask],
                    speed_limit,
                ),
            }
        )
    return thirds


def table_row(name: str, scenario: str, metrics: dict) -> str:
    """A Table 6/7-style row, beside the paper's numbers where it has them."""
    t, r = metrics["time_s"], metrics["total_reward"]
    time_text = "n/a" if t["mean"] is None else f"{t['mean']:.1f} +- {t['std']:.1f}"
    row = (
        f"| {name} | {scenario} | {metrics['success_rate']:.1f} | {time_text} | "
        f"{r['mean']:.1f} +- {r['std']:.1f} |"
    )
    paper = PAPER_RESULTS.get((name, scenario))
    if paper is not None:
        s, tm, ts, rm, rs = paper
        row += (
            f"\n| {name} (paper) | {scenario} | {s:.1f} | {tm:.1f} +- {ts:.1f} | "
            f"{rm:.1f} +- {rs:.1f} |"
        )
    header = (
        "| algorithm | scenario | success % | time s (docked) | total reward |\n"
        "|---|---|---|---|---|\n"
    )
    return header + row
