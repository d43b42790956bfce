"""Frames and videos of docking approaches in the style of the paper's Figure 10: the station's
funnel, the vehicle, its track and the ocean current's arrow."""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Polygon, Rectangle

from dockingrl.env import DockingConfig
from dockingrl.io import atomic_write

#: the vehicle's outline in its body frame (m): a torpedo of 1.6 m, nose at +x
VEHICLE_OUTLINE = np.array([[0.8, 0.0], [0.3, 0.2], [-0.8, 0.2], [-0.8, -0.2], [0.3, -0.2]])
#: video formats :func:`write_video` writes, by file suffix
VIDEO_SUFFIXES = (".gif", ".mp4")


class DockingRenderer:
    """Draws one approach as an RGB frame: the funnel (mouth towards -x at the origin) and
    its contact box, the track of true poses so far, the vehicle at the last pose and the
    current's arrow (15 m per m/s, from 6 m inside the lower right corner), on a fixed-size
    canvas.

    Args:
        config: the env's constants (the contact box).

    Keyword Args:
        size: ``(width, height)`` of a frame in pixels.
    """

    def __init__(self, config: DockingConfig | None = None, *, size=(640, 400)) -> None:
        self.config = config or DockingConfig()
        width, height = size
        self.figure = Figure(figsize=(width / 100, height / 100), dpi=100)
        self.canvas = FigureCanvasAgg(self.figure)
        self.axes = ax = self.figure.add_axes((0.11, 0.13, 0.86, 0.78))
        ax.plot([-2.0, 0.0, -2.0], [1.0, 0.0, -1.0], color="k", lw=2)
        (x0, x1), (y0, y1) = self.config.dock_x, self.config.dock_y
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, color="0.8", zorder=0))
        ax.plot([0], [0], "ko", ms=3)
        (self._track,) = ax.plot([], [], color="tab:green", lw=1)
        self._vehicle = Polygon(VEHICLE_OUTLINE, closed=True, color="tab:blue", zorder=3)
        ax.add_patch(self._vehicle)
        self._current = None
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        self._window = None

    def draw(
        self, track: np.ndarray, ocean_current: Sequence[float], *, title: str = ""
    ) -> np.ndarray:
        """The frame of ``track`` ``(T, 3)`` (true poses ``x, y, alpha``, the vehicle at the
        last) under ``ocean_current`` ``(oc_x, oc_y)``: ``(H, W, 3)`` uint8."""
        track = np.asarray(track, dtype=float).reshape(-1, 3)
        x, y, alpha = track[-1]
        xmin, xmax = min(track[:, 0].min(), -3.0) - 2.0, max(track[:, 0].max(), 1.0) + 2.0
        ymin, ymax = min(track[:, 1].min(), -2.0) - 2.0, max(track[:, 1].max(), 2.0) + 2.0
        ax = self.axes
        # equal scales on both axes: widen the shorter range to the canvas's shape
        width, height = self.axes.get_window_extent().size
        grow_y = (xmax - xmin) * height / width - (ymax - ymin)
        if grow_y > 0:
            ymin, ymax = ymin - grow_y / 2, ymax + grow_y / 2
        else:
            grow_x = (ymax - ymin) * width / height - (xmax - xmin)
            xmin, xmax = xmin - grow_x / 2, xmax + grow_x / 2
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        self._track.set_data(track[:, 0], track[:, 1])
        cos, sin = math.cos(alpha), math.sin(alpha)
        outline = VEHICLE_OUTLINE @ np.array([[cos, sin], [-sin, cos]]) + (x, y)
        self._vehicle.set_xy(outline)
        if self._current is not None:
            self._current.remove()
        oc_x, oc_y = (float(v) for v in ocean_current)
        start = (xmax - 6.0, ymin + 6.0)  # room for a 0.3 m/s current either way
        self._current = ax.annotate(
            "",
            xy=(start[0] + 15.0 * oc_x, start[1] + 15.0 * oc_y),
            xytext=start,
            arrowprops={"arrowstyle": "->", "color": "red", "lw": 2},
        )
        ax.set_title(f"{title}   oc = [{oc_x:.2f}, {oc_y:.2f}] m/s".strip(), fontsize=9)
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()

    def show(self, frame: np.ndarray) -> None:
        """Show ``frame`` in a matplotlib window (``render_mode="human"``), updated in place."""
        import matplotlib.pyplot as plt

        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*non-interactive.*")
            if self._window is None:
                self._window = plt.figure("dockingrl")
                ax = self._window.add_axes((0, 0, 1, 1))
                ax.axis("off")
                self._image = ax.imshow(frame)
                plt.show(block=False)
            else:
                self._image.set_data(frame)
            self._window.canvas.draw_idle()
            self._window.canvas.flush_events()

    def close(self) -> None:
        if self._window is not None:
            import matplotlib.pyplot as plt

            plt.close(self._window)
            self._window = None


def _outcome(record: dict) -> str:
    if record["success"]:
        return "success"
    return "docked, failed" if record["docked"] else "timeout"


def write_video(
    policy,
    scenario: str,
    path: str | Path,
    episodes: int = 3,
    *,
    seed: int = 0,
    every: int = 2,
    fps: int = 15,
    device: torch.device | str = "cpu",
    **env_kwargs,
) -> Path:
    """Run ``episodes`` episodes of ``policy`` (what :func:`dockingrl.evaluate` accepts) in
    ``scenario`` and write them one after the other as a video: a GIF (``.gif``, no ffmpeg
    needed) or an MP4 (``.mp4``, through ``imageio-ffmpeg``), chosen by ``path``'s suffix.

    The episodes are those of ``dockingrl.evaluate(policy, scenario, episodes, seed=seed,
    **env_kwargs)``: the same starts, currents and outcomes. Every ``every``-th step is a frame
    (with ``dt = 0.2`` s and the defaults, 6x real time); each episode's last frame, with its
    outcome, is held for a second. Returns the path, written atomically."""
    from dockingrl.evaluation import episode_record, run_episodes
    from dockingrl.scenarios import make_env

    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"video {path}: the suffix must be one of {', '.join(VIDEO_SUFFIXES)}")
    for name, value in (("episodes", episodes), ("every", every), ("fps", fps)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"write_video: {name} must be an integer >= 1, got {value!r}")
    import imageio.v2 as imageio

    env = make_env(scenario, episodes, seed=seed, device=device, **env_kwargs)
    config = env.base_env.config
    outcomes = run_episodes(policy, env, record_trajectories=True)
    renderer = DockingRenderer(config)
    repeat = env_kwargs.get("action_repeat", 1)  # env steps between two points of a track

    def frames():
        for i in range(episodes):
            record = episode_record(outcomes, i, config)
            track = np.asarray(record["path"])
            current = outcomes["ocean_current"][i].tolist()
            last = len(track) - 1
            for k in [*range(0, last, every), last]:
                seconds = min(k * repeat * config.dt, record["time_s"])
                title = f"{scenario}, episode {i + 1}/{episodes}, t = {seconds:.1f} s"
                if k == last:
                    title += f", {_outcome(record)}"
                frame = renderer.draw(track[: k + 1], current, title=title)
                yield from [frame] * (fps if k == last else 1)

    def write(tmp: Path) -> None:
        if path.suffix.lower() == ".gif":
            writer = imageio.get_writer(tmp, format="GIF", mode="I", duration=1000 / fps, loop=0)
        else:
            writer = imageio.get_writer(tmp, format="FFMPEG", mode="I", fps=fps)
        with writer:
            for frame in frames():
                writer.append_data(frame)

    return atomic_write(path, write)
