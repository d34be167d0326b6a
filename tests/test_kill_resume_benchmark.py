"""A short run of ``benchmarks/kill_resume.py``: kill -9 a single run and a population at random
moments, resume each, and check that every resume ends in a verdict having lost at most one checkpoint
interval (the script exits 1 otherwise)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).parents[1] / "benchmarks" / "kill_resume.py"


def test_kill_resume_benchmark_passes_for_a_single_run_and_a_population():
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--agents", "cem,ppo-population", "--trials", "2", "--seed", "1"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "resumed to a verdict: 2/2; passed: 2/2" in done.stdout
