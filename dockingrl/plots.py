"""Figures in the style of the paper's: success map (Fig. 9), trajectories (Fig. 10), filter
effect (Fig. 5) and learning curves (Figs. 6-8). Every function writes a PNG atomically."""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from dockingrl.io import atomic_write  # noqa: E402

FOOTER_POINTS = 6
"""Font size of a figure's footer (its command, machine and wall-clock)."""


def add_footer(fig, footer: str) -> int:
    """Write ``footer`` under everything ``fig`` holds, wrapped to the figure's width, and make
    the figure that much taller so that no line runs over an axis or off the edge: every axis
    and figure text keeps its size in inches and moves up. Returns the number of lines."""
    width, height = fig.get_size_inches()
    per_line = max(40, int(width * 72 / (0.58 * FOOTER_POINTS)))  # a wide character is 0.58 em
    lines = textwrap.wrap(footer, per_line, break_long_words=True, break_on_hyphens=False)
    extra = (1.3 * FOOTER_POINTS * len(lines) + 4) / 72
    keep = height / (height + extra)  # the old content's share of the taller figure
    fig.set_size_inches(width, height + extra)
    for ax in fig.axes:
        box = ax.get_position()
        ax.set_position((box.x0, 1 - keep + box.y0 * keep, box.width, box.height * keep))
    for text in fig.texts:
        x, y = text.get_position()
        text.set_position((x, 1 - keep + y * keep))
    fig.text(
        0.01,
        2 / 72 / (height + extra),
        "\n".join(lines),
        fontsize=FOOTER_POINTS,
        color="0.4",
        ha="left",
        va="bottom",
        linespacing=1.3,
    )
    return len(lines)


def _save(fig, path: str | Path, footer: str | None = None) -> Path:
    if footer:
        add_footer(fig, footer)
    try:
        return atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110))
    finally:
        plt.close(fig)


def plot_success_map(result: dict, path: str | Path, *, title: str = "", footer: str = "") -> Path:
    """Heat map of success rate over the ocean-current grid (Figure 9)."""
    rate = np.asarray(result["success_rate"], dtype=float)
    oc_x, oc_y = np.asarray(result["oc_x"]), np.asarray(result["oc_y"])
    fig, ax = plt.subplots(figsize=(5.6, 4.8))
    step = oc_x[1] - oc_x[0] if len(oc_x) > 1 else 0.1
    extent = (oc_x[0] - step / 2, oc_x[-1] + step / 2, oc_y[0] - step / 2, oc_y[-1] + step / 2)
    image = ax.imshow(rate, origin="lower", extent=extent, vmin=0, vmax=100, cmap="RdYlGn")
    for i, y in enumerate(oc_y):
        for j, x in enumerate(oc_x):
            if np.isfinite(rate[i, j]):  # NaN: a cell not run
                ax.text(x, y, f"{rate[i, j]:.0f}", ha="center", va="center", fontsize=7)
    ax.set_xlabel("ocean current $oc_x$ (m/s)")
    ax.set_ylabel("ocean current $oc_y$ (m/s)")
    ax.set_title(title or f"success rate (%), mean {np.nanmean(rate):.1f} %")
    fig.colorbar(image, ax=ax, label="success rate (%)")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return _save(fig, path, footer)


def _draw_funnel(ax, half_width: float = 0.5, length: float = 2.0) -> None:
    """The docking station: a funnel whose mouth opens towards -x at the origin."""
    ax.plot([-length, 0, -length], [half_width * 2, 0, -half_width * 2], color="k", lw=2)
    ax.add_patch(plt.Rectangle((-0.8, -0.5), 0.8, 1.0, color="0.8", zorder=0))
    ax.plot([0], [0], "ko", ms=3)


