"""The docking task's own fields of :class:`~dockingrl.env.DockingConfig`, with their accepted
ranges and the checks between them: the paper's constants, the training draws of the start
state (curricula, not in the paper) and the contact's speed tolerance.

Values are the paper's (Sec. 3-4.1, Tables 2 and 3) unless marked *chosen*: the paper does not
give the PID gains nor the yaw inertia of its simulated vehicle; ours are chosen so that the
closed-loop step response of surge and yaw rate follows the first-order model the EKF assumes
(eq. 24, k = 2.5 1/s). ``tests/test_env.py::test_step_response_matches_first_order_model``
measures that choice.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from dockingrl.env.bounds import Bound

_GAIN = Bound(0.0, 1e6, "", "PID gain, N or N m per unit of velocity error (or its integral)")
_POSITION = Bound(-1e4, 1e4, "m", "10 km, beyond a USBL's range")
_WEIGHT = Bound(0.0, 1e6, "", "reward weight")

#: The accepted range of every number of :class:`TaskOptions` (each entry of a pair), with its
#: reason (:data:`dockingrl.env.config.BOUNDS` holds them with the realism options').
TASK_BOUNDS: dict[str, Bound] = {
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
}


def training_draw(doc: str) -> Any:
    """A field of :class:`TaskOptions` that biases the training envs' resets (a curriculum,
    not in the paper; 0 is Sec. 4.1's draw, which evaluation keeps): a probability, with its
    ``--help`` text ``doc``. The training config takes these fields as they are
    (:func:`~dockingrl.agents.option_fields.env_field`)."""
    return field(default=0.0, metadata={"doc": doc, "training_draw": True})


@dataclass(frozen=True)
class TaskOptions:
    """The task's fields of :class:`~dockingrl.env.DockingConfig` (which validates them)."""

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
    following_current_fraction: float = training_draw(
        "training envs: probability that a reset draws oc_x from [0, 0.3] only (following "
        "currents, the hard cells of Figure 9); evaluation keeps the uniform draw (0: Sec. 4.1; "
        "not in the paper)"
    )
    lateral_current_fraction: float = training_draw(
        "training envs: probability that a reset draws |oc_y| from [0.15, 0.3] only (strong "
        "lateral currents, sign kept); evaluation keeps the uniform draw (0: Sec. 4.1; not in "
        "the paper)"
    )
    near_start_fraction: float = training_draw(
        "training envs: probability that a reset starts 3-8 m before the station (|y| <= 3 m, "
        "near_start_x x near_start_y, at rest) instead of 25-30 m, to practise the final "
        "approach; evaluation keeps Sec. 4.1's starts (0: off; not in the paper)"
    )
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

    def _check_gains(self, fail) -> None:
        """Each PID loop has a proportional or an integral gain."""
        if self.surge_kp == 0 and self.surge_ki == 0:
            fail("surge_kp", "surge PID needs a proportional or integral gain")
        if self.yaw_kp == 0 and self.yaw_ki == 0:
            fail("yaw_kp", "yaw PID needs a proportional or integral gain")

    def _check_ranges(self, fail) -> None:
        """The command bounds and the (low, high) ranges are ordered, and the contact box lies
        apart from the start areas."""
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


#: the fields of :class:`TaskOptions` that bias the training envs' resets
#: (:func:`training_draw`), in their order
TRAINING_DRAWS: tuple[str, ...] = tuple(
    f.name for f in dataclasses.fields(TaskOptions) if f.metadata.get("training_draw")
)
