"""Two `cartpole sweep` processes (two "machines") share one study in a real PostgreSQL server.

Needs CARTPOLE_TEST_POSTGRES_URL, which `.ci/postgres.sh` exports after starting a throwaway cluster:
    source .ci/postgres.sh && python -m pytest tests/test_sweep_postgres.py
"""

from __future__ import annotations

import os
import subprocess
import sys
import uuid

import optuna
import pytest

URL = os.environ.get("CARTPOLE_TEST_POSTGRES_URL")
pytestmark = pytest.mark.skipif(
    not URL,
    reason="no PostgreSQL server: run `source .ci/postgres.sh` (starts a throwaway cluster and exports "
    "CARTPOLE_TEST_POSTGRES_URL), then pytest tests/test_sweep_postgres.py",
)


def test_two_sweep_processes_share_one_postgres_study(tmp_path):
    assert URL is not None
    study = f"shared-{uuid.uuid4().hex[:8]}"
    trials = 5
    commands = [
        [sys.executable, "-m", "cartpole", "sweep", "cem", "--trials", str(trials), "--seeds-per-trial", "2",
         "--study", study, "--storage", URL, "--budget", "3gen", "--runs-dir", str(tmp_path / f"machine{i}")]
        for i in range(2)
    ]  # fmt: skip
    processes = [
        subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for c in commands
    ]
    outputs = [p.communicate(timeout=600) for p in processes]
    for process, (_, stderr) in zip(processes, outputs, strict=True):
        assert process.returncode == 0, stderr

    loaded = optuna.load_study(study_name=study, storage=URL)  # a plain URL, as other tools take it
    states = optuna.trial.TrialState
    done = loaded.get_trials(states=(states.COMPLETE, states.PRUNED))
    assert len(done) == trials, [(t.number, t.state) for t in loaded.get_trials()]
    assert not loaded.get_trials(states=(states.RUNNING, states.WAITING))
    # No trial was run twice: each finished trial has its own runs, on one machine or the other.
    folders = [t.user_attrs["run_seed0"] for t in done]
    assert len(set(folders)) == trials and all("/machine" in f for f in folders)
    for i in range(2):
        assert (tmp_path / f"machine{i}" / "sweeps" / study / "best.toml").is_file()