def plot_trajectories(
    cases: Sequence[dict],
    path: str | Path,
    *,
    columns: int = 2,
    footer: str = "",
    window: tuple[float, float, float, float] | None = None,
) -> Path:
    """AUV paths with heading arrows, the current as an arrow and ``r_g`` in each title
    (Figure 10). ``window`` ``(xmin, xmax, ymin, ymax)`` shows only that part of each path
    (the final approach, say); by default the whole path."""
    rows = math.ceil(len(cases) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(5.2 * columns, 2.8 * rows), squeeze=False)
    for ax, case in zip(axes.ravel(), cases, strict=False):
        path_xya = np.asarray(case["path"], dtype=float)
        if window is not None:
            inside = (path_xya[:, 0] >= window[0]) & (path_xya[:, 0] <= window[1])
            inside &= (path_xya[:, 1] >= window[2]) & (path_xya[:, 1] <= window[3])
            ax.plot(*np.where(inside[:, None], path_xya[:, :2], np.nan).T, color="tab:green", lw=1)
            path_xya = path_xya[inside] if inside.any() else path_xya[-1:]
        else:
            ax.plot(path_xya[:, 0], path_xya[:, 1], color="tab:green", lw=1)
        x, y, alpha = path_xya[:, 0], path_xya[:, 1], path_xya[:, 2]
        _draw_funnel(ax)
        every = max(1, len(x) // 25)
        ax.quiver(
            x[::every],
            y[::every],
            np.cos(alpha[::every]),
            np.sin(alpha[::every]),
            color="tab:green",
            scale=30,
            width=0.004,
        )
        oc = case["ocean_current"]
        if window is None:
            xmin, xmax = min(x.min(), -2.5) - 1, max(x.max(), 0.5) + 1
            ymin, ymax = min(y.min(), -1.5) - 1, max(y.max(), 1.5) + 1
        else:
            xmin, xmax, ymin, ymax = window
        # the current's arrow: 15 m per m/s, from 1.5 m inside the corner (in a window: a
        # 0.3 m/s current spans 15 % of its width)
        scale = 15.0 if window is None else 0.5 * (xmax - xmin)
        inset = 1.5 if window is None else 0.15 * (xmax - xmin)
        ax.annotate(
            "",
            xy=(xmax - inset + scale * oc[0], ymin + inset + scale * oc[1]),
            xytext=(xmax - inset, ymin + inset),
            arrowprops={"arrowstyle": "->", "color": "red", "lw": 2},
        )
        r_g = case.get("r_g", math.nan)
        outcome = (
            "success" if case.get("success") else ("docked" if case.get("docked") else "timeout")
        )
        r_text = "no contact" if math.isnan(r_g) else f"$r_g$ = {r_g:.0f}"
        seconds = case.get("time_s", 0)
        ax.set_title(
            f"oc = [{oc[0]:.2f}, {oc[1]:.2f}] m/s, {r_text}, {outcome}, {seconds:.0f} s", fontsize=8
        )
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    for ax in axes.ravel()[len(cases) :]:
        ax.axis("off")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return _save(fig, path, footer)


def plot_filter_episode(
    time_s: np.ndarray,
    raw: np.ndarray,
    filtered: np.ndarray,
    true: np.ndarray,
    path: str | Path,
    *,
    footer: str = "",
) -> Path:
    """Raw, filtered and true range, bearing and heading over one episode (Figure 5)."""
    names = [r"range $\rho$ (m)", r"bearing $\psi$ (rad)", r"heading $\alpha$ (rad)"]
    fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(time_s, raw[:, k], color="0.6", lw=0.8, label="raw (noisy)")
        ax.plot(time_s, filtered[:, k], color="tab:blue", lw=1.2, label="filtered (EKF)")
        ax.plot(time_s, true[:, k], color="k", lw=1, ls="--", label="true")
        ax.set_ylabel(names[k])
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return _save(fig, path, footer)


def plot_learning_curve(
    steps: Sequence[float],
    reward: Sequence[float],
    episode_time: Sequence[float],
    path: str | Path,
    *,
    success: Sequence[float] | None = None,
    title: str = "",
    footer: str = "",
) -> Path:
    """Total reward and episode time during training (Figures 6-8), success rate if given."""
    panels = 3 if success is not None else 2
    fig, axes = plt.subplots(panels, 1, figsize=(7, 2.4 * panels), sharex=True)
    axes[0].plot(steps, reward, color="tab:blue")
    axes[0].set_ylabel("total reward")
    axes[1].plot(steps, episode_time, color="tab:orange")
    axes[1].set_ylabel("episode time (s)")
    if success is not None:
        axes[2].plot(steps, success, color="tab:green")
        axes[2].set_ylabel("success (%)")
        axes[2].set_ylim(-2, 102)
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("env steps")
    if title:
        axes[0].set_title(title)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return _save(fig, path, footer)
