"""The machine an evaluation or a training ran on, in one line, and whether the threads asked
for share their cores with other work."""

from __future__ import annotations

import os
import platform
import sys
from pathlib import Path

import torch


def cpu_fields(cpuinfo: str | None = None) -> dict[str, str]:
    """The first core's ``key: value`` lines of ``/proc/cpuinfo`` (or of the text ``cpuinfo``);
    empty where there is no such file."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return {}
    fields: dict[str, str] = {}
    for key, _, value in (line.partition(":") for line in cpuinfo.splitlines()):
        fields.setdefault(key.strip(), value.strip())  # a later core's line does not replace it
    return fields


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; elsewhere what :mod:`platform` says)."""
    fields = cpu_fields()
    if "model name" in fields:
        return fields["model name"]
    return platform.processor() or platform.machine()


def cpu_speed(cpuinfo: str | None = None) -> str:
    """The first core's clock and whether it has AVX-512, from ``/proc/cpuinfo`` (or the text
    ``cpuinfo``), e.g. ``"2.6 GHz, AVX-512"``; empty where neither is known. Virtual machines
    may name their CPU by its family alone ("AMD EPYC"), which holds machines of different
    speeds: these two tell them apart."""
    fields = cpu_fields(cpuinfo)
    parts = []
    try:
        parts.append(f"{float(fields['cpu MHz']) / 1000:.1f} GHz")
    except (KeyError, ValueError):
        pass
    if "avx512f" in fields.get("flags", "").split():
        parts.append("AVX-512")
    return ", ".join(parts)


def describe_machine(device: torch.device | str | None = None) -> str:
    """The CPU (its model, clock and AVX-512), its cores, torch's version and threads, and the
    GPU when ``device`` is CUDA."""
    threads = torch.get_num_threads()
    speed = cpu_speed()
    cpu = f"{cpu_model()} ({speed})" if speed else cpu_model()
    text = f"{cpu}, {os.cpu_count()} cores, torch {torch.__version__}, {threads} threads"
    if device is not None and torch.device(device).type == "cuda":
        text += f", GPU {torch.cuda.get_device_name(device)}"
    return text


def shared_cores_warning(threads: int, load: float | None = None, cores: int | None = None):
    """One line to print when ``threads`` torch threads (more than one) would share their
    cores with other running work: the load average over the last minute (``load``, else
    ``os.getloadavg``) plus ``threads`` exceeds the ``cores`` (else ``os.cpu_count``) by half a
    core or more; else None. Torch's threads wait for each other at every operation, so one
    thread that shares a core holds all back: a 3 M-step PPO run took 95 s at 2 threads beside
    one single-thread job on 2 cores against 11 s at 1 thread (7 s at 2 threads on the idle
    machine; docs/performance.md)."""
    if threads <= 1:
        return None
    if load is None:
        try:
            load = os.getloadavg()[0]
        except (AttributeError, OSError):  # no load average on this system
            return None
    cores = cores or os.cpu_count() or 1
    if load + threads < cores + 0.5:
        return None
    return (
        f"note: {threads} torch threads on {cores} cores with a load of {load:.1f}: threads "
        "that share a core with other work wait for each other at every operation (up to 9x "
        "slower); --threads 1 runs at full speed beside one other job"
    )


def note_shared_cores(threads: int, stream=None) -> None:
    """Prints :func:`shared_cores_warning`'s line for ``threads`` to ``stream`` (standard
    error) when there is one and the stream is a terminal: a person at it can act on it; logs,
    pipes and tests keep their output as it was."""
    stream = stream or sys.stderr
    if stream.isatty() and (note := shared_cores_warning(threads)) is not None:
        print(note, file=stream, flush=True)
