"""Shared fixtures: small policies with known behaviour and a ready-made trained run."""

from __future__ import annotations

import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from postgres_cluster import postgres_cluster, private_postgres  # noqa: F401 (fixtures)

# The test process decides its thread count once, as `cartpole train --torch-threads 1` does (agents
# never set it): small nets run fastest on one thread, and a loaded machine does not stall on
# threads waiting for each other.
torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def one_torch_thread() -> Iterator[None]:
    """Every test starts on one torch thread (a test that runs the CLI with ``--torch-threads``
    changes it): bit-identity between a seed alone and in a population is promised for one thread
    count, and on a shared 2-core machine a second thread makes small ops wait for each other."""
    torch.set_num_threads(1)
    yield


class AlwaysLeft:
    """Pushes left every step: the pole falls in about ten steps."""

    def act(self, observations: np.ndarray) -> np.ndarray:
        return np.zeros(len(observations), dtype=np.int64)


class Balancer:
    """A hand-written linear controller that balances CartPole for the full episode."""

    weights = np.array([0.05, 0.3, 1.0, 0.3])

    def act(self, observations: np.ndarray) -> np.ndarray:
        return (np.asarray(observations) @ self.weights > 0).astype(np.int64)


@pytest.fixture
def always_left() -> AlwaysLeft:
    return AlwaysLeft()


@pytest.fixture
def balancer() -> Balancer:
    return Balancer()


@pytest.fixture(scope="session")
def cem_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A solved CEM run folder, trained once per test session (about a second)."""
    from cartpole.training import train

    runs_dir = tmp_path_factory.mktemp("runs")
    outcome = train("cem", "CartPole-v1", seed=0, runs_dir=runs_dir, quiet=True)
    assert outcome.report is not None and outcome.report.solved, outcome.report
    return outcome.run.path


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Callable[[str, str], Path]]:
    """``tmpfs(name, options)`` mounts a tmpfs with those mount options (``size=1m``, ``ro,size=64k``)
    at ``tmp_path/name`` and returns it; unmounted after the test. Mounting needs root: the test is
    skipped elsewhere."""
    mounted: list[Path] = []

    def mount(name: str, options: str) -> Path:
        folder = tmp_path / name
        folder.mkdir()
        done = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(folder)], capture_output=True, text=True
        )
        if done.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here (needs root): {done.stderr.strip()}")
        mounted.append(folder)
        return folder

    try:
        yield mount
    finally:
        for folder in mounted:
            subprocess.run(["umount", "-l", str(folder)], capture_output=True)


CHROMIUM = "/usr/bin/chromium"
"""Debian's Chromium, which the browser tests drive (Playwright cannot download its own here)."""


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    """Headless Chromium through Playwright, one per test module (its tests skip without either)."""
    if not Path(CHROMIUM).exists():
        pytest.skip(f"browser tests need Chromium at {CHROMIUM}")
    playwright_api = pytest.importorskip("playwright.sync_api", reason="browser tests need playwright (pip)")
    with playwright_api.sync_playwright() as p:
        chromium = p.chromium.launch(
            executable_path=CHROMIUM,
            args=["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"],
        )
        yield chromium
        chromium.close()
