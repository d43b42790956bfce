"""Fixtures shared by the test files: one intra-op thread per test, and tiny training runs
trained once per session."""

import functools

import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread(monkeypatch):
    """Every test starts on one torch thread, and the processes it starts too: the tests'
    tensors are small, so a second thread only adds synchronisation, which on a busy machine
    costs ten times the arithmetic. A run sets its own (``threads``) when it trains."""
    torch.set_num_threads(1)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")


def _shorten_episodes(patch: pytest.MonkeyPatch):
    """Episodes of ``SMOKE_EPISODE_STEPS`` in the worlds that training and ``dockingrl eval``
    build; returns that world's config."""
    from helpers import SMOKE_EPISODE_STEPS

    from dockingrl import policies
    from dockingrl.env import DockingConfig
    from dockingrl.training import options

    short = functools.partial(DockingConfig, max_steps=SMOKE_EPISODE_STEPS)
    patch.setattr(options, "DockingConfig", short)
    patch.setattr(policies, "DockingConfig", short)
    return short()


@pytest.fixture
def short_episodes(monkeypatch):
    """Training runs and ``dockingrl eval`` in this test use episodes of
    ``SMOKE_EPISODE_STEPS``: their untrained policies time out, and what the test checks does
    not depend on how long an episode is. Returns the world's config, for evaluations that
    the test runs itself."""
    return _shorten_episodes(monkeypatch)


@pytest.fixture(scope="session")
def tiny_runs(tmp_path_factory):
    """``tiny_runs(algo, scenario)``: ``(config, result of train, run folder)`` of the smoke
    run of :func:`helpers.tiny_config` with one periodic evaluation, at its end, and episodes
    of ``SMOKE_EPISODE_STEPS`` (training and evaluations), trained the first time it is asked
    for; the tests that use it read the folder and do not change it."""
    from helpers import TINY, tiny_config

    from dockingrl import training

    runs: dict = {}

    def get(algo: str, scenario: str):
        if (algo, scenario) not in runs:
            torch.set_num_threads(1)
            root = tmp_path_factory.mktemp(f"{algo}_{scenario}")
            cfg = tiny_config(algo, scenario, root, eval_every=TINY[algo]["total_steps"])
            with pytest.MonkeyPatch.context() as patch:
                _shorten_episodes(patch)
                result = training.train(cfg, progress=False)
            runs[algo, scenario] = (cfg, result, root / f"{algo}_{scenario}")
        return runs[algo, scenario]

    return get
