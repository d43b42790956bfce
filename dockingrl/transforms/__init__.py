"""The EKF (pure functions and a TorchRL transform) and the compound observation."""

from dockingrl.transforms.command import PreviousAction
from dockingrl.transforms.ekf import (
    ekf_predict,
    ekf_step,
    ekf_update,
    measurement_covariance,
    measurement_function,
    measurement_jacobian,
    motion_jacobian,
    motion_model,
)
from dockingrl.transforms.filtering import EKFTransform
from dockingrl.transforms.noise import MeasurementNoise, NoiseContext, ProcessNoise
from dockingrl.transforms.observations import CompoundObservation
from dockingrl.transforms.repeat import ActionRepeat
from dockingrl.transforms.shaping import (
    ContactSpeedPenalty,
    MissPenaltyFloor,
    PassedStationEnd,
    SuccessBonus,
)

__all__ = [
    "ActionRepeat",
    "CompoundObservation",
    "ContactSpeedPenalty",
    "MissPenaltyFloor",
    "PassedStationEnd",
    "SuccessBonus",
    "PreviousAction",
    "EKFTransform",
    "MeasurementNoise",
    "NoiseContext",
    "ProcessNoise",
    "ekf_predict",
    "ekf_step",
    "ekf_update",
    "measurement_covariance",
    "measurement_function",
    "measurement_jacobian",
    "motion_jacobian",
    "motion_model",
]
