"""Saving and loading the EKF's noise parameters (``Q`` and ``R``)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch

from dockingrl.io import (
    UPGRADE_COMMAND,
    ArtifactError,
    first_line,
    read_artifact,
    read_to_upgrade,
    require_finite,
    require_keys,
    save_artifact,
)
from dockingrl.transforms.noise import NoiseParameters

FORMAT = "dockingrl.filter_params/5"
#: version 1 stored ``Q``'s Cholesky factor with absolute off-diagonal entries
FORMAT_V1 = "dockingrl.filter_params/1"
#: version 2 had no context model (``noise_context``)
FORMAT_V2 = "dockingrl.filter_params/2"
#: version 3 had no ``range_noise_from`` (always the measured range)
FORMAT_V3 = "dockingrl.filter_params/3"
#: version 4 had no content hash
FORMAT_V4 = "dockingrl.filter_params/4"
OLD_FORMATS = (FORMAT_V4, FORMAT_V3, FORMAT_V2, FORMAT_V1)
WHAT = "dockingrl filter-parameter file"
KEYS = ("process_noise", "measurement_noise", "noise_context", "range_noise_from")


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
    return save_artifact(path, payload)


def read_filter_params(path: str | Path) -> dict:
    """The payload of a file written by :func:`save_filter_params`, checked (format, hash,
    keys). Raises :class:`~dockingrl.io.ArtifactError`."""
    payload = read_artifact(path, WHAT, FORMAT, OLD_FORMATS)
    require_keys(path, payload, WHAT, KEYS)
    return payload


def load_filter_params(transform, source: str | Path | Mapping, *, name: str | None = None) -> dict:
    """Load parameters written by :func:`save_filter_params` into ``transform``, from the file
    ``source`` or from its payload already read (:func:`read_filter_params`, or the copy a saved
    policy carries; ``name`` says where it came from in errors); returns the payload."""
    if isinstance(source, Mapping):
        name = name or "filter parameters"
        payload = dict(source)
        found = payload.get("format")
        if found in OLD_FORMATS:
            raise ArtifactError(
                f"{name}: of the older format {found}; convert the file that holds them once "
                f"with: {UPGRADE_COMMAND} PATH"
            )
        if found != FORMAT:
            raise ArtifactError(f"{name}: not dockingrl filter parameters ({FORMAT}): {found!r}")
        require_keys(name, payload, WHAT, KEYS)
    elif isinstance(source, (str, Path)):
        payload = read_filter_params(source)
    else:
        raise TypeError(
            "filter_params must be a file path or the payload read from one, got "
            f"{type(source).__name__}"
        )
        name = name or str(source)
    for key in ("process_noise", "measurement_noise", "noise_context"):
        require_finite(name, key, payload[key])
    try:
        transform.process_noise.set_manoeuvre("log_manoeuvre_gain" in payload["process_noise"])
        transform.process_noise.load_state_dict(payload["process_noise"])
        transform.measurement_noise.load_state_dict(payload["measurement_noise"])
        transform.range_noise_from = payload["range_noise_from"]
        context = payload["noise_context"]
        transform.set_context_noise(context is not None)
        if context is not None:
            transform.noise_context.load_state_dict(context)
    except (AttributeError, KeyError, RuntimeError, TypeError, ValueError) as exc:
        raise ArtifactError(f"{name}: do not fit the EKF ({first_line(exc)})") from None
    return payload


def upgrade_payload(payload: Mapping) -> dict:
    """A payload of an older format (:data:`OLD_FORMATS`) in the current one: version 1's
    off-diagonal entries of ``Q``'s factor made relative, and the defaults of the entries
    later versions added (no context model, the range from the measurement)."""
    payload = dict(payload)
    found = payload.get("format")
    if found not in OLD_FORMATS:
        raise ValueError(f"not filter parameters of an older format: {found!r}")
    process = dict(payload["process_noise"])
    if found == FORMAT_V1:
        # v1: L = diag(sigma) + C_abs; now L = diag(sigma) (I + C): C = C_abs / sigma_row
        n = process["log_diag"].numel()
        rows, _ = torch.tril_indices(n, n, -1)
        process["off_diag"] = process["off_diag"] / process["log_diag"].exp()[rows]
    payload["process_noise"] = process
    payload.setdefault("noise_context", None)
    payload.setdefault("range_noise_from", "measurement")
    payload.setdefault("metadata", {})
    payload["format"] = FORMAT
    return payload


def upgrade_filter_params(path: str | Path) -> str:
    """Rewrite the filter-parameter file ``path`` of an older format in the current one
    (atomically); returns what was done."""
    payload = read_to_upgrade(path, WHAT, FORMAT, OLD_FORMATS)
    if payload is None:
        return f"{path}: already {FORMAT}"
    found = payload["format"]
    require_keys(path, payload, WHAT, ("process_noise", "measurement_noise"))
    payload = upgrade_payload(payload)
    check_fits(payload, f"{path}: not converted, its parameters")
    save_artifact(path, payload)
    return f"{path}: {found} -> {FORMAT}"


def check_fits(payload: Mapping, name: str) -> None:
    """Raise :class:`~dockingrl.io.ArtifactError` (its line starting with ``name``) unless the
    filter parameters ``payload`` (of the current format) load into the EKF: what an upgrade
    checks before it writes, as older formats do not say which filter they were for."""
    load_filter_params(NoiseParameters().init_noise_models(), payload, name=name)
