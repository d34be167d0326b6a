"""A short run of each measure of ``benchmarks/dqn_step.py``: it prints what it says."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).parents[1] / "benchmarks" / "dqn_step.py"


def measure(*args: str) -> dict:
    done = subprocess.run(
        [sys.executable, str(SCRIPT), *args, "--json"], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return json.loads(done.stdout)


def test_step_and_memory_report_their_figures():
    step = measure("step", "--warmup", "80", "--repeats", "3", "--trials", "2")
    assert step["us_per_gradient_step"] > 0 and len(step["trials_us"]) == 2
    memory = measure("memory", "--seeds", "3", "--steps", "80")
    assert memory["seeds"] == 3 and memory["peak_rss_mb"] > 0 and memory["cpu_s"] > 0


def test_bad_sizes_get_one_line_and_exit_2():
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "memory", "--seeds", "0"], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 2 and "--seeds must be at least 1" in done.stderr
    assert "Traceback" not in done.stderr
