"""A short run of ``benchmarks/claims.py`` against the test PostgreSQL: simulated workers join at one
moment, then claim, renew and finish through its delaying proxy; its JSON and table say what they
measured and no row is claimed twice. Tiny sizes: the path works, the figures mean nothing here.

Needs CARTPOLE_TEST_POSTGRES_URL, which `.ci/postgres.sh` exports after starting a throwaway cluster:
    source .ci/postgres.sh && python -m pytest tests/test_claims_benchmark.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

URL = os.environ.get("CARTPOLE_TEST_POSTGRES_URL")
pytestmark = pytest.mark.skipif(
    not URL,
    reason="no PostgreSQL server: run `source .ci/postgres.sh` (starts a throwaway cluster and exports "
    "CARTPOLE_TEST_POSTGRES_URL), then pytest tests/test_claims_benchmark.py",
)
SCRIPT = Path(__file__).parents[1] / "benchmarks" / "claims.py"


def test_the_claims_benchmark_measures_simulated_workers_through_a_delay(tmp_path):
    assert URL is not None
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--workers", "3", "--delay-ms", "5", "--storage", URL,
         "--seconds", "1", "--json", str(tmp_path / "claims.json"),
         "--table", "claims", "--results-dir", str(tmp_path)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    found = json.loads((tmp_path / "claims.json").read_text())
    assert (found["workers"], found["delay_ms"], found["join"], found["claim"]) == (
        3,
        5.0,
        "current",
        "current",
    )
    assert found["claims_per_s"] > 0 and found["claims"] > 0
    assert 0 < found["join_median_s"] <= found["join_max_s"] < found["first_claim_from_start_max_s"] < 60
    assert 0 < found["first_claim_wait_max_s"] < found["first_claim_from_start_max_s"]
    assert found["double_claims"] == 0 and found["errors"] == []
    table = (tmp_path / "claims.md").read_text()
    assert "| current | current | 3 | 5 |" in table


def test_the_legacy_join_and_claim_are_measured_beside_the_current_ones(tmp_path):
    assert URL is not None
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--workers", "1,2", "--delay-ms", "0", "--storage", URL,
         "--join", "current,legacy", "--claim", "current,legacy", "--seconds", "0.5",
         "--json", str(tmp_path / "claims.json")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    found = json.loads((tmp_path / "claims.json").read_text())
    assert [(r["join"], r["claim"], r["workers"]) for r in found] == [
        (join, claim, workers)
        for join in ("current", "legacy")
        for claim in ("current", "legacy")
        for workers in (1, 2)
    ]
    assert all(r["double_claims"] == 0 and r["errors"] == [] for r in found)
