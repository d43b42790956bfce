"""The parameters of the Fossen vehicle (:mod:`dockingrl.env.fossen`): a thruster-driven
torpedo AUV in the horizontal plane, by default a Sparus II-class vehicle (:data:`SPARUS_II`),
each parameter with its source or marked an estimate; and the terms derived from them alone,
the added mass of a prolate spheroid and the mass matrix ``M = M_RB + M_A`` (Fossen, *Handbook
of Marine Craft Hydrodynamics and Motion Control*, 2nd ed., Wiley, 2021). docs/vehicles.md
tabulates them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SPARUS_II", "FossenVehicle", "mass_matrix", "spheroid_added_mass", "strip_positions"]


@dataclass(frozen=True)
class FossenVehicle:
    """The parameters of a thruster-driven torpedo AUV in the horizontal plane. The defaults,
    :data:`SPARUS_II`, are a Sparus II-class vehicle; each says where it comes from, and which
    are estimates. SI units: kg, m, s, N."""

    #: kg, mass in air (Carreras et al., "Sparus II AUV - A hovering vehicle for seabed
    #: inspection", IEEE J. Oceanic Eng. 43(2), 2018: 52 kg). Trimmed neutrally buoyant.
    mass: float = 52.0
    #: m, hull length (Carreras et al. 2018: 1.6 m; also the paper's ``l`` of eq. 13).
    length: float = 1.6
    #: m, hull diameter (Carreras et al. 2018: 230 mm).
    diameter: float = 0.23
    #: kg/m^3, sea water.
    water_density: float = 1025.0
    #: m, centre of gravity ahead of the body origin (the centre of buoyancy). Estimate: a
    #: trimmed AUV keeps them within a few centimetres; it gives ``M`` its off-diagonal ``m x_g``.
    cg_x: float = 0.02
    #: m, the horizontal thrusters' lateral offset, one each side. Estimate from the vehicle's
    #: overall width of about 0.46 m with the thrusters (Carreras et al. 2018's drawings).
    thruster_y: float = 0.17
    #: N, each thruster's full forward thrust. Estimate, chosen so that the pair gives the
    #: paper's 40 N surge force limit (Sec. 3.2.1).
    forward_thrust: float = 20.0
    #: full reverse thrust as a fraction of forward: a propeller with blades shaped for forward
    #: thrust gives about half backwards (estimate; the realism options' typical 30-50 % loss).
    reverse_thrust_ratio: float = 0.45
    #: s, time constant of a thruster's first-order response to its command (estimate for a
    #: brushless thruster with its own speed loop, 0.2-0.4 s).
    thruster_time_constant: float = 0.3
    #: N s/m, linear surge damping (skin friction at low speed). Estimate.
    surge_linear_damping: float = 2.0
    #: axial drag coefficient on the frontal area ``pi D^2 / 4``, appendages (antenna mast,
    #: DVL, thruster nacelles) included. Estimate: it makes full thrust hold about 1.4 m/s.
    surge_drag_coefficient: float = 0.9
    #: cross-flow drag coefficient of the hull's strips: a circular cylinder in cross flow at
    #: Reynolds numbers 1e4-1e5 (Hoerner, *Fluid-Dynamic Drag*, 1965: about 1.1; Fossen, Ch. 6).
    crossflow_drag_coefficient: float = 1.1
    #: N s/m, linear sway damping (low-speed viscous sway). Estimate.
    sway_linear_damping: float = 5.0
    #: N m s/rad, linear yaw damping. Estimate.
    yaw_linear_damping: float = 1.0
    #: strips of the cross-flow drag integral along the hull (midpoint rule).
    strips: int = 8
    #: the low-level velocity loop: N/(m/s) and N/m on the surge error, N m/(rad/s) and N m/rad
    #: on the yaw-rate error, on top of a feedforward of the model's steady damping. Chosen for
    #: a well-damped loop over the thrusters' lag (docs/vehicles.md shows the step responses).
    surge_kp: float = 40.0
    surge_ki: float = 10.0
    yaw_kp: float = 15.0
    yaw_ki: float = 5.0
    #: substeps of the env's ``dt`` over which the controller runs (zero-order hold) and the
    #: equations are integrated (Heun's method): 2 at dt = 0.2 s is a 10 Hz loop.
    substeps: int = 2

    def __post_init__(self) -> None:
        positive = (
            "mass",
            "length",
            "diameter",
            "water_density",
            "thruster_y",
            "forward_thrust",
            "reverse_thrust_ratio",
            "thruster_time_constant",
        )
        for name, value in vars(self).items():
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"FossenVehicle.{name}: must be a number (got {value!r})")
            if not math.isfinite(value):
                raise ValueError(f"FossenVehicle.{name}: must be finite (got {value!r})")
            if value < 0 or (name in positive and value == 0):
                need = "> 0" if name in positive else ">= 0"
                raise ValueError(f"FossenVehicle.{name}: must be {need} (got {value!r})")
        if self.diameter >= self.length:
            raise ValueError(
                f"FossenVehicle.diameter: must be below the length {self.length:g} m for a "
                f"slender hull (got {self.diameter!r})"
            )
        if abs(self.cg_x) >= self.length / 2:
            raise ValueError(f"FossenVehicle.cg_x: must lie on the hull (got {self.cg_x!r})")
        for name in ("strips", "substeps"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise ValueError(f"FossenVehicle.{name}: must be an integer >= 1")

    @property
    def yaw_inertia(self) -> float:
        """kg m^2, rigid-body yaw inertia about the origin: a uniform solid cylinder of the
        vehicle's mass, ``m (3 (D/2)^2 + L^2) / 12`` (an estimate; no public figure)."""
        return self.mass * (3 * (self.diameter / 2) ** 2 + self.length**2) / 12


