"""Saving and loading the EKF's noise parameters (``Q`` and ``R``)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch

from dockingrl.io import atomic_write

FORMAT = "dockingrl.filter_params/4"
#: version 1 stored ``Q``'s Cholesky factor with absolute off-diagonal entries
FORMAT_V1 = "dockingrl.filter_params/1"
#: version 2 had no context model (``noise_context``)
FORMAT_V2 = "dockingrl.filter_params/2"
#: version 3 had no ``range_noise_from`` (always the measured range)
FORMAT_V3 = "dockingrl.filter_params/3"
READABLE = (FORMAT, FORMAT_V3, FORMAT_V2, FORMAT_V1)


def save_filter_params(transform, path: str | Path, **metadata) -> Path:
    """Write ``transform``'s ``Q`` and ``R`` parameters (and the matrices, for reading) to
    ``path`` atomically. ``metadata`` (objective, steps, ...) is stored alongside."""
    with torch.no_grad():
        payload = {
            "format": FORMAT,
            "process_noise": {
                k: v.detach().cpu() for k, v in transform.process_noise.state_dict().items()
            },
            "measurement_noise": {
                k: v.detach().cpu() for k, v in transform.measurement_noise.state_dict().items()
            },
            "Q": transform.process_noise().detach().cpu(),
            "R_std": transform.measurement_noise.std().detach().cpu(),
            "noise_context": None
            if transform.noise_context is None
            else {k: v.detach().cpu() for k, v in transform.noise_context.state_dict().items()},
            "range_noise_from": transform.range_noise_from,
            "metadata": metadata,
        }
    return atomic_write(path, lambda tmp: torch.save(payload, tmp))


def read_filter_params(path: str | Path) -> dict:
    """The payload of a file written by :func:`save_filter_params`, checked."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no filter-parameter file at {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a foreign or damaged file fails to unpickle in many ways
        raise ValueError(f"{path} is not a dockingrl filter-parameter file: {exc}") from exc
    if not isinstance(payload, dict) or payload.get("format") not in READABLE:
        raise ValueError(f"{path} is not a dockingrl filter-parameter file ({FORMAT})")
    return payload


def load_filter_params(transform, source: str | Path | Mapping) -> dict:
    """Load parameters written by :func:`save_filter_params` into ``transform``, from the file
    ``source`` or from its payload already read (:func:`read_filter_params`, or the copy a saved
    policy carries); returns the payload."""
    if isinstance(source, Mapping):
        payload = dict(source)
        if payload.get("format") not in READABLE:
            raise ValueError(f"not dockingrl filter parameters ({FORMAT})")
    else:
        payload = read_filter_params(source)
    process = dict(payload["process_noise"])
    transform.process_noise.set_manoeuvre("log_manoeuvre_gain" in process)
    if payload["format"] == FORMAT_V1:
        # v1: L = diag(sigma) + C_abs; now L = diag(sigma) (I + C): C = C_abs / sigma_row
        rows, _ = torch.tril_indices(process["log_diag"].numel(), process["log_diag"].numel(), -1)
        process["off_diag"] = process["off_diag"] / process["log_diag"].exp()[rows]
    transform.process_noise.load_state_dict(process)
    transform.measurement_noise.load_state_dict(payload["measurement_noise"])
    transform.range_noise_from = payload.get("range_noise_from", "measurement")
    context = payload.get("noise_context")
    transform.set_context_noise(context is not None)
    if context is not None:
        transform.noise_context.load_state_dict(context)
    return payload
