"""Logged sensor streams (docs/onboard.md): the format, a recorder that writes one from a
simulated approach, and the replay of a log through the onboard loop.

A log is a CSV file, one message per row, each sensor at its own rate::

    # dockingrl sensor log v1
    t,sensor,a,b
    0.0,usbl,20.31,0.412        # range (m), bearing (rad): eq. 2's rho, beta
    0.0,imu,0.105,-0.003        # heading (rad), yaw rate (rad/s): eq. 2's alpha, r
    0.0,dvl,0.0,0.0             # surge, sway through the water (m/s): eq. 2's u, v
    0.0,current,0.12,-0.05      # the current estimate in the station's frame (m/s)
    0.0,command,0.62,0.04       # optional: the command the vehicle sent (m/s, rad/s)

``t`` is the time of arrival in seconds, non-decreasing. The onboard loop runs at the control
step ``dt`` (0.2 s): at each tick, every message that arrived since the last tick is fresh
(its age 0, it updates the filter); a sensor without one keeps its last reading, aged by the
ticks since it arrived, and the filter predicts through it, as the training env's filter does
(docs/realism.md). The loop starts at the first tick by which every sensor and the current
have arrived. ``command`` rows are not read by the loop; the replay sets them beside its own.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import torch

from dockingrl.env.realism import SENSOR_OF_ENTRY, SENSORS
from dockingrl.io import atomic_write
from dockingrl.onboard.policy import OBS_DIM, OnboardPolicy

HEADER = "# dockingrl sensor log v1"
COLUMNS = ("t", "sensor", "a", "b")
#: the messages of a log: the three sensors of eq. 2, the current estimate, the sent command
MESSAGES = (*SENSORS, "current", "command")
#: which two entries of eq. 2's six each sensor's message holds, in its (a, b) order
ENTRIES = {
    sensor: tuple(i for i, s in enumerate(SENSOR_OF_ENTRY) if s == k)
    for k, sensor in enumerate(SENSORS)
}
#: a message counts as arrived by a tick when it is at most this late (float rounding of t)
_TICK_SLACK = 1e-6
#: s, the longest silence between two messages of a log: a vehicle silent longer than this has
#: no approach to replay (an episode of the paper's task lasts 120 s)
MAX_GAP_S = 60.0
#: s, the longest log a replay takes (18,000 control ticks): longer, its times are likely not
#: in seconds
MAX_SPAN_S = 3600.0


@dataclass
class SensorLog:
    """A log's messages by kind: ``times[kind]`` (s) and ``values[kind]`` (``(a, b)`` pairs)."""

    times: dict[str, list[float]] = field(default_factory=lambda: {m: [] for m in MESSAGES})
    values: dict[str, list[tuple[float, float]]] = field(
        default_factory=lambda: {m: [] for m in MESSAGES}
    )

    def add(self, t: float, kind: str, a: float, b: float) -> None:
        self.times[kind].append(float(t))
        self.values[kind].append((float(a), float(b)))

    def rows(self) -> list[tuple[float, str, float, float]]:
        """Every message, in order of arrival (stable within a time: the order added)."""
        rows = [
            (t, kind, a, b)
            for kind in MESSAGES
            for t, (a, b) in zip(self.times[kind], self.values[kind], strict=True)
        ]
        order = {kind: i for i, kind in enumerate(MESSAGES)}
        return sorted(rows, key=lambda r: (r[0], order[r[1]]))


def write_log(log: SensorLog, path: str | Path) -> Path:
    """Write ``log`` as CSV (floats as ``repr``: read back exactly), atomically."""

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="") as f:
            f.write(HEADER + "\n")
            writer = csv.writer(f)
            writer.writerow(COLUMNS)
            for t, kind, a, b in log.rows():
                writer.writerow((repr(t), kind, repr(a), repr(b)))

    return atomic_write(path, write)