#: the Sparus II-class vehicle that ``DockingConfig(vehicle="fossen")`` flies
SPARUS_II = FossenVehicle()


def spheroid_added_mass(length: float, diameter: float, density: float):
    """``(X_udot, Y_vdot, N_rdot)`` of a prolate spheroid of semi-axes ``a = L/2`` and
    ``b = D/2`` (Lamb's k-factors; Fossen 2021, Ch. 8, after Imlay 1961): with the
    eccentricity ``e = sqrt(1 - (b/a)^2)``, ``alpha0 = 2 (1 - e^2) / e^3 (ln((1+e)/(1-e)) / 2
    - e)``, ``beta0 = 1/e^2 - (1 - e^2) / (2 e^3) ln((1+e)/(1-e))``, ``k1 = alpha0 /
    (2 - alpha0)``, ``k2 = beta0 / (2 - beta0)``, ``k' = e^4 (beta0 - alpha0) / ((2 - e^2)
    (2 e^2 - (2 - e^2)(beta0 - alpha0)))``; ``X_udot = -k1 m_s``, ``Y_vdot = -k2 m_s``,
    ``N_rdot = -k' I_s`` with the spheroid's displaced mass ``m_s = 4/3 pi rho a b^2`` and
    inertia ``I_s = m_s (a^2 + b^2) / 5``."""
    a, b = length / 2, diameter / 2
    e = math.sqrt(1 - (b / a) ** 2)
    log = math.log((1 + e) / (1 - e))
    alpha0 = 2 * (1 - e * e) / e**3 * (log / 2 - e)
    beta0 = 1 / e**2 - (1 - e * e) / (2 * e**3) * log
    k1 = alpha0 / (2 - alpha0)
    k2 = beta0 / (2 - beta0)
    k_yaw = e**4 * (beta0 - alpha0) / ((2 - e * e) * (2 * e * e - (2 - e * e) * (beta0 - alpha0)))
    m_s = 4 / 3 * math.pi * density * a * b * b
    inertia = m_s * (a * a + b * b) / 5
    return -k1 * m_s, -k2 * m_s, -k_yaw * inertia


def mass_matrix(vehicle: FossenVehicle) -> np.ndarray:
    """``M = M_RB + M_A`` (Fossen 2021, Ch. 6, the 3-DOF manoeuvring model):
    ``M_RB = [[m, 0, 0], [0, m, m x_g], [0, m x_g, I_z]]``, ``M_A = diag(-X_udot, -Y_vdot,
    -N_rdot)`` (the spheroid's ``Y_rdot = N_vdot = 0`` by its fore-aft symmetry)."""
    m, xg = vehicle.mass, vehicle.cg_x
    x_udot, y_vdot, n_rdot = spheroid_added_mass(
        vehicle.length, vehicle.diameter, vehicle.water_density
    )
    return np.array(
        [
            [m - x_udot, 0.0, 0.0],
            [0.0, m - y_vdot, m * xg],
            [0.0, m * xg, vehicle.yaw_inertia - n_rdot],
        ]
    )


def strip_positions(vehicle: FossenVehicle) -> np.ndarray:
    """m, the midpoints of the hull's ``strips`` equal strips along ``[-L/2, L/2]``."""
    k, length = vehicle.strips, vehicle.length
    return (np.arange(k) + 0.5) * (length / k) - length / 2
