"""The Fossen vehicle (dockingrl.env.fossen): an independent RK4 integration of the same
equations, physical checks, the realism options on it and its place in the env."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.optimize import brentq

from dockingrl.env import DockingConfig, DockingEnv
from dockingrl.env.fossen import (
    SPARUS_II,
    FossenVehicle,
    allocate_thrust,
    body_acceleration,
    command_from_thrust,
    hydrodynamics,
    mass_matrix,
    spheroid_added_mass,
    strip_positions,
    strip_tensors,
    thrust_from_command,
)
from dockingrl.env.levels import LEVELS, level_config

VEHICLE = SPARUS_II
DT = 0.2


class Reference:
    """The Fossen vehicle's equations written again in numpy, float64: the controller held over
    each substep as in the env, the continuous thrusters, body and pose integrated by RK4 at a
    step ``fine`` times smaller."""

    def __init__(self, vehicle: FossenVehicle, fine: int = 20):
        self.p = vehicle
        self.m = mass_matrix(vehicle)
        self.minv = np.linalg.inv(self.m)
        self.x = strip_positions(vehicle)
        self.dx = vehicle.length / vehicle.strips
        self.fine = fine
        rho = vehicle.water_density
        self.xuu = 0.5 * rho * vehicle.surge_drag_coefficient * math.pi * vehicle.diameter**2 / 4
        self.cd = 0.5 * rho * vehicle.crossflow_drag_coefficient * vehicle.diameter
        self.t_rev = vehicle.forward_thrust * vehicle.reverse_thrust_ratio

    def drag(self, v, r):
        w = v + self.x * r
        f = np.abs(w) * w * self.dx * self.cd
        return f.sum(), (f * self.x).sum()

    def derivative(self, state, target, current):
        x, y, psi, u, v, r, tp, ts = state
        p, m = self.p, self.m
        fx, fn = tp + ts, p.thruster_y * (ts - tp)
        dy, dn = self.drag(v, r)
        m11, m22, m23 = m[0, 0], m[1, 1], m[1, 2]
        coriolis = np.array(
            [-(m22 * v + m23 * r) * r, m11 * u * r, (m22 * v + m23 * r) * u - m11 * u * v]
        )
        damping = np.array(
            [
                p.surge_linear_damping * u + self.xuu * abs(u) * u,
                p.sway_linear_damping * v + dy,
                p.yaw_linear_damping * r + dn,
            ]
        )
        acc = self.minv @ (np.array([fx, 0.0, fn]) - coriolis - damping)
        c, s = math.cos(psi), math.sin(psi)
        lag = (np.asarray(target) - np.array([tp, ts])) / p.thruster_time_constant
        return np.array([c * u - s * v + current[0], s * u + c * v + current[1], r, *acc, *lag])

    def control(self, action, u, r, integral):
        p = self.p
        e_u, e_r = action[0] - u, action[1] - r
        cubes = (np.abs(self.x) ** 3).sum() * self.dx * self.cd
        want_x = p.surge_linear_damping * action[0] + self.xuu * abs(action[0]) * action[0]
        want_x += p.surge_kp * e_u + p.surge_ki * integral[0]
        want_n = p.yaw_linear_damping * action[1] + cubes * abs(action[1]) * action[1]
        want_n += p.yaw_kp * e_r + p.yaw_ki * integral[1]
        span = (p.forward_thrust + self.t_rev) / 2
        delta = np.clip(want_n / (2 * p.thruster_y), -span, span)
        common = np.clip(want_x / 2, -self.t_rev + abs(delta), p.forward_thrust - abs(delta))
        got_x, got_n = 2 * common, 2 * p.thruster_y * delta
        h = DT / p.substeps
        if not (want_x - got_x) * e_u > 0:
            integral[0] += h * e_u
        if not (want_n - got_n) * e_r > 0:
            integral[1] += h * e_r
        return (common - delta, common + delta)

    def step(self, state, integral, action, current):
        h = DT / self.p.substeps
        for _ in range(self.p.substeps):
            target = self.control(action, state[3], state[5], integral)
            k = h / self.fine
            for _ in range(self.fine):
                a = self.derivative(state, target, current)
                b = self.derivative(state + k / 2 * a, target, current)
                c = self.derivative(state + k / 2 * b, target, current)
                d = self.derivative(state + k * c, target, current)
                state = state + k / 6 * (a + 2 * b + 2 * c + d)
        return state


def fossen_env(n=1, **changes):
    return DockingEnv(n, config=DockingConfig(vehicle="fossen", noise=False, **changes), seed=0)


def _vehicle_state(env) -> tuple[np.ndarray, list[float]]:
    """The env's (first) vehicle as the reference's state and integrals, float64."""
    parts = (env._pose[0], env._velocity[0], env._thrust[0])
    return np.concatenate([p.double().numpy() for p in parts]), env._integral[0].tolist()


def test_the_env_integrates_the_equations_as_an_independent_rk4_does():
    """Step by step over 30 s of manoeuvres, each env step (Heun at 0.1 s) from the env's own
    state against RK4 at 5 ms from the same state: pose and velocity agree to the integrator's
    error. The thrusters agree to 1e-2 N on nearly every step (the second substep's targets
    follow the first substep's velocity, which the two integrators give 1e-4 apart); on a few
    the controller's switches (anti-windup, saturation) fall on the other side for that
    difference, and the thrust differs by a fraction of a newton."""
    env = fossen_env()
    env.set_initial_state(torch.tensor([[-28.0, 4.0, 0.3]]), torch.tensor([[0.15, -0.2]]))
    env.reset()
    reference = Reference(VEHICLE)
    rng = np.random.default_rng(0)
    worst, thrust_error = np.zeros(6), []
    for step in range(150):
        if step % 10 == 0:
            action = (rng.uniform(-0.4, 0.8), rng.uniform(-0.3, 0.3))
        state, integral = _vehicle_state(env)
        want = reference.step(state, integral, action, (0.15, -0.2))
        env._step(_action(action))
        got, _ = _vehicle_state(env)
        diff = np.abs(got - want)
        diff[2] = abs(math.remainder(got[2] - want[2], 2 * math.pi))
        worst = np.maximum(worst, diff[:6])
        thrust_error.append(diff[6:].max())
    assert worst[:3].max() < 1e-3, worst
    assert worst[3:].max() < 2e-3, worst
    thrust_error = np.array(thrust_error)
    assert (thrust_error < 1e-2).mean() > 0.8, thrust_error
    assert thrust_error.max() < 0.5, thrust_error


def _action(action):
    from tensordict import TensorDict

    return TensorDict({"action": torch.tensor([action], dtype=torch.float32)}, batch_size=[1])


def test_without_thrust_or_current_the_kinetic_energy_only_decays():
    hydro = hydrodynamics(VEHICLE, DT)
    strips = strip_tensors(VEHICLE, dtype=torch.float64)
    mass = torch.tensor(mass_matrix(VEHICLE))
    rng = torch.Generator().manual_seed(0)
    velocity = (torch.rand(256, 3, generator=rng, dtype=torch.float64) - 0.5) * 2
    zero = torch.zeros(256, 2, dtype=torch.float64)
    # the Coriolis-centripetal terms do no work: nu . M nu' = -nu . D(nu) nu
    acc = body_acceleration(velocity, zero, hydro, strips)
    power = (velocity * (acc @ mass.T)).sum(-1)
    undamped = hydro._replace(
        surge_linear=0.0, surge_quadratic=0.0, sway_linear=0.0, yaw_linear=0.0, crossflow=0.0
    )
    coriolis_power = velocity * (body_acceleration(velocity, zero, undamped, strips) @ mass.T)
    assert coriolis_power.sum(-1).abs().max() < 1e-12
    assert (power < 0).all()
    # coasting down with the env's integrator, the energy falls every substep
    h = DT / VEHICLE.substeps
    energy = []
    nu = torch.tensor([[1.0, 0.3, 0.4]], dtype=torch.float64)
    for _ in range(300):
        energy.append(float(0.5 * nu[0] @ mass @ nu[0]))
        a = body_acceleration(nu, zero[:1], hydro, strips)
        b = body_acceleration(nu + h * a, zero[:1], hydro, strips)
        nu = nu + 0.5 * h * (a + b)
    assert all(later < earlier for earlier, later in zip(energy, energy[1:], strict=False))
    assert energy[-1] < 1e-3 * energy[0]


def test_the_steady_surge_at_full_thrust_balances_thrust_and_drag():
    hydro = hydrodynamics(VEHICLE, DT)
    strips = strip_tensors(VEHICLE, dtype=torch.float64)
    full = torch.tensor([[2 * VEHICLE.forward_thrust, 0.0]], dtype=torch.float64)
    nu = torch.zeros(1, 3, dtype=torch.float64)
    for _ in range(2000):
        nu = nu + 0.05 * body_acceleration(nu, full, hydro, strips)
    a, b, c = hydro.surge_quadratic, hydro.surge_linear, -2 * VEHICLE.forward_thrust
    balance = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)
    assert nu[0, 0].item() == pytest.approx(balance, rel=1e-6)
    assert 1.2 < balance < 1.6  # the estimate's top speed, about 1.4 m/s
    assert abs(nu[0, 1].item()) < 1e-9 and abs(nu[0, 2].item()) < 1e-9


def test_a_steady_turn_has_the_radius_of_its_sway_balance():
    env = fossen_env()
    env.set_initial_state(torch.tensor([[-60.0, 20.0, 0.0]]), torch.zeros(1, 2))
    env.reset()
    poses, velocities = [], []
    for _ in range(400):
        out = env._step(_action((0.5, 0.2)))
        poses.append(out["true_state"][0, :2].double().numpy())
        velocities.append(out["true_state"][0, 3:].double().numpy())
    u, v, r = velocities[-1]
    assert u == pytest.approx(0.5, abs=2e-3) and r == pytest.approx(0.2, abs=2e-3)
    # at steady state the sway row of the model is a balance of the centripetal term and drag
    hydro = hydrodynamics(VEHICLE, DT)
    x, dx = strip_positions(VEHICLE), VEHICLE.length / VEHICLE.strips

    def sway(side):
        w = side + x * 0.2
        drag = hydro.crossflow * VEHICLE.diameter * dx * (np.abs(w) * w).sum()
        return -hydro.m11 * 0.5 * 0.2 - hydro.sway_linear * side - drag

    side = brentq(sway, -1.0, 1.0)
    assert v == pytest.approx(side, abs=2e-3)
    assert side < -0.01  # a turn to port slips to starboard, outwards
    expected = math.hypot(0.5, side) / 0.2
    # the circle through the last 30 s of the path (algebraic least-squares fit)
    points = np.array(poses[-150:])
    design = np.column_stack((2 * points, np.ones(len(points))))
    (cx, cy, k), *_ = np.linalg.lstsq(design, (points**2).sum(1), rcond=None)
    radius = math.sqrt(k + cx * cx + cy * cy)
    assert radius == pytest.approx(expected, rel=0.01)


def test_a_vehicle_at_rest_drifts_with_the_current():
    env = fossen_env()
    env.set_initial_state(torch.tensor([[-28.0, 3.0, 0.7]]), torch.tensor([[0.2, -0.15]]))
    env.reset()
    for _ in range(100):
        out = env._step(_action((0.0, 0.0)))
    state = out["true_state"][0]
    assert state[3:].abs().max() < 1e-6  # no motion through the water
    assert state[0].item() == pytest.approx(-28.0 + 0.2 * 20, abs=1e-4)
    assert state[1].item() == pytest.approx(3.0 - 0.15 * 20, abs=1e-4)
    assert state[2].item() == pytest.approx(0.7, abs=1e-6)


def test_the_added_mass_of_a_slender_spheroid():
    x_udot, y_vdot, n_rdot = spheroid_added_mass(1.6, 0.23, 1025.0)
    displaced = 4 / 3 * math.pi * 1025.0 * 0.8 * 0.115**2
    # slender body: little added mass along the axis, nearly the displaced mass across it
    assert 0.02 < -x_udot / displaced < 0.06
    assert 0.9 < -y_vdot / displaced < 1.0
    inertia = displaced * (0.8**2 + 0.115**2) / 5
    assert 0.7 < -n_rdot / inertia < 0.95
    # a sphere's added mass is half its displaced mass on every axis
    sphere = spheroid_added_mass(1.0, 1.0 - 1e-6, 1000.0)
    half = 0.5 * 4 / 3 * math.pi * 1000.0 * 0.5**3
    assert -sphere[0] == pytest.approx(half, rel=1e-3)
    assert -sphere[1] == pytest.approx(half, rel=1e-3)


def test_the_thrust_curve_is_weaker_astern_and_its_inverse_holds():
    command = torch.linspace(-1, 1, 41)
    thrust = thrust_from_command(command, 20.0, 9.0)
    assert thrust[-1].item() == 20.0 and thrust[0].item() == -9.0
    back = command_from_thrust(thrust, 20.0, 9.0)
    assert torch.allclose(back, command, atol=1e-6)
    assert command_from_thrust(torch.tensor([50.0, -50.0]), 20.0, 9.0).tolist() == [1.0, -1.0]


def test_the_allocation_keeps_the_yaw_moment_first_within_the_thrusters():
    x = torch.tensor([40.0, 40.0, 0.0, -30.0])
    n = torch.tensor([0.0, 3.0, 10.0, 0.0])
    thrust, got_x, got_n = allocate_thrust(x, n, 0.17, 20.0, 9.0)
    assert (thrust <= 20.0 + 1e-6).all() and (thrust >= -9.0 - 1e-6).all()
    assert got_n[1].item() == pytest.approx(3.0)  # the moment kept, the surge force given up
    assert got_x[1].item() < 40.0
    # the largest moment needs one thruster ahead and one astern: weak reverse forces surge on
    assert got_n[2].item() == pytest.approx(0.17 * 29.0)
    assert got_x[2].item() == pytest.approx(11.0)
    assert got_x[3].item() == pytest.approx(-18.0)
    assert torch.allclose(thrust.sum(-1), got_x)


@pytest.mark.parametrize("level", [name for name in LEVELS if name != "L0"])
def test_the_realism_levels_fly_the_fossen_vehicle(level):
    config = level_config(level).replace(vehicle="fossen")
    if level.startswith("L"):
        assert level_config(level).vehicle == "paper"
    env = DockingEnv(32, config=config, seed=1)
    rollout = env.rollout(200, break_when_any_done=False)
    assert torch.isfinite(rollout["next", "observation"]).all()
    paper = config.replace(vehicle="paper", scale_fossen=True)  # M5F spares the Fossen vehicle
    plain = DockingEnv(32, config=paper, seed=1).rollout(
        200, policy=_fixed_policy, break_when_any_done=False
    )
    flown = DockingEnv(32, config=config, seed=1).rollout(
        200, policy=_fixed_policy, break_when_any_done=False
    )
    # the same starts, another vehicle
    assert torch.equal(plain[:, 0]["true_state"], flown[:, 0]["true_state"])
    assert not torch.allclose(plain["next", "true_state"], flown["next", "true_state"])


def _fixed_policy(td):
    return td.set("action", torch.tensor([[0.6, 0.1]]).expand(td.batch_size[0], 2).clone())


def test_the_dynamics_scales_act_on_the_fossen_vehicle():
    heavy = fossen_env(mass_scale=(2.0, 2.0))
    light = fossen_env()
    for env in (heavy, light):
        env.set_initial_state(torch.tensor([[-28.0, 0.0, 0.0]]), torch.zeros(1, 2))
        env.reset()
    for _ in range(5):
        slow = heavy._step(_action((0.8, 0.0)))["true_state"][0, 3].item()
        fast = light._step(_action((0.8, 0.0)))["true_state"][0, 3].item()
    assert slow < 0.8 * fast
    weak = fossen_env(reverse_thrust_loss=0.5)
    weak.reset()
    assert weak._fossen_hydro.reverse.max().item() == pytest.approx(0.5 * 9.0)


def test_the_fossen_vehicle_can_fly_as_identified_beside_a_scaled_paper_model():
    """M5F: the dynamics scales act on the paper's model only; the Fossen episodes fly as
    its env without scales does, step for step."""
    options = dict(mass_scale=(2.0, 2.0), response_time_scale=(3.0, 3.0), noise=False)
    unscaled = dict(options, scale_fossen=False)
    envs = {
        "mixed": DockingEnv(64, config=DockingConfig(vehicle="mixed", **unscaled), seed=5),
        "fossen": DockingEnv(64, config=DockingConfig(vehicle="fossen", noise=False), seed=5),
        "scaled": DockingEnv(64, config=DockingConfig(vehicle="fossen", **options), seed=5),
        "paper": DockingEnv(64, config=DockingConfig(**options), seed=5),
    }
    states = {}
    for name, env in envs.items():
        env.set_initial_state(torch.tensor([[-28.0, 0.0, 0.0]]).expand(64, 3), torch.zeros(64, 2))
        run = env.rollout(20, policy=_fixed_policy, break_when_any_done=False)
        states[name] = run["next", "true_state"]
    on = envs["mixed"].on_fossen[:, 0]
    assert on.any() and (~on).any()
    assert torch.equal(states["mixed"][on], states["fossen"][on])
    assert not torch.allclose(states["scaled"][on], states["fossen"][on])
    assert torch.equal(states["mixed"][~on], states["paper"][~on])
    level = level_config("M5F")
    assert level.vehicle == "mixed" and not level.scale_fossen and level.dynamics_mismatch


def test_mixed_episodes_fly_each_vehicle_as_its_own_env_does():
    n = 400
    mixed = DockingEnv(n, config=DockingConfig(vehicle="mixed", noise=False), seed=3)
    paper = DockingEnv(n, config=DockingConfig(noise=False), seed=3)
    fossen = DockingEnv(n, config=DockingConfig(vehicle="fossen", noise=False), seed=3)
    runs = [
        env.rollout(50, policy=_fixed_policy, break_when_any_done=False)
        for env in (mixed, paper, fossen)
    ]
    on = mixed.on_fossen[:, 0]
    assert 0.4 < on.float().mean().item() < 0.6
    states = [run["next", "true_state"] for run in runs]
    assert torch.equal(states[0][on], states[2][on])
    assert torch.equal(states[0][~on], states[1][~on])
    everyone = DockingEnv(8, config=DockingConfig(vehicle="mixed", fossen_fraction=1.0), seed=0)
    everyone.reset()
    assert everyone.on_fossen.all()


def test_compile_step_compiles_the_mixed_vehicles_step_to_the_eager_numbers():
    """``compile_step`` compiles the Fossen and mixed vehicles' step too, not only the paper
    model's. From the same starts its first steps give the eager numbers up to rounding (further
    on, the thrusters' quantised commands can turn a rounding difference into a step of thrust,
    so long rollouts part)."""
    config = level_config("M5F")
    eager, fast = (DockingEnv(64, config=config, seed=5, compile_step=c) for c in (False, True))
    runs = [
        env.rollout(3, policy=_fixed_policy, break_when_any_done=False) for env in (eager, fast)
    ]
    on = fast.on_fossen[:, 0]
    assert torch.equal(on, eager.on_fossen[:, 0]) and on.any() and (~on).any()
    for key in ("true_state", "observation", "reward"):
        torch.testing.assert_close(runs[1]["next", key], runs[0]["next", key], rtol=1e-4, atol=1e-4)
    states = [env.get_state() for env in (eager, fast)]  # thrusters and both PIs' state too
    torch.testing.assert_close(states[1], states[0], rtol=1e-4, atol=1e-4)
    assert fast._thrust[on].abs().sum() > 0 and fast._thrust[~on].abs().sum() == 0
    assert hasattr(fast._fossen_transition, "_torchdynamo_orig_callable")  # compiled
    assert not hasattr(eager._fossen_transition, "_torchdynamo_orig_callable")


def test_a_state_round_trip_keeps_the_thrusters():
    env = fossen_env(4)
    env.rollout(20, policy=_fixed_policy, break_when_any_done=False)
    state = env.get_state()
    assert state["realism", "thrust"].abs().sum() > 0
    after = env._step(_action_n((0.3, -0.2), 4))["true_state"]
    env.set_state(state)
    again = env._step(_action_n((0.3, -0.2), 4))["true_state"]
    assert torch.equal(after, again)


def test_simulate_steps_the_fossen_vehicle_as_the_env_does():
    env = fossen_env(4)
    env.rollout(20, policy=_fixed_policy, break_when_any_done=False)
    state = env.get_state()
    action = torch.tensor([[0.8, 0.3], [-0.4, -0.3], [0.2, 0.0], [1.5, -2.0]])
    next_state, out = env.simulate(state, action)
    td = env._step(_action_n((0.0, 0.0), 4).set("action", action))
    torch.testing.assert_close(
        torch.cat((next_state["pose"], next_state["velocity"]), -1), td["true_state"]
    )
    for key in ("reward", "terminated", "success", "contact_score", "contact_speed"):
        torch.testing.assert_close(out[key], td[key])
    after = env.get_state()
    torch.testing.assert_close(after["realism", "thrust"], next_state["realism", "thrust"])
    torch.testing.assert_close(after["integral"], next_state["integral"])
    # a batch of another size (a planner's samples) steps too
    many = state.unsqueeze(1).expand(4, 3).reshape(12).clone()
    wide, _ = env.simulate(many, action.repeat_interleave(3, 0))
    torch.testing.assert_close(wide["pose"][::3], next_state["pose"])
    with pytest.raises(ValueError, match="nominal Fossen vehicle"):
        fossen_env(4, mass_scale=(0.9, 1.1)).simulate(state, action)
    mixed = DockingEnv(4, config=DockingConfig(vehicle="mixed", noise=False), seed=0)
    with pytest.raises(ValueError, match="vehicle='mixed'"):
        mixed.simulate(state, action)


def _action_n(action, n):
    from tensordict import TensorDict

    value = torch.tensor([action], dtype=torch.float32).expand(n, 2).clone()
    return TensorDict({"action": value}, batch_size=[n])


def test_bad_vehicle_options_are_refused_in_one_line():
    with pytest.raises(ValueError, match=r"DockingConfig.vehicle: unknown vehicle; valid: paper"):
        DockingConfig(vehicle="boat")
    with pytest.raises(ValueError, match="DockingConfig.vehicle: must be a string"):
        DockingConfig(vehicle=3)
    with pytest.raises(ValueError, match="fossen_fraction"):
        DockingConfig(vehicle="mixed", fossen_fraction=1.5)
    with pytest.raises(ValueError, match="DockingConfig.scale_fossen: False only spares"):
        DockingConfig(scale_fossen=False, mass_scale=(0.7, 1.3))  # the paper's model only
    with pytest.raises(ValueError, match="DockingConfig.scale_fossen: False only spares"):
        DockingConfig(vehicle="fossen", scale_fossen=False)  # no dynamics scale to spare it
    with pytest.raises(ValueError, match="FossenVehicle.mass: must be > 0"):
        FossenVehicle(mass=0.0)
    with pytest.raises(ValueError, match="FossenVehicle.diameter"):
        FossenVehicle(diameter=2.0)


def test_the_paper_vehicle_is_unchanged_by_the_option():
    a = DockingEnv(16, seed=5).rollout(100, policy=_fixed_policy, break_when_any_done=False)
    config = DockingConfig(vehicle="paper", fossen_fraction=0.9)
    b = DockingEnv(16, config=config, seed=5).rollout(
        100, policy=_fixed_policy, break_when_any_done=False
    )
    assert torch.equal(a["next", "observation"], b["next", "observation"])


def test_eval_and_stress_fly_the_chosen_vehicle(tmp_path, capsys):
    import json

    from dockingrl.cli import main

    common = ["--episodes", "16", "--quiet", "--threads", "1"]
    for vehicle in ("paper", "fossen"):
        out = tmp_path / vehicle
        assert main(["eval", *common, "--vehicle", vehicle, "--out", str(out)]) == 0
    rates = [json.loads((tmp_path / v / "eval.json").read_text()) for v in ("paper", "fossen")]
    assert rates[0]["total_reward"] != rates[1]["total_reward"]
    assert main(["stress", "--episodes", "8", "--levels", "L0,F0", "--vehicle", "fossen"]) == 0
    table = capsys.readouterr().out
    assert "| L0 |" in table and "| F0 |" in table
    with pytest.raises(SystemExit):
        main(["eval", "--vehicle", "boat"])
    assert "invalid choice: 'boat'" in capsys.readouterr().err
