"""How the paper's vehicle model (eqs. 36-38) and the Fossen vehicle (docs/vehicles.md) answer
the same commands: step responses (0 to 0.8 m/s, 0 to -0.4 m/s, 0 to 0.3 rad/s, surge and yaw
together), a turning circle and the braking distance from 0.8 m/s. Both fly the batched env
(``dockingrl.DockingEnv``) with no current and no sensor noise, from rest far from the station.

    python scripts/vehicle_responses.py --out results/vehicle_responses

writes ``responses.json`` (every number) and ``responses.png`` (the figure).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict

from dockingrl.env import DockingConfig, DockingEnv
from dockingrl.io import write_json

VEHICLES = ("paper", "fossen")
#: the step responses: name -> the command (v_d, w_d) held from rest
STEPS = {
    "surge 0.8 m/s": (0.8, 0.0),
    "astern -0.4 m/s": (-0.4, 0.0),
    "yaw 0.3 rad/s": (0.0, 0.3),
    "surge 0.8 m/s and yaw 0.3 rad/s": (0.8, 0.3),
}
#: far from the station, heading away from it: nothing ends the runs
START = (-150.0, 0.0, math.pi)


def fly(vehicle: str, commands: np.ndarray) -> np.ndarray:
    """The true states ``(T + 1, 6)`` ``(x, y, alpha, u, v, r)`` of ``vehicle`` from rest at
    :data:`START` under the ``(T, 2)`` commands, one per 0.2 s step, with no current."""
    config = DockingConfig(vehicle=vehicle, noise=False, max_steps=len(commands) + 1)
    env = DockingEnv(1, config=config, seed=0)
    env.set_initial_state(torch.tensor(START), torch.zeros(2))
    states = [env._reset()["true_state"][0]]
    for command in commands:
        action = torch.as_tensor(command, dtype=torch.float32).reshape(1, 2)
        out = env._step(TensorDict({"action": action}, batch_size=[1]))
        if bool(out["terminated"]) or bool(out["truncated"]):
            raise RuntimeError(f"the {vehicle} run ended early; start it farther away")
        states.append(out["true_state"][0])
    return torch.stack(states).double().numpy()


def rise_time(t: np.ndarray, signal: np.ndarray, target: float) -> float | None:
    """The first time ``signal`` reaches 90 % of ``target`` (``None`` if it never does)."""
    reached = np.flatnonzero(signal * np.sign(target) >= 0.9 * abs(target))
    return round(float(t[reached[0]]), 3) if reached.size else None


def step_response(vehicle: str, command: tuple[float, float], seconds: float, dt: float) -> dict:
    """One step response: its time series and its rise times, final values and overshoot."""
    steps = round(seconds / dt)
    states = fly(vehicle, np.tile(np.array(command), (steps, 1)))
    t = np.arange(steps + 1) * dt
    u, r = states[:, 3], states[:, 5]
    out = {
        "t": t.tolist(),
        "u": u.tolist(),
        "v": states[:, 4].tolist(),
        "r": r.tolist(),
        "final_u": float(u[-1]),
        "final_r": float(r[-1]),
    }
    for name, signal, target in (("u", u, command[0]), ("r", r, command[1])):
        if target:
            out[f"rise_90_{name}_s"] = rise_time(t, signal, target)
            out[f"overshoot_{name}"] = float(
                max(0.0, np.max(signal * np.sign(target)) / abs(target) - 1)
            )
    return out


def turning_circle(vehicle: str, seconds: float, dt: float) -> dict:
    """``(0.8, 0.3)`` held from rest: the track, the steady radius (speed over yaw rate at the
    end) and the steady drift angle ``atan2(v, u)``."""
    steps = round(seconds / dt)
    states = fly(vehicle, np.tile(np.array((0.8, 0.3)), (steps, 1)))
    u, v, r = states[-1, 3:6]
    return {
        "x": states[:, 0].tolist(),
        "y": states[:, 1].tolist(),
        "radius_m": float(math.hypot(u, v) / abs(r)),
        "drift_angle_deg": float(math.degrees(math.atan2(v, u))),
        "speed_m_s": float(math.hypot(u, v)),
        "yaw_rate_rad_s": float(r),
    }


def braking(vehicle: str, command: float, dt: float, settle_s: float = 30.0) -> dict:
    """From a steady 0.8 m/s, the command ``(command, 0)``: the distance and time until the
    surge speed falls below 0.01 m/s."""
    settle, stop = round(settle_s / dt), round(60.0 / dt)
    commands = np.concatenate(
        [np.tile((0.8, 0.0), (settle, 1)), np.tile((command, 0.0), (stop, 1))]
    )
    states = fly(vehicle, commands)[settle:]
    stopped = np.flatnonzero(states[:, 3] < 0.01)
    if not stopped.size:
        return {"command": command, "distance_m": None, "time_s": None}
    end = stopped[0]
    distance = math.hypot(states[end, 0] - states[0, 0], states[end, 1] - states[0, 1])
    return {"command": command, "distance_m": round(distance, 3), "time_s": round(end * dt, 3)}


def measure(seconds: float = 20.0) -> dict:
    dt = DockingConfig().dt
    return {
        vehicle: {
            "steps": {name: step_response(vehicle, c, seconds, dt) for name, c in STEPS.items()},
            "turning_circle": turning_circle(vehicle, 90.0, dt),
            "braking": [braking(vehicle, 0.0, dt), braking(vehicle, -0.4, dt)],
        }
        for vehicle in VEHICLES
    }


def draw(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5))
    styles = {"paper": ("C0", "the paper's model"), "fossen": ("C3", "Fossen vehicle")}
    panels = [
        ("surge 0.8 m/s", "u", "surge u (m/s)"),
        ("astern -0.4 m/s", "u", "surge u (m/s)"),
        ("yaw 0.3 rad/s", "r", "yaw rate r (rad/s)"),
        ("surge 0.8 m/s and yaw 0.3 rad/s", "u", "u (m/s, solid), r (rad/s, dashed)"),
    ]
    for ax, (name, key, label) in zip(axes.flat[:4], panels, strict=True):
        for vehicle, (colour, text) in styles.items():
            run = results[vehicle]["steps"][name]
            ax.plot(run["t"], run[key], colour, label=text)
            if name.endswith("together") or "and yaw" in name:
                ax.plot(run["t"], run["r"], colour, linestyle="--")
        ax.set(title=f"command: {name}", xlabel="t (s)", ylabel=label)
        ax.grid(alpha=0.3)
    axes.flat[0].legend()
    ax = axes.flat[4]
    for vehicle, (colour, text) in styles.items():
        run = results[vehicle]["turning_circle"]
        ax.plot(run["x"], run["y"], colour, label=f"{text}: R = {run['radius_m']:.2f} m")
    ax.set(title="turning circle: (0.8 m/s, 0.3 rad/s) from rest", xlabel="x (m)", ylabel="y (m)")
    ax.set_aspect("equal")
    ax.legend(fontsize=8)
    ax = axes.flat[5]
    labels, width = ["command 0", "full astern (-0.4)"], 0.35
    for k, (vehicle, (colour, text)) in enumerate(styles.items()):
        values = [b["distance_m"] or 0.0 for b in results[vehicle]["braking"]]
        ax.bar(np.arange(2) + (k - 0.5) * width, values, width, color=colour, label=text)
    ax.set_xticks(range(2), labels)
    ax.set(title="braking distance from 0.8 m/s (to < 0.01 m/s)", ylabel="distance (m)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder for the JSON and PNG")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of a step response")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    start = time.perf_counter()
    results = measure(args.seconds)
    args.out.mkdir(parents=True, exist_ok=True)
    draw(results, args.out / "responses.png")
    results["wall_clock_s"] = round(time.perf_counter() - start, 1)
    results["command"] = "python scripts/vehicle_responses.py " + " ".join(argv or sys.argv[1:])
    write_json(args.out / "responses.json", results)
    for vehicle in VEHICLES:
        steps, turn = results[vehicle]["steps"], results[vehicle]["turning_circle"]
        rises = ", ".join(
            f"{name}: {run.get('rise_90_u_s', run.get('rise_90_r_s'))} s"
            for name, run in steps.items()
        )
        brakes = ", ".join(
            f"{b['command']:+.1f}: {b['distance_m']} m" for b in results[vehicle]["braking"]
        )
        print(f"{vehicle}: 90 % rise {rises}; turn R {turn['radius_m']:.2f} m; braking {brakes}")
    print(f"wall-clock {results['wall_clock_s']} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
