"""The machine an evaluation or a training ran on, in one line."""

from __future__ import annotations

import platform
from pathlib import Path

import torch


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; elsewhere what :mod:`platform` says)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def describe_machine(device: torch.device | str | None = None) -> str:
    """The CPU, its cores, torch's version and threads, and the GPU when ``device`` is CUDA."""
    import os

    threads = torch.get_num_threads()
    text = f"{cpu_model()}, {os.cpu_count()} cores, torch {torch.__version__}, {threads} threads"
    if device is not None and torch.device(device).type == "cuda":
        text += f", GPU {torch.cuda.get_device_name(device)}"
    return text
