"""The machine line of runs and results, and the note printed on a terminal when the torch
threads asked for would share their cores with other work (torch's threads wait for each other
at every operation: a 2-thread run beside one busy job on 2 cores was 9x slower than 1 thread,
docs/performance.md)."""

import io
import os

import pytest
import torch
from helpers import smoke_config

from dockingrl.evaluation import machine
from dockingrl.evaluation.machine import (
    cpu_model,
    cpu_speed,
    describe_machine,
    shared_cores_warning,
)
from dockingrl.training.trainer import Trainer


@pytest.mark.parametrize(
    ("threads", "load", "cores", "noted"),
    [
        (1, 5.0, 2, False),  # one thread never waits for another
        (2, 0.1, 2, False),  # an idle machine
        (2, 0.6, 2, True),  # one other job on two cores
        (2, 1.0, 4, False),  # room beside it
        (4, 1.0, 4, True),
        (2, 2.0, 16, False),
    ],
)
def test_the_note_reads_the_load_the_threads_and_the_cores(threads, load, cores, noted):
    note = shared_cores_warning(threads, load=load, cores=cores)
    assert (note is not None) is noted
    if noted:
        assert note.startswith(f"note: {threads} torch threads on {cores} cores")
        assert "--threads 1" in note and "\n" not in note


def test_no_load_average_means_no_note(monkeypatch):
    def missing():
        raise OSError("no load average")

    monkeypatch.setattr(machine.os, "getloadavg", missing)
    assert shared_cores_warning(2) is None


class Terminal(io.StringIO):
    """Standard error as a terminal."""

    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize(
    ("load", "stream", "noted"),
    [(1.5, Terminal, True), (0.0, Terminal, False), (1.5, io.StringIO, False)],
)
def test_a_training_prints_the_note_on_a_terminal_when_its_threads_share_cores(
    tmp_path, monkeypatch, load, stream, noted
):
    monkeypatch.setattr(machine.os, "getloadavg", lambda: (load, load, load))
    monkeypatch.setattr(machine.os, "cpu_count", lambda: 2)
    err = stream()
    monkeypatch.setattr(machine.sys, "stderr", err)
    cfg = smoke_config("sac", "noise", tmp_path, "run", threads=2)
    threads = torch.get_num_threads()
    try:
        Trainer(cfg, tmp_path / "run", progress=False)
    finally:
        torch.set_num_threads(threads)
    assert ("note: 2 torch threads on 2 cores" in err.getvalue()) is noted


def test_the_machine_line_tells_two_cpus_of_one_name_apart():
    fast = "processor\t: 0\nmodel name\t: AMD EPYC\ncpu MHz\t: 2596.138\nflags\t\t: avx2 avx512f\n"
    slow = "processor\t: 0\nmodel name\t: AMD EPYC\ncpu MHz\t\t: 1996.249\nflags\t\t: fpu avx2\n"
    two_cores = fast + "\nprocessor\t: 1\ncpu MHz\t\t: 1400.000\nflags\t\t: fpu\n"
    assert cpu_speed(fast) == "2.6 GHz, AVX-512"
    assert cpu_speed(slow) == "2.0 GHz"
    assert cpu_speed(two_cores) == "2.6 GHz, AVX-512"  # the first core's
    assert cpu_speed("model name\t: ARM\ncpu MHz\t: unknown\n") == ""
    line = describe_machine()
    assert line.startswith(cpu_model()) and f"{os.cpu_count()} cores" in line
