"""The onboard step (:class:`~dockingrl.onboard.policy.OnboardStep`: the EKF's predict and its
update for each fresh sensor, the observation layout and normaliser, the deterministic action
and its clipping) as a program for a vehicle's computer: a ``torch.export`` program (``.pt2``,
for libtorch and AOTInductor) or an ONNX program (``.onnx``, for ONNX Runtime from C++ or
Python). The filter's state is an explicit input and output of either (docs/onboard.md)."""

from __future__ import annotations

import contextlib
import copy
import logging
import warnings
from pathlib import Path

import torch

from dockingrl.env.realism import SENSORS
from dockingrl.io import atomic_write
from dockingrl.onboard.policy import OBS_DIM, OnboardPolicy

#: the ONNX opset the programs are written with
ONNX_OPSET = 18
#: the ONNX program's inputs, in order; ``history`` only for a filter that compensates the USBL
#: latency
ONNX_INPUTS = ("z", "current", "mean", "cov", "command", "age", "sensor_age", "history")
#: its outputs, in order; ``history_out`` only with ``history``
ONNX_OUTPUTS = ("command_out", "mean_out", "cov_out", "age_out", "history_out")


def _example(policy: OnboardPolicy, batch: int, sensor_age: bool) -> tuple[torch.Tensor, ...]:
    """Inputs of the step for ``batch`` vehicles at the start of an approach."""
    z = torch.zeros(batch, OBS_DIM)
    z[:, 0] = 20.0
    mean, cov, command, age, *history = policy.initial_state(batch)
    if history and not sensor_age:
        raise ValueError("a filter that compensates the USBL latency needs sensor_age=True")
    example = (z, torch.zeros(batch, 2), mean, cov, command, age)
    if sensor_age:
        example = (*example, torch.zeros(batch, len(SENSORS)), *history)
    return example


def _frozen_step(policy: OnboardPolicy) -> torch.nn.Module:
    return copy.deepcopy(policy.step).cpu().eval().requires_grad_(False)


def export_onboard(
    policy: OnboardPolicy, path: str | Path, batch: int = 1, *, sensor_age: bool = False
) -> Path:
    """Write ``policy``'s :class:`OnboardStep` as a ``torch.export`` program (``.pt2``) for
    ``batch`` vehicles: ``torch.export.load(path).module()(z, current, mean, cov, command,
    age)`` runs with torch alone (no dockingrl, TorchRL or tensordict), and AOTInductor can
    compile it for a C++ control loop. With ``sensor_age`` the program takes the sensors' ages
    ``(batch, 3)`` as a seventh input (sensors at their own rates); a filter that compensates
    the USBL latency needs them and takes and returns its history
    ``(batch, latency_steps, 2)`` as an eighth input and fifth output. Written atomically."""
    example = _example(policy, batch, sensor_age)
    with torch.no_grad():
        program = torch.export.export(_frozen_step(policy), example)
    return atomic_write(path, lambda tmp: torch.export.save(program, tmp))


def onnx_names(policy: OnboardPolicy) -> tuple[list[str], list[str]]:
    """The ONNX program's input and output names for ``policy`` (``history`` and
    ``history_out`` only for a filter that compensates the USBL latency)."""
    ekf = policy.step.ekf
    history = ekf is not None and ekf.latency_steps > 0
    inputs = list(ONNX_INPUTS if history else ONNX_INPUTS[:-1])
    outputs = list(ONNX_OUTPUTS if history else ONNX_OUTPUTS[:-1])
    return inputs, outputs


@contextlib.contextmanager
def _quiet_exporter():
    """Silence what torch.onnx's exporter and onnx_ir log about themselves while exporting
    (torchvision's operators it skips, a deprecation inside torch, a defaulted attribute
    type): warnings about the exporter, not about the policy. Errors still raise."""
    loggers = [logging.getLogger(name) for name in ("torch.onnx", "onnx_ir", "onnxscript")]
    levels = [logger.level for logger in loggers]
    try:
        for logger in loggers:
            logger.setLevel(logging.ERROR)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


def export_onnx(policy: OnboardPolicy, path: str | Path, batch: int = 1) -> Path:
    """Write ``policy``'s whole onboard step as one ONNX program (opset :data:`ONNX_OPSET`) for
    ``batch`` vehicles, float32 throughout:

    inputs ``z (B, 6)``, ``current (B, 2)``, ``mean (B, n)``, ``cov (B, n, n)``, ``command
    (B, 2)``, ``age (B, 1)``, ``sensor_age (B, 3)`` [, ``history (B, L, 2)``] ->
    outputs ``command_out (B, 2)``, ``mean_out``, ``cov_out``, ``age_out`` [, ``history_out``]

    with the meanings of :class:`~dockingrl.onboard.policy.OnboardStep` (``n`` = 5, or 7 for
    the filter that estimates the current; ``age = -1`` starts an approach; ``sensor_age`` all
    0 updates with every reading). The caller feeds each output back as the next step's input
    (``command_out`` as ``command``). Needs the ``onnx`` and ``onnxscript`` packages
    (``pip install dockingrl[onboard]``); written atomically."""
    try:
        import onnxscript  # noqa: F401  (torch.onnx's exporter needs it)
    except ImportError:
        raise ValueError(
            "the ONNX export needs onnx and onnxscript: pip install 'dockingrl[onboard]'"
        ) from None
    example = _example(policy, batch, sensor_age=True)
    inputs, outputs = onnx_names(policy)
    step = _frozen_step(policy)

    def write(tmp: Path) -> None:
        with torch.no_grad(), _quiet_exporter():
            program = torch.onnx.export(
                step,
                example,
                dynamo=True,
                opset_version=ONNX_OPSET,
                input_names=inputs,
                output_names=outputs,
                verbose=False,
                optimize=True,
            )
        program.save(str(tmp))

    return atomic_write(Path(path), write)


__all__ = ["ONNX_INPUTS", "ONNX_OPSET", "ONNX_OUTPUTS", "export_onboard", "export_onnx"]
