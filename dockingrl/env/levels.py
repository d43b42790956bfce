"""The stress ladder's levels (``dockingrl stress``, docs/realism.md): the paper's task (L0),
:class:`DockingConfig` realism options at harsh but realistic values (L1-L5), the Fossen vehicle
(docs/vehicles.md) alone (F0) and with L5's sensors and current (F5), and either vehicle per
episode alone (M0), with L4's sensors and current (M4), with all of L5's ranges (M5) or at L5
and F5 (M5F: L5's dynamics on the paper's model only), for
evaluating a policy and for training over the realistic task (``train_level``)."""

from __future__ import annotations

from dockingrl.env.config import DockingConfig

#: 1 Hz USBL, 0.6 s late, 20 % of the fixes lost in bursts of 3, 5 % outliers 5 m off; a
#: 2.5 Hz DVL
HARSH_SENSORS = {
    "usbl_period": 1.0,
    "usbl_latency": 0.6,
    "usbl_dropout_probability": 0.2,
    "usbl_dropout_burst": 3.0,
    "usbl_outlier_probability": 0.05,
    "usbl_outlier_distance": 5.0,
    "dvl_period": 0.4,
}
#: a current varying by 0.05 m/s over 30 s, believed with a 0.05 m/s bias and 0.02 m/s noise
HARSH_CURRENT = {
    "current_time_constant": 30.0,
    "current_variation_std": 0.05,
    "current_knowledge_bias": 0.05,
    "current_knowledge_noise": 0.02,
}
#: +-30 % mass, damping and PID gains, +-20 % thrust, a response up to 3x slower, 40 % less
#: thrust in reverse and half the surge thrust at full yaw moment
HARSH_DYNAMICS = {
    "mass_scale": (0.7, 1.3),
    "damping_scale": (0.7, 1.3),
    "thrust_scale": (0.8, 1.2),
    "pid_gain_scale": (0.7, 1.3),
    "response_time_scale": (1.0, 3.0),
    "reverse_thrust_loss": 0.4,
    "turning_surge_loss": 0.5,
}
#: either vehicle per episode with all of L5's ranges (M5; M5F keeps the Fossen vehicle unscaled)
MIXED_L5 = {**HARSH_SENSORS, **HARSH_CURRENT, **HARSH_DYNAMICS, "vehicle": "mixed"}
#: the ladder: name -> (what it is, the DockingConfig options it sets)
LEVELS: dict[str, tuple[str, dict]] = {
    "L0": ("the paper's task", {}),
    "L1": ("sensors: 1 Hz USBL, late, dropouts, outliers; slow DVL", HARSH_SENSORS),
    "L2": ("current: varying, known with bias and noise", HARSH_CURRENT),
    "L3": ("dynamics: +-30 % vehicle, 3x slower loops, weak reverse", HARSH_DYNAMICS),
    "L4": ("sensors and current", {**HARSH_SENSORS, **HARSH_CURRENT}),
    "L5": ("sensors, current and dynamics", {**HARSH_SENSORS, **HARSH_CURRENT, **HARSH_DYNAMICS}),
    "F0": ("the Fossen vehicle", {"vehicle": "fossen"}),
    "F5": (
        "the Fossen vehicle, L5's sensors and current",
        {**HARSH_SENSORS, **HARSH_CURRENT, "vehicle": "fossen"},
    ),
    "M0": ("either vehicle per episode", {"vehicle": "mixed"}),
    "M4": (
        "either vehicle per episode, L4's sensors and current",
        {**HARSH_SENSORS, **HARSH_CURRENT, "vehicle": "mixed"},
    ),
    "M5": ("either vehicle per episode, L5's sensors, current and dynamics", MIXED_L5),
    "M5F": (
        "either vehicle per episode, the paper's model at L5, the Fossen vehicle at F5",
        {**MIXED_L5, "scale_fossen": False},
    ),
}


def level_config(level: str, base: DockingConfig | None = None) -> DockingConfig:
    """The :class:`DockingConfig` of a ladder level: ``base`` (the paper's) with its options."""
    if level not in LEVELS:
        raise ValueError(f"unknown stress level {level!r}; valid: {', '.join(LEVELS)}")
    return (base or DockingConfig()).replace(**LEVELS[level][1])
