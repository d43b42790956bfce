"""The checks of :class:`~dockingrl.env.DockingEnv`'s inputs and, in debug mode, outputs: an
action's type, shape and finiteness, a seed's range, and NaN or inf in what a reset or step
gives."""

from __future__ import annotations

import operator
import os
import shutil

import torch

from dockingrl.env.dynamics import clip_action
from dockingrl.env.specs import ACTION_DIM


def checked_seed(seed) -> int:
    """``seed`` as an int, refused (one line) unless it is an integer in ``[0, 2**63)``, the
    range of the envs' generators."""
    try:
        value = None if isinstance(seed, bool) else operator.index(seed)
    except TypeError:
        value = None
    if value is None:
        raise TypeError(f"seed must be an integer, got {type(seed).__name__}")
    if not 0 <= value < 2**63:
        raise ValueError(f"seed must be an integer in [0, 2**63), got {value}")
    return value


def validated_action(
    action: torch.Tensor,
    batch: tuple[int, ...],
    device: torch.device,
    dtype: torch.dtype,
    low: torch.Tensor,
    high: torch.Tensor,
) -> torch.Tensor:
    """``action`` checked (a real tensor of shape ``(*batch, 2)``, finite) and clipped to the
    bounds ``low``, ``high`` of eq. 3, on ``device`` in ``dtype``."""
    expected = (*batch, ACTION_DIM)
    if not isinstance(action, torch.Tensor):
        raise TypeError(
            f"action must be a torch.Tensor of shape {expected}, got {type(action).__name__}"
        )
    if action.dtype == torch.bool or action.is_complex():
        raise ValueError(f"action must be a real-valued tensor, got dtype {action.dtype}")
    if tuple(action.shape) != expected:
        raise ValueError(
            f"action must have shape {expected} (batch, [v_d, w_d]), got {tuple(action.shape)}"
        )
    finite = torch.isfinite(action).reshape(-1, ACTION_DIM).all(-1)
    if not bool(finite.all()):
        index = int((~finite).nonzero()[0, 0])
        raise ValueError(
            f"action must be finite, no NaN or inf; batch entry {index} (flattened) is "
            f"{action.reshape(-1, ACTION_DIM)[index].tolist()}"
        )
    action = action.to(device=device, dtype=dtype)
    return clip_action(action, low, high)


def check_finite(entries: dict[str, torch.Tensor], step_count: torch.Tensor, when: str) -> None:
    """Raise ``FloatingPointError`` at the first of ``entries`` (``(n, ...)`` each) holding a
    NaN or inf, naming it, ``when`` (``"reset"`` or ``"step"``), the first env holding one and
    its step count (``step_count`` ``(n, 1)``)."""
    n = step_count.shape[0]
    for key, value in entries.items():
        finite = torch.isfinite(value).reshape(n, -1).all(-1)
        if not bool(finite.all()):
            env = int((~finite).nonzero()[0, 0])
            step = int(step_count[env, 0])
            raise FloatingPointError(
                f"DockingEnv check_finite: {key!r} is not finite after {when} in env {env} "
                f"at its step {step}: {value[env].tolist()}"
            )


def available_device(text: str, *, here: bool = True) -> str:
    """``text`` if it names a torch device (``cpu``, ``cuda``, ``cuda:1``, ``mps``) that this
    machine has (``here``; else any such name); else a one-line ``ValueError`` that says why."""
    try:
        parsed = torch.device(text)
    except (RuntimeError, TypeError):
        raise ValueError(f"not a torch device: {text!r}") from None
    if parsed.type not in ("cpu", "cuda", "mps"):
        raise ValueError(f"{text!r}: expected cpu, cuda[:N] or mps")
    if not here:
        return text
    if parsed.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"{text!r}: CUDA is not available on this machine")
        if parsed.index is not None and parsed.index >= torch.cuda.device_count():
            raise ValueError(
                f"{text!r}: this machine has {torch.cuda.device_count()} CUDA device(s)"
            )
    elif parsed.type == "mps":
        if not torch.backends.mps.is_available():
            raise ValueError(f"{text!r}: MPS is not available on this machine")
    return text


#: the C++ compilers TorchInductor looks for on a CPU, after the ``CXX`` variable
CPP_COMPILERS = ("c++", "g++", "clang++")


def check_can_compile(device) -> None:
    """``torch.compile`` builds its CPU kernels from C++ at run time: on a CPU with neither
    ``CXX`` set nor a compiler of :data:`CPP_COMPILERS` on the path, a one-line ``ValueError``
    before anything is built (instead of TorchInductor's traceback at the first step)."""
    if torch.device(device).type != "cpu" or os.environ.get("CXX"):
        return
    if not any(shutil.which(name) for name in CPP_COMPILERS):
        raise ValueError(
            "compile: torch.compile needs a C++ compiler on a CPU and none was found "
            "(CXX, c++, g++, clang++): install one (e.g. the build-essential package) "
            "or turn compiling off (--no-compile)"
        )


def compiled(fn, device, **options):
    """``torch.compile(fn, **options)`` for a function that runs on ``device``, refused in one
    line first where it could not be built (:func:`check_can_compile`): every compiled step of
    dockingrl (the simulation, the filter, the Gymnasium step, the gradient step) is made here."""
    check_can_compile(device)
    return torch.compile(fn, **options)