def read_log(path: str | Path) -> SensorLog:
    """Read a log; ``ValueError`` (one line, naming the file and row) for anything else: a
    missing file, another header, an unknown sensor, a number that is not one or not finite,
    a negative range, times that go back, a silence over :data:`MAX_GAP_S` or a log longer than
    :data:`MAX_SPAN_S`."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"sensor log {path}: cannot read it ({exc})") from None
    lines = text.splitlines()
    if not lines or lines[0].strip() != HEADER:
        raise ValueError(f"sensor log {path}: not a dockingrl sensor log (first line {HEADER!r})")
    reader = csv.reader(lines[1:])
    if next(reader, None) != list(COLUMNS):
        raise ValueError(f"sensor log {path}: line 2 must be the columns {','.join(COLUMNS)}")
    log, first, last = SensorLog(), math.inf, -math.inf
    for number, row in enumerate(reader, start=3):
        where = f"sensor log {path}, line {number}"
        if len(row) != len(COLUMNS):
            raise ValueError(f"{where}: {len(COLUMNS)} fields expected, got {len(row)}")
        t, kind, a, b = row
        if kind not in MESSAGES:
            raise ValueError(f"{where}: unknown sensor {kind!r}; valid: {', '.join(MESSAGES)}")
        try:
            numbers = [float(t), float(a), float(b)]
        except ValueError:
            raise ValueError(f"{where}: t, a and b must be numbers, got {row}") from None
        if not all(math.isfinite(x) for x in numbers):
            raise ValueError(f"{where}: t, a and b must be finite, got {row}")
        if kind == "usbl" and numbers[1] < 0:
            raise ValueError(f"{where}: a usbl range (a, in m) must be >= 0, got {row}")
        if numbers[0] < last:
            raise ValueError(f"{where}: t {numbers[0]} is before the previous row's {last}")
        if math.isfinite(last) and numbers[0] - last > MAX_GAP_S:
            raise ValueError(
                f"{where}: t {numbers[0]} is {numbers[0] - last:g} s after the previous row's "
                f"{last}, a silence over {MAX_GAP_S:g} s (t is in seconds)"
            )
        if numbers[0] - first > MAX_SPAN_S:
            raise ValueError(
                f"{where}: t {numbers[0]} is {numbers[0] - first:g} s after the first row's "
                f"{first}; a replay takes at most {MAX_SPAN_S:g} s (t is in seconds)"
            )
        first = min(first, numbers[0])
        last = numbers[0]
        log.add(numbers[0], kind, numbers[1], numbers[2])
    if not any(log.times[kind] for kind in MESSAGES):
        raise ValueError(f"sensor log {path}: no messages")
    return log


@torch.no_grad()
def record_episode(
    policy: OnboardPolicy, env, *, max_steps: int | None = None
) -> tuple[SensorLog, torch.Tensor]:
    """Fly one approach of the bare env ``env`` (a :class:`~dockingrl.env.DockingEnv` of one
    env, seeded; its realism options set the sensors' rates) with ``policy`` acting on its
    readings, and log what the vehicle received: each sensor's reading when it arrived (age 0),
    the current estimate and the command sent, at every step. Returns the log and the ``(T,
    2)`` commands the env applied."""
    from tensordict import TensorDict

    if env.num_envs != 1:
        raise ValueError(f"record_episode flies one vehicle: env has {env.num_envs}")
    dt = env.config.dt
    out = env.reset()
    policy.reset()
    log, commands = SensorLog(), []
    steps = max_steps or env.config.max_steps
    for k in range(steps):
        t = k * dt
        z, current = out["observation"][0], out["ocean_current"][0]
        ages = out.get("sensor_age", torch.zeros(1, len(SENSORS)))[0]
        for s, sensor in enumerate(SENSORS):
            if float(ages[s]) == 0.0:
                i, j = ENTRIES[sensor]
                log.add(t, sensor, float(z[i]), float(z[j]))
        log.add(t, "current", float(current[0]), float(current[1]))
        sensor_age = ages if "sensor_age" in out.keys() else None
        command = policy.act(z, current, sensor_age)
        log.add(t, "command", float(command[0]), float(command[1]))
        commands.append(command.clone())
        td = TensorDict({"action": command.reshape(1, 2)}, batch_size=[1])
        out = env.step(td)["next"]
        if bool(out["done"].any()):
            break
    return log, torch.stack(commands)


@dataclass
class Replay:
    """What the onboard loop did over a log: one row per control tick."""

    times: list[float]
    commands: torch.Tensor  # (T, 2)
    means: torch.Tensor  # (T, n): the filter's estimate after the tick's update
    stds: torch.Tensor  # (T, n): the square roots of its covariance's diagonal
    logged_commands: torch.Tensor | None  # (T, 2) the log's commands at those ticks, if any


@dataclass
class Tick:
    """The loop's inputs at one control tick: ``z`` ``(6,)``, the ``current`` ``(2,)``, the
    sensors' ``ages`` ``(3,)`` (s) and the command the log says was sent then (``None`` if
    none)."""

    t: float
    z: torch.Tensor
    current: torch.Tensor
    ages: torch.Tensor
    logged_command: tuple[float, float] | None


def ticks(log: SensorLog, dt: float = 0.2):
    """The loop's inputs tick by tick over ``log`` at the control step ``dt`` (the module's
    docstring says how messages become readings); ``ValueError`` if a sensor or the current
    never arrives."""
    missing = [kind for kind in (*SENSORS, "current") if not log.times[kind]]
    if missing:
        raise ValueError(f"the log has no {', '.join(missing)} messages: the loop cannot start")
    first = max(log.times[kind][0] for kind in (*SENSORS, "current"))
    start = min(t for kind in MESSAGES for t in log.times[kind][:1])
    end = max(t for kind in MESSAGES for t in log.times[kind][-1:])
    cursor = {kind: 0 for kind in MESSAGES}
    latest: dict[str, tuple[float, float]] = {}
    arrived: dict[str, int] = {}
    tick = 0
    while start + tick * dt <= end + _TICK_SLACK:
        now = start + tick * dt
        for kind in MESSAGES:
            ts, i = log.times[kind], cursor[kind]
            while i < len(ts) and ts[i] <= now + _TICK_SLACK:
                latest[kind], arrived[kind] = log.values[kind][i], tick
                i += 1
            cursor[kind] = i
        if now + _TICK_SLACK >= first:
            z = torch.zeros(OBS_DIM)
            for sensor in SENSORS:
                for entry, value in zip(ENTRIES[sensor], latest[sensor], strict=True):
                    z[entry] = value
            # as the env counts them: whole ticks since arrival, times dt in float32
            ages = torch.tensor([tick - arrived[s] for s in SENSORS], dtype=torch.float32) * dt
            sent = latest.get("command") if arrived.get("command") == tick else None
            yield Tick(now, z, torch.tensor(latest["current"]), ages, sent)
        tick += 1


@torch.no_grad()
def replay(policy: OnboardPolicy, log: SensorLog, dt: float = 0.2) -> Replay:
    """Run the onboard loop (``policy``, from a new approach) over ``log`` at the control step
    ``dt``, tick by tick (:func:`ticks`)."""
    policy.reset()
    times, commands, means, stds, logged = [], [], [], [], []
    for tick in ticks(log, dt):
        try:
            command = policy.act(tick.z, tick.current, tick.ages)
        except RuntimeError as exc:  # a non-finite command: say which tick and readings
            z, current = (", ".join(f"{x:.4g}" for x in v.tolist()) for v in (tick.z, tick.current))
            raise RuntimeError(
                f"at t {tick.t:g} s, readings ({z}), current ({current}): {exc}"
            ) from None
        mean, cov = policy.filter_state
        times.append(tick.t)
        commands.append(command.clone())
        means.append(mean[0].clone())
        stds.append(torch.diagonal(cov[0]).clamp_min(0).sqrt())
        sent = tick.logged_command
        logged.append(torch.tensor(sent if sent is not None else (math.nan, math.nan)))
    logged_commands = torch.stack(logged) if log.times["command"] else None
    return Replay(
        times, torch.stack(commands), torch.stack(means), torch.stack(stds), logged_commands
    )


#: the names of the filter's state entries (eq. 22; the current's error with
#: ``estimate_current``)
STATE_NAMES = ("x", "y", "alpha", "nu", "w")
AUGMENTED_NAMES = (*STATE_NAMES, "current_error_x", "current_error_y")


def state_names(size: int) -> tuple[str, ...]:
    """The names of a filter state of ``size`` entries."""
    return STATE_NAMES if size == len(STATE_NAMES) else AUGMENTED_NAMES[:size]


def write_replay(result: Replay, path: str | Path) -> Path:
    """The replay as CSV: ``t``, the command sent (``v_d``, ``w_d``), the filter's estimate
    and its standard deviations (``std_<name>``) and, with a log that has them, the log's
    commands (``logged_v_d``, ``logged_w_d``). Written atomically."""

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="") as f:
            writer = csv.writer(f)
            names = state_names(result.means.shape[-1])
            header = ["t", "v_d", "w_d", *names, *(f"std_{n}" for n in names)]
            if result.logged_commands is not None:
                header += ["logged_v_d", "logged_w_d"]
            writer.writerow(header)
            for k, t in enumerate(result.times):
                row = [repr(t), *map(repr, result.commands[k].tolist())]
                row += [*map(repr, result.means[k].tolist()), *map(repr, result.stds[k].tolist())]
                if result.logged_commands is not None:
                    row += list(map(repr, result.logged_commands[k].tolist()))
                writer.writerow(row)

    return atomic_write(path, write)


__all__ = [
    "SensorLog",
    "Tick",
    "read_log",
    "record_episode",
    "replay",
    "ticks",
    "write_log",
    "write_replay",
]
