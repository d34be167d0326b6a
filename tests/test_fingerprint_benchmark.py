"""``benchmarks/fingerprint.py`` on one small case: it hashes each seed's run, a seed alone and in a
population alike, and ``--compare`` exits 1 naming what differs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).parents[1] / "benchmarks" / "fingerprint.py"


def fingerprint(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=300)


def test_a_case_is_fingerprinted_and_compared(tmp_path):
    out = tmp_path / "a.json"
    done = fingerprint("--out", str(out), "--cases", "cem/default")
    assert done.returncode == 0, done.stdout + done.stderr
    runs = json.loads(out.read_text())["cases"]["cem/default"]["runs"]
    assert set(runs) == {"population seed 1", "population seed 2", "single seed 2"}
    assert runs["population seed 2"] == runs["single seed 2"]  # one engine: a seed alone is itself
    assert runs["population seed 1"]["latest.pt params"] != runs["single seed 2"]["latest.pt params"]
    assert {"metrics", "verdict", "latest.pt learner data", "best.pt params"} <= set(runs["single seed 2"])

    same = fingerprint("--compare", str(out), str(out))
    assert same.returncode == 0 and "0 difference(s) in 1 case(s)" in same.stdout

    changed = json.loads(out.read_text())
    changed["cases"]["cem/default"]["runs"]["single seed 2"]["latest.pt params"] = "0" * 16
    other = tmp_path / "b.json"
    other.write_text(json.dumps(changed))
    differs = fingerprint("--compare", str(out), str(other))
    assert differs.returncode == 1
    assert "cem/default, single seed 2: latest.pt params differs" in differs.stdout


def test_an_unknown_case_gets_one_line_and_exit_2(tmp_path):
    done = fingerprint("--out", str(tmp_path / "a.json"), "--cases", "ppo/nonsense")
    assert done.returncode == 2 and "unknown case 'ppo/nonsense'" in done.stderr
    assert "Traceback" not in done.stderr
