"""The realism options of :class:`~dockingrl.env.DockingConfig`, not in the paper and all off by
default: their fields (with each one's physical reason and a typical value), accepted ranges,
checks and the flags the env reads (docs/realism.md). :mod:`dockingrl.env.realism` simulates
them."""

from __future__ import annotations

from dataclasses import dataclass

from dockingrl.env.bounds import Bound

#: The per-episode (low, high) factors of the dynamics-mismatch options.
SCALE_RANGES = (
    "mass_scale",
    "damping_scale",
    "thrust_scale",
    "pid_gain_scale",
    "response_time_scale",
)

#: The accepted range of every number of :class:`RealismOptions` (each entry of a pair), with
#: its reason (:data:`dockingrl.env.config.BOUNDS` holds them with the task's).
REALISM_BOUNDS: dict[str, Bound] = {
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
    "fossen_fraction": Bound(0.0, 1.0, "", "a probability"),
}

#: the vehicles the env flies (:attr:`RealismOptions.vehicle`)
VEHICLES = ("paper", "fossen", "mixed")


@dataclass(frozen=True)
class RealismOptions:
    """The realism fields of :class:`~dockingrl.env.DockingConfig` (which validates them); the
    step counts and flags derived from them need its ``dt``."""

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
    #: the vehicle flown: ``"paper"``, the paper's model (eqs. 36-38, Sec. 4.1); ``"fossen"``, a
    #: Fossen manoeuvring model of a Sparus II-class AUV with added mass, Coriolis and
    #: cross-flow drag, two thrusters with lag and weak reverse thrust and its own velocity
    #: controller (:mod:`dockingrl.env.fossen`, docs/vehicles.md); ``"mixed"``, each episode
    #: one of the two, the Fossen vehicle with probability ``fossen_fraction`` (training
    #: across vehicles). The dynamics scales above apply to either: on the Fossen vehicle the
    #: mass factor scales ``M`` and ``C``, the damping factor ``D``, the thrust factor both
    #: thrusts, the gain factor its controller's gains, the response factor its thrusters' time
    #: constant; ``reverse_thrust_loss`` weakens its reverse thrust further;
    #: ``turning_surge_loss`` is the paper vehicle's only (the Fossen allocation trades surge
    #: for yaw by itself).
    vehicle: str = "paper"
    #: the share of ``"mixed"`` episodes flown on the Fossen vehicle.
    fossen_fraction: float = 0.5
    #: whether the dynamics scales above apply to the Fossen vehicle as well (off: it flies
    #: as identified, its own difference from the paper's model being its mismatch, while the
    #: paper's model takes the scales; the ladder's M5F). False needs the Fossen vehicle
    #: (``"fossen"`` or ``"mixed"``) and a dynamics scale on.
    scale_fossen: bool = True

    def _check_realism(self, fail) -> None:
        """The realism options' checks beyond :data:`REALISM_BOUNDS` (the worst-case PID loop
        of the dynamics scales is :class:`~dockingrl.env.DockingConfig`'s)."""
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
        if self.vehicle not in VEHICLES:
            fail("vehicle", f"unknown vehicle; valid: {', '.join(VEHICLES)}")
        if not self.scale_fossen and (self.vehicle == "paper" or not self.dynamics_mismatch):
            fail(
                "scale_fossen",
                "False only spares the Fossen vehicle the dynamics scales: it needs vehicle "
                "'fossen' or 'mixed' and a dynamics scale on",
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
        return (
            self.sensor_timing
            or self.current_model
            or self.dynamics_mismatch
            or self.vehicle != "paper"
        )
