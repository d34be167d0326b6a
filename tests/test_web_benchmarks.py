"""Short runs of the web app's benchmarks with trainings started through its API:
``benchmarks/web_latency.py --trainings K`` (play timed again while DQN trainings train) and
``benchmarks/web_start.py`` (a run started from the page against the same run from the CLI). Tiny
sizes: the paths work and the tables say what they measured; the figures mean nothing here."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).parents[1] / "benchmarks"


def script(name: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(BENCHMARKS / name), *args], capture_output=True, text=True, timeout=timeout
    )


def test_web_latency_times_play_again_while_trainings_started_through_the_api_train(tmp_path):
    done = script(
        "web_latency.py",
        *("--steps", "50", "--sessions", "2", "--episodes", "2", "--watch-load", "1", "--trainings", "1"),
        *("--table", "web-latency", "--results-dir", str(tmp_path)),
    )
    assert done.returncode == 0, done.stdout + done.stderr
    record = json.loads((tmp_path / "web-latency.json").read_text())
    measures = [row["measure"] for row in record["summary"]["rows"]]
    assert measures[:2] == ["play round-trip, 2 session(s)", "play, 2 sessions + 1 watching"]
    assert "play round-trip, 2 session(s), with 1 DQN training" in measures
    assert "play, 2 sessions + 1 watching, with 1 DQN training" in measures
    assert measures[-1].startswith("episode API, cem")
    trained = record["summary"]["trainings"]
    assert trained["count"] == 1 and trained["still_running"], trained
    assert trained["env_steps_at_end"][0] >= trained["env_steps_at_start"][0] > 0
    assert trained["request"]["settings"] == {"stop_when_solved": False}
    table = (tmp_path / "web-latency.md").read_text()
    assert "| play, 2 sessions + 1 watching, with 1 DQN training |" in table
    assert "all still training at the end: yes" in table
    assert "it needs --trainings 2 --sessions 20 --watch-load 4" in table  # the target's case is not this


def test_web_latency_refuses_a_negative_count_of_trainings():
    done = script("web_latency.py", "--trainings", "-1", timeout=120)
    assert done.returncode == 2 and "--trainings must be 0 or more" in done.stderr


def test_web_start_compares_the_page_s_start_with_the_cli_s_and_run_py_copies_its_table(tmp_path):
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / "run.py"), "web-start", "--smoke", "--results-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    record = json.loads((tmp_path / "web-start.json").read_text())
    summary = record["summary"]
    assert summary["metrics_equal"] and summary["verdicts_equal"], summary
    assert summary["metrics_rows"] > 0 and summary["verdict"]["episodes"] == 100
    assert 0 < summary["cli_to_status_s"] <= summary["cli_to_end_s"]
    assert 0 < summary["web_to_status_s"] <= summary["web_to_end_s"]
    assert summary["difference_s"] == summary["web_to_status_s"] - summary["cli_to_status_s"]
    (cli,), (web,) = record["results"]["cli"], record["results"]["web"]
    assert web["command"][:2] == ["cartpole", "train"] and web["command"][-2] == "--runs-dir"
    assert cli["command"][4:] == [*web["command"][2:-2], "--runs-dir", cli["command"][-1]]  # the same run
    table = (tmp_path / "web-start.md").read_text()
    assert table.startswith("`python benchmarks/web_start.py --trials 1 --warmup 0 --table web-start`")
    assert "Target: a run started from the page starts in no more than 1 s longer" in table
    readme = (tmp_path / "benchmarks-README.md").read_text()
    assert "<!-- table: web-start -->\n" + table + "<!-- end table: web-start -->" in readme
