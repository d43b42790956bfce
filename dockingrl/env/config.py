"""Every constant of the docking task, in one validated dataclass.

Values are the paper's (Sec. 3-4.1, Tables 2 and 3) unless marked *chosen*: the paper does not
give the PID gains nor the yaw inertia of its simulated vehicle; ours are chosen so that the
closed-loop step response of surge and yaw rate follows the first-order model the EKF assumes
(eq. 24, k = 2.5 1/s). ``tests/test_env.py::test_step_response_matches_first_order_model``
measures that choice.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import numbers
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


def _real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


class Bound(NamedTuple):
    """The physically sensible values of one config number: ``low`` to ``high`` (``low``
    itself excluded when ``open_low``), in ``unit``, for the reason ``why``."""

    low: float
    high: float
    unit: str
    why: str = ""
    open_low: bool = False

    def holds(self, value: float) -> bool:
        return (self.low < value if self.open_low else self.low <= value) and value <= self.high

    def describe(self) -> str:
        interval = f"{'(' if self.open_low else '['}{self.low:g}, {self.high:g}]"
        unit = f" {self.unit}" if self.unit else ""
        return f"must lie in {interval}{unit}" + (f": {self.why}" if self.why else "")


_GAIN = Bound(0.0, 1e6, "", "PID gain, N or N m per unit of velocity error (or its integral)")
_POSITION = Bound(-1e4, 1e4, "m", "10 km, beyond a USBL's range")
_WEIGHT = Bound(0.0, 1e6, "", "reward weight")

#: The per-episode (low, high) factors of the dynamics-mismatch options.
SCALE_RANGES = (
    "mass_scale",
    "damping_scale",
    "thrust_scale",
    "pid_gain_scale",
    "response_time_scale",
)

#: The accepted range of every number of :class:`DockingConfig` (each entry of a pair), with
#: its reason. Every accepted config keeps the simulation finite in float32: the long rollouts of
#: ``tests/test_validation.py`` at the extreme values show it. The paper's values lie well inside.
BOUNDS: dict[str, Bound] = {
    "dt": Bound(
        1e-3,
        0.5,
        "s",
        "the explicit-Euler velocity loops (the env's PID, the EKF's eq. 24 with k = 2.5 1/s) "
        "diverge from about 0.7 s",
    ),
    "max_steps": Bound(1, 1_000_000, "steps", "55 h at dt = 0.2 s, longer than any approach"),
    "surge_command_min": Bound(-10.0, 10.0, "m/s"),
    "surge_command_max": Bound(-10.0, 10.0, "m/s"),
    "yaw_rate_command_max": Bound(0.0, 10.0, "rad/s", open_low=True),
    "mass": Bound(1.0, 1e5, "kg", "a 1 kg micro-AUV to a 100 t vehicle"),
    "yaw_inertia": Bound(1e-2, 1e7, "kg m^2", "a 1 kg micro-AUV to a 100 t vehicle"),
    "linear_damping": Bound(0.0, 1e5, "N s/m"),
    "quadratic_damping": Bound(0.0, 1e5, "N s^2/m^2"),
    "max_acceleration": Bound(0.0, 100.0, "m/s^2", "10 g", open_low=True),
    "max_velocity": Bound(0.0, 10.0, "m/s", "twice the fastest AUVs'", open_low=True),
    "max_thrust": Bound(0.0, 1e6, "N", open_low=True),
    "surge_kp": _GAIN,
    "surge_ki": _GAIN,
    "surge_kd": _GAIN,
    "yaw_kp": _GAIN,
    "yaw_ki": _GAIN,
    "yaw_kd": _GAIN,
    "init_x": _POSITION,
    "init_y": _POSITION,
    "init_heading": Bound(-math.pi, math.pi, "rad"),
    "ocean_current_range": Bound(-5.0, 5.0, "m/s", "the strongest tidal streams reach 5 m/s"),
    "following_current_fraction": Bound(0.0, 1.0, "", "a probability"),
    "lateral_current_fraction": Bound(0.0, 1.0, "", "a probability"),
    "near_start_fraction": Bound(0.0, 1.0, "", "a probability"),
    "near_start_x": _POSITION,
    "near_start_y": _POSITION,
    "range_noise_fraction": Bound(
        0.0,
        0.125,
        "of the range",
        "a reading rho (1 + sigma N) goes negative only for N < -1/sigma, 8 sigma away at "
        "0.125 (odds 6e-16 a reading); Table 2 gives 0.025",
    ),
    "bearing_noise": Bound(
        0.0, math.pi / 4, "rad", "45 deg; the wrapped reading of a wider sigma says little"
    ),
    "heading_noise": Bound(
        0.0, math.pi / 4, "rad", "45 deg; the wrapped reading of a wider sigma says little"
    ),
    "velocity_noise": Bound(0.0, 1.0, "m/s", "the vehicle's top speed; Table 2 gives 0.02"),
    "yaw_rate_noise": Bound(0.0, 1.0, "rad/s", "the vehicle's top yaw rate; Table 2 gives 0.0035"),
    "max_dist": Bound(0.1, 1e4, "m", "the distance of eq. 4's normalisation"),
    "thrust_weight": Bound(1e-3, 1e6, "N", "the divisor of eq. 5"),
    "entry_speed_max": Bound(0.0, 10.0, "m/s", open_low=True),
    "approach_distance": Bound(1e-2, 1e4, "m", "the divisor of eq. 6"),
    "entry_speed_weight": _WEIGHT,
    "aligned_weight": _WEIGHT,
    "misaligned_weight": _WEIGHT,
    "contact_weight": Bound(0.0, 1e6, "", "reward weight", open_low=True),
    "dock_x": _POSITION,
    "dock_y": _POSITION,
    "contact_speed_tolerance": Bound(0.0, 10.0, "m/s"),
    "usbl_period": Bound(0.0, 60.0, "s", "0 (every step) or a whole number of steps"),
    "usbl_latency": Bound(0.0, 5.0, "s", "0 or a whole number of steps"),
    "usbl_dropout_probability": Bound(
        0.0, 0.95, "", "a fraction of the fixes; at 1 the USBL would never report"
    ),
    "usbl_dropout_burst": Bound(0.0, 1000.0, "fixes", "0 (independent losses) or >= 1"),
    "usbl_outlier_probability": Bound(0.0, 1.0, "", "a probability"),
    "usbl_outlier_distance": Bound(0.0, 1e3, "m"),
    "dvl_period": Bound(0.0, 60.0, "s", "0 (every step) or a whole number of steps"),
    "imu_period": Bound(0.0, 60.0, "s", "0 (every step) or a whole number of steps"),
    "current_time_constant": Bound(0.0, 1e6, "s", "0 keeps the current constant"),
    "current_variation_std": Bound(0.0, 2.0, "m/s"),
    "current_knowledge_bias": Bound(0.0, 2.0, "m/s"),
    "current_knowledge_noise": Bound(0.0, 2.0, "m/s"),
    "mass_scale": Bound(0.1, 10.0, "", "a factor on mass and yaw inertia"),
    "damping_scale": Bound(0.0, 10.0, "", "a factor on K_dl and K_qdl"),
    "thrust_scale": Bound(0.0, 10.0, "", "a factor on max_thrust", open_low=True),
    "pid_gain_scale": Bound(0.0, 10.0, "", "a factor on every PID gain", open_low=True),
    "response_time_scale": Bound(
        0.25, 10.0, "", "a factor on the velocity loops' time constant (0.4 s)"
    ),
    "reverse_thrust_loss": Bound(0.0, 0.95, "", "a fraction of max_thrust"),
    "turning_surge_loss": Bound(0.0, 0.95, "", "a fraction of the surge thrust"),
}


@dataclass(frozen=True)
class DockingConfig:
    """Constants of the docking task. Angles in rad, lengths in m, times in s.

    Validated on creation: every number must be finite and within its :data:`BOUNDS`, and both
    PID velocity loops must settle at ``dt`` (:meth:`velocity_loop_radius` < 1); a refusal is a
    ``ValueError`` naming the field, the valid range and the value."""

    # --- time -----------------------------------------------------------------------------
    dt: float = 0.2  # s, one env step (Sec. 4.1)
    max_steps: int = 600  # steps, truncation after 2 min (Sec. 4.1)

    # --- action bounds (eq. 3) ------------------------------------------------------------
    surge_command_min: float = -0.4  # m/s, lower bound of v_d
    surge_command_max: float = 0.8  # m/s, upper bound of v_d
    yaw_rate_command_max: float = 0.3  # rad/s, |w_d| bound

    # --- vehicle dynamics (eqs. 36-38) ----------------------------------------------------
    mass: float = 60.0  # kg, added mass on surge and sway (Sec. 4.1)
    yaw_inertia: float = 60.0  # kg m^2, *chosen* (not given by the paper)
    linear_damping: float = 6.0  # N s/m, K_dl (Sec. 4.1)
    quadratic_damping: float = 12.0  # N s^2/m^2, K_qdl (Sec. 4.1)
    max_acceleration: float = 5.0  # m/s^2 (rad/s^2 on yaw), per-axis clip (eq. 37)
    max_velocity: float = 1.0  # m/s (rad/s on yaw), per-axis clip (eq. 37)
    max_thrust: float = 40.0  # N (N m on yaw), |tau| clip of the PID output (Sec. 3.2.1)

    # --- low-level PID velocity controller, *chosen* ---------------------------------------
    surge_kp: float = 144.0  # N/(m/s): (k_v * mass - K_dl) with k_v = 2.5 1/s
    surge_ki: float = 40.0  # N/m, removes the steady-state error left by damping
    surge_kd: float = 0.0  # N s^2/m, no derivative action: eq. 24 is first order
    yaw_kp: float = 144.0  # N m/(rad/s): (k_w * yaw_inertia - K_dl) with k_w = 2.5 1/s
    yaw_ki: float = 40.0  # N m/rad
    yaw_kd: float = 0.0  # N m s^2/rad

    # --- starting state (Sec. 4.1) -------------------------------------------------------
    init_x: tuple[float, float] = (-30.0, -25.0)  # m
    init_y: tuple[float, float] = (-7.5, 7.5)  # m
    init_heading: tuple[float, float] = (-math.pi / 2, math.pi / 2)  # rad
    ocean_current_range: tuple[float, float] = (-0.3, 0.3)  # m/s, each of oc_x, oc_y
    #: probability that a reset draws oc_x from the upper half of ``ocean_current_range`` only
    #: (currents that carry the AUV towards the DS, the hard cells of Figure 9); 0 is Sec. 4.1's
    #: uniform draw. A training curriculum, not in the paper; evaluation keeps 0.
    following_current_fraction: float = 0.0
    #: probability that a reset draws ``|oc_y|`` from the outer half of the range only (strong
    #: lateral currents, sign kept); 0 is Sec. 4.1's draw. A training curriculum, not in the
    #: paper; evaluation keeps 0.
    lateral_current_fraction: float = 0.0
    #: probability that a reset starts in the near box ``near_start_x`` x ``near_start_y``
    #: (heading as ``init_heading``, at rest) instead of Sec. 4.1's start area, so that the
    #: final approach is practised more often. A training curriculum, not in the paper.
    near_start_fraction: float = 0.0
    near_start_x: tuple[float, float] = (-8.0, -3.0)  # m
    near_start_y: tuple[float, float] = (-3.0, 3.0)  # m

    # --- sensor noise (Table 2), standard deviations ---------------------------------------
    noise: bool = True  # False gives the true observation (scenario ``no_noise``)
    range_noise_fraction: float = 0.025  # rho: 2.5 % of the true range
    bearing_noise: float = math.radians(1.5)  # rad, psi
    heading_noise: float = math.radians(3.0)  # rad, alpha
    velocity_noise: float = 0.02  # m/s, vx and vy (DVL)
    yaw_rate_noise: float = math.radians(0.2)  # rad/s, w (IMU)

    # --- reward (eqs. 4-12) --------------------------------------------------------------
    max_dist: float = 30.0  # m, eq. 4
    thrust_weight: float = 100.0  # w_tau, eq. 5
    entry_speed_max: float = 0.3  # m/s, v_max of eq. 6 and of the success criterion
    approach_distance: float = 3.0  # m, d_appro, eq. 6
    entry_speed_weight: float = 10.0  # w_vel, eq. 6
    aligned_weight: float = 1.0  # w_1, eq. 9
    misaligned_weight: float = 3.05  # w_2, eq. 9
    contact_weight: float = 200.0  # w_contact, eq. 11

    # --- docking-station contact box and success (Sec. 4.1, Tables 6-7) --------------------
    dock_x: tuple[float, float] = (-0.8, 0.0)  # m, x range of the contact box
    dock_y: tuple[float, float] = (-0.5, 0.5)  # m, y range of the contact box
    contact_speed_tolerance: float = 0.0  # m/s, added to entry_speed_max for success

    # --- realism options, not in the paper; all off by default (docs/realism.md) ------------
    #: s between USBL fixes (0: a fix every step, Table 2's 5 Hz at dt = 0.2 s). An inverted
    #: USBL waits for the acoustic ping's round trip and its processing: about 1 s (1 Hz) at
    #: tens of metres. Between fixes the range and bearing hold their last value.
    usbl_period: float = 0.0
    #: s between the instant a USBL fix describes and its arrival (0: none): the acoustic
    #: travel, the station's processing and the modem's link back, about 0.4-1 s. The fix
    #: gives the range and bearing of the vehicle ``usbl_latency`` ago.
    usbl_latency: float = 0.0
    #: fraction of the scheduled USBL fixes lost (0: none): multipath, the vehicle's own hull
    #: or a busy modem drop pings, about 0.1-0.3 near a station.
    usbl_dropout_probability: float = 0.0
    #: mean number of consecutive fixes a loss lasts, a two-state (Gilbert) Markov chain over
    #: the scheduled fixes (0: each fix lost independently). Shadowing lasts a few pings: 3.
    usbl_dropout_burst: float = 0.0
    #: probability that a USBL fix is an outlier (0: none), a multipath return near the
    #: station's structure: about 0.02-0.05.
    usbl_outlier_probability: float = 0.0
    #: m, how far an outlier fix is from where the vehicle was, in a uniformly random
    #: direction (on top of Table 2's noise); reflections add metres: about 5 m.
    usbl_outlier_distance: float = 0.0
    #: s between DVL readings (0: every step). A DVL pings at 1-5 Hz: 0.2-1 s.
    dvl_period: float = 0.0
    #: s between IMU (heading, yaw rate) readings (0: every step). An AHRS gives 10-100 Hz,
    #: faster than the env's step: 0 is realistic; a slower value models a compass.
    imu_period: float = 0.0
    #: s, the time constant of an Ornstein-Uhlenbeck variation of the current around the
    #: episode's drawn mean (0: the constant current of Sec. 4.1). Eddies and the flow around
    #: a station change it over tens of seconds: 30 s.
    current_time_constant: float = 0.0
    #: m/s, the stationary standard deviation of that variation, per axis: about 0.05 m/s.
    current_variation_std: float = 0.0
    #: m/s, the standard deviation of a per-episode bias, per axis, in the current the
    #: vehicle believes (what the EKF and the managed surge controller are given): the DVL's
    #: water-track layer is not the water that drifts the hull, about 0.05 m/s.
    current_knowledge_bias: float = 0.0
    #: m/s, the standard deviation of white noise on the believed current, each step, per
    #: axis: a water-track ping's noise, about 0.02 m/s.
    current_knowledge_noise: float = 0.0
    #: (low, high) of a factor drawn uniformly per episode on the mass and yaw inertia: the
    #: added mass of a real hull is known to about +-30 %.
    mass_scale: tuple[float, float] = (1.0, 1.0)
    #: (low, high) of a factor drawn per episode on both damping coefficients (eq. 36):
    #: identified damping is often off by +-30 %.
    damping_scale: tuple[float, float] = (1.0, 1.0)
    #: (low, high) of a factor drawn per episode on ``max_thrust``: battery voltage and
    #: fouling change a thruster's force by +-20 %.
    thrust_scale: tuple[float, float] = (1.0, 1.0)
    #: (low, high) of a factor drawn per episode on every PID gain: a controller tuned on
    #: another vehicle, +-30 %.
    pid_gain_scale: tuple[float, float] = (1.0, 1.0)
    #: (low, high) of a factor drawn per episode on the time constant of the low-level
    #: velocity loops (0.4 s, eq. 24's k = 2.5 1/s): the PID is retuned so that the poles of
    #: its linear closed loop are the nominal ones divided by the factor (``kp + K_dl`` / s,
    #: ``ki`` / s^2, ``kd`` / s; ``kp`` floored at 0); the 63 % rise time grows by about the
    #: factor (3.4x at 3). A sluggish vehicle is up to 3x slower.
    response_time_scale: tuple[float, float] = (1.0, 1.0)
    #: fraction of ``max_thrust`` lost in reverse surge: a propeller designed for forward
    #: thrust gives 30-50 % less backwards.
    reverse_thrust_loss: float = 0.0
    #: fraction of the surge thrust lost at full yaw moment, linearly in ``|tau_r| /
    #: max_thrust``: a vectored thruster that turns hard pushes less forward, about 0.5.
    turning_surge_loss: float = 0.0

    def __post_init__(self) -> None:
        def fail(name: str, why: str) -> None:
            raise ValueError(f"DockingConfig.{name}: {why} (got {getattr(self, name)!r})")

        for field in dataclasses.fields(self):
            name, value = field.name, getattr(self, field.name)
            if name == "noise":
                if not isinstance(value, bool):
                    fail(name, "must be True or False")
            elif name == "max_steps":
                if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                    fail(name, "must be an integer")
            elif field.type.startswith("tuple"):
                if not (isinstance(value, tuple) and len(value) == 2 and all(map(_real, value))):
                    fail(name, "must be a (low, high) tuple of two numbers")
            elif not _real(value):
                fail(name, "must be a number")
            values = value if isinstance(value, tuple) else (value,)
            if not all(math.isfinite(v) for v in values):
                fail(name, "must be finite")
            bound = BOUNDS.get(name)
            if bound is not None and not all(bound.holds(v) for v in values):
                fail(name, ("each entry " if isinstance(value, tuple) else "") + bound.describe())
        if self.surge_kp == 0 and self.surge_ki == 0:
            fail("surge_kp", "surge PID needs a proportional or integral gain")
        if self.yaw_kp == 0 and self.yaw_ki == 0:
            fail("yaw_kp", "yaw PID needs a proportional or integral gain")
        for axis, inertia in (("surge", "mass"), ("yaw", "yaw_inertia")):
            radius = self.velocity_loop_radius(axis)
            if radius >= 1.0:
                fail(
                    f"{axis}_kp",
                    f"the {axis} PID loop diverges with these gains, dt = {self.dt:g} s and "
                    f"{inertia} = {getattr(self, inertia):g} (spectral radius {radius:.3g} >= 1): "
                    f"lower the gains or dt, or raise {inertia}",
                )
        if self.surge_command_min >= self.surge_command_max:
            fail("surge_command_min", "must be < surge_command_max")
        ranges = ("init_x", "init_y", "init_heading", "ocean_current_range", "dock_x", "dock_y")
        for name in (*ranges, "near_start_x", "near_start_y"):
            low, high = getattr(self, name)
            if not low < high:
                fail(name, "empty range: needs low < high")
        if self.dock_x[0] <= self.init_x[1]:
            fail(
                "dock_x", "the contact box must not overlap the start area (dock_x[0] > init_x[1])"
            )

        if self.near_start_fraction > 0 and self.dock_x[0] <= self.near_start_x[1]:
            fail(
                "near_start_x",
                "the contact box must not overlap the near start box (dock_x[0] > near_start_x[1])",
            )
        self._check_realism(fail)

    def _check_realism(self, fail) -> None:
        """The realism options' checks beyond :data:`BOUNDS`."""
        for name in ("usbl_period", "usbl_latency", "dvl_period", "imu_period"):
            value = getattr(self, name)
            steps = round(value / self.dt)
            if value > 0 and (steps < 1 or abs(steps * self.dt - value) > 1e-6 * self.dt):
                fail(name, f"must be 0 or a whole number of steps of dt = {self.dt:g} s")
        burst, lost = self.usbl_dropout_burst, self.usbl_dropout_probability
        if 0 < burst < 1:
            fail("usbl_dropout_burst", "must be 0 (independent losses) or >= 1 fix")
        if burst > 0 and lost > 0 and burst < lost / (1 - lost):
            fail(
                "usbl_dropout_burst",
                f"bursts this short cannot lose {lost:g} of the fixes: needs >= "
                f"usbl_dropout_probability / (1 - usbl_dropout_probability) = "
                f"{lost / (1 - lost):.3g}",
            )
        if (self.current_time_constant > 0) != (self.current_variation_std > 0):
            fail(
                "current_time_constant",
                "a varying current needs both current_time_constant and "
                "current_variation_std > 0, or both 0",
            )
        for name in SCALE_RANGES:
            low, high = getattr(self, name)
            if low > high:
                fail(name, "empty range: needs low <= high")
        for axis in ("surge", "yaw") if self.dynamics_mismatch else ():
            radius = self.velocity_loop_radius(axis, worst_case=True)
            if radius >= 1.0:
                fail(
                    "pid_gain_scale",
                    f"the {axis} PID loop diverges at the extremes of the dynamics scales "
                    f"(largest gains, lightest vehicle, fastest response: spectral radius "
                    f"{radius:.3g} >= 1): narrow pid_gain_scale, mass_scale or "
                    f"response_time_scale",
                )

    def _steps(self, seconds: float) -> int:
        return max(1, round(seconds / self.dt))

    @property
    def usbl_period_steps(self) -> int:
        """Steps between USBL fixes (1: every step)."""
        return self._steps(self.usbl_period)

    @property
    def usbl_latency_steps(self) -> int:
        """Steps between the instant a USBL fix describes and its arrival."""
        return round(self.usbl_latency / self.dt)

    @property
    def dvl_period_steps(self) -> int:
        """Steps between DVL readings (1: every step)."""
        return self._steps(self.dvl_period)

    @property
    def imu_period_steps(self) -> int:
        """Steps between IMU readings (1: every step)."""
        return self._steps(self.imu_period)

    @property
    def sensor_timing(self) -> bool:
        """Whether a sensor option is on (the env then adds ``sensor_age``)."""
        return (
            self.usbl_period_steps > 1
            or self.usbl_latency_steps > 0
            or self.usbl_dropout_probability > 0
            or self.usbl_outlier_probability > 0
            or self.dvl_period_steps > 1
            or self.imu_period_steps > 1
        )

    @property
    def current_model(self) -> bool:
        """Whether the current varies or the vehicle's knowledge of it is imperfect (the env
        then adds ``true_ocean_current``)."""
        return (
            self.current_time_constant > 0
            or self.current_knowledge_bias > 0
            or self.current_knowledge_noise > 0
        )

    @property
    def dynamics_mismatch(self) -> bool:
        """Whether a dynamics option is on (drawn per episode)."""
        return (
            any(getattr(self, name) != (1.0, 1.0) for name in SCALE_RANGES)
            or self.reverse_thrust_loss > 0
            or self.turning_surge_loss > 0
        )

    @property
    def realistic(self) -> bool:
        """Whether any realism option is on (the paper's task when False)."""
        return self.sensor_timing or self.current_model or self.dynamics_mismatch

    def velocity_loop_radius(self, axis: str, *, worst_case: bool = False) -> float:
        """Spectral radius of the ``axis`` (``"surge"`` or ``"yaw"``) velocity loop, the PID of
        :func:`~dockingrl.env.dynamics.pid_thrust` and the explicit-Euler step of eq. 37
        linearised with the steepest damping slope ``K_dl + 2 K_qdl max_velocity``, unclipped.
        Below 1 the loop settles; at or above 1 a step-to-step oscillation grows until the
        thrust and acceleration clips hold it. A settling surge loop implies a settling
        unactuated sway (``dt * slope / mass < 2``). ``worst_case``: the largest radius over
        the corners of the per-episode scales (``pid_gain_scale``, ``mass_scale``,
        ``damping_scale``, ``response_time_scale``)."""
        kp, ki, kd = (getattr(self, f"{axis}_{gain}") for gain in ("kp", "ki", "kd"))
        inertia = self.mass if axis == "surge" else self.yaw_inertia
        corners = [(1.0, 1.0, 1.0, 1.0)]
        if worst_case:
            corners = list(
                itertools.product(
                    self.pid_gain_scale,
                    self.mass_scale,
                    self.damping_scale,
                    self.response_time_scale,
                )
            )
        radii = []
        for gain, mass, damping, response in corners:
            gains = retuned_gains(kp, ki, kd, self.linear_damping, gain, response)
            slope = damping * (
                self.linear_damping + 2.0 * self.quadratic_damping * self.max_velocity
            )
            radii.append(_loop_radius(*gains, inertia * mass, slope, self.dt))
        return max(radii)

    def replace(self, **changes) -> DockingConfig:
        """Return a copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)

    def scale_usbl_noise(self, range_scale: float = 1.0, bearing_scale: float = 1.0):
        """A copy whose USBL range and bearing sigmas (Table 2) are multiplied by these
        factors: the sensor-mismatch world of ``--range-noise-scale`` and
        ``--bearing-noise-scale`` (the filter keeps Table 2). A scale that takes a sigma out of
        :data:`BOUNDS` is refused, named."""
        for name, scale, sigma in (
            ("range_scale", range_scale, "range_noise_fraction"),
            ("bearing_scale", bearing_scale, "bearing_noise"),
        ):
            problem = noise_scale_problem(scale, sigma, getattr(self, sigma))
            if problem:
                raise ValueError(f"DockingConfig.scale_usbl_noise: {name} {problem}")
        return self.replace(
            range_noise_fraction=self.range_noise_fraction * range_scale,
            bearing_noise=self.bearing_noise * bearing_scale,
        )

    @property
    def action_low(self) -> tuple[float, float]:
        return (self.surge_command_min, -self.yaw_rate_command_max)

    @property
    def action_high(self) -> tuple[float, float]:
        return (self.surge_command_max, self.yaw_rate_command_max)

    @property
    def observation_noise_std(self) -> tuple[float, float, float, float, float, float]:
        """Table 2 sigmas; the first entry is relative to the true range rho."""
        return (
            self.range_noise_fraction,
            self.bearing_noise,
            self.heading_noise,
            self.velocity_noise,
            self.velocity_noise,
            self.yaw_rate_noise,
        )


def retuned_gains(kp, ki, kd, linear_damping, gain_scale=1.0, response_time_scale=1.0):
    """PID gains ``(kp, ki, kd)`` (numbers or tensors) scaled by ``gain_scale`` after being
    retuned so that the linear closed loop of eq. 37 with damping ``linear_damping`` runs
    ``response_time_scale`` times slower: ``kp + K_dl`` / s, ``ki`` / s^2 and ``kd`` / s, ``kp``
    floored at 0 (:attr:`DockingConfig.response_time_scale`). Scales of 1 return the gains
    unchanged."""
    if isinstance(response_time_scale, numbers.Real) and response_time_scale == 1.0:
        return kp * gain_scale, ki * gain_scale, kd * gain_scale
    proportional = (kp + linear_damping) / response_time_scale - linear_damping
    if isinstance(proportional, numbers.Real):
        proportional = max(proportional, 0.0)
    else:
        proportional = proportional.clamp_min(0.0)
    return (
        proportional * gain_scale,
        ki / response_time_scale**2 * gain_scale,
        kd / response_time_scale * gain_scale,
    )


def _loop_radius(kp, ki, kd, m, slope, dt) -> float:
    # state (v, integral, previous error); error = -v for a zero set-point
    full = np.array(
        [
            [1 - dt * (kp + slope) / m - dt * dt * ki / m - kd / m, dt * ki / m, -kd / m],
            [-dt, 1.0, 0.0],
            [-1.0, 0.0, 0.0],
        ]
    )
    keep = [0, 1, 2] if ki else [0, 2]  # without ki the integral never acts
    return float(np.abs(np.linalg.eigvals(full[np.ix_(keep, keep)])).max())


def noise_scale_problem(scale, sigma: str, base: float | None = None) -> str:
    """Why ``scale`` may not multiply the sensor sigma ``sigma`` (``base``, Table 2's value by
    default) of :class:`DockingConfig`: the product must stay within :data:`BOUNDS`; ``""``
    when it may."""
    base = getattr(DockingConfig, sigma) if base is None else base
    high = BOUNDS[sigma].high
    if _real(scale) and math.isfinite(scale) and 0 <= scale * base <= high:
        return ""
    top = f"{high / base:g}" if base else "any"
    return (
        f"must lie in [0, {top}] so that {sigma} ({base:g} x the scale) stays within "
        f"[0, {high:g}] (got {scale!r})"
    )
