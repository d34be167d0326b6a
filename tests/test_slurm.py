"""A comparison on a real Slurm cluster: the shipped docs/experiments/slurm-compare.sbatch submitted as a
job array of 3 tasks that share one comparison in a real PostgreSQL server; one task is cancelled with
scancel while it trains (it hands its claims back on the SIGTERM: the claim timeout is 10 minutes, which
no task waits out), and every (entry, seed) still finishes exactly once, with the results of a
one-machine run of the same comparison.

Needs a Slurm cluster whose node is this machine (SLURM_CONF; `.ci/slurm.sh` starts a throwaway one) and
CARTPOLE_TEST_POSTGRES_URL (`.ci/postgres.sh`):
    source .ci/postgres.sh && source .ci/slurm.sh && python -m pytest -m slow -n 0 tests/test_slurm.py
Skipped where either is missing, except under CI=true, where it fails: CI cannot skip it unseen. (The
test that the docs show the script is a quick one.)
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Any

import pytest
from platforms import proc
from polling import wait_for

from cartpole.experiments.shared import RowState, SharedComparison

URL = os.environ.get("CARTPOLE_TEST_POSTGRES_URL")
DOCS = Path(__file__).resolve().parents[1] / "docs"
SCRIPT = DOCS / "experiments" / "slurm-compare.sbatch"
ENTRIES = ["cem", "random-search"]
SEEDS = 6
TASKS = 3
COMPARE_ARGS = [*ENTRIES, "--seeds", str(SEEDS), "--budget", "3gen"]
SHARED_ARGS = ["--chunk", "2", "--claim-timeout", "600"]
"""A claim timeout no task waits out: the cancelled task hands its claims back on SIGTERM."""
SAME = ("solved_in_training", "solve_steps", "env_steps", "stop_reason", "final_mean", "final_solved",
        "final_verdict")  # fmt: skip
"""What a run's record must hold alike on the cluster and on one machine."""


def missing() -> list[str]:
    """What this test needs and does not have."""
    lacks = []
    if not os.environ.get("SLURM_CONF") or not shutil.which("sbatch"):
        lacks.append("a Slurm cluster (SLURM_CONF and sbatch: `source .ci/slurm.sh` starts one)")
    if not URL:
        lacks.append("PostgreSQL (CARTPOLE_TEST_POSTGRES_URL: `source .ci/postgres.sh` starts one)")
    return lacks


def cluster() -> str:
    """The PostgreSQL URL; skips the test without Slurm or PostgreSQL, but fails it under CI=true."""
    lacks = missing()
    if lacks:
        message = "this test needs " + " and ".join(lacks)
        if os.environ.get("CI", "").lower() in ("true", "1"):
            pytest.fail(message + " (CI=true: it must run)")
        pytest.skip(message)
    assert URL is not None
    return URL


def slurm(*args: str) -> str:
    return subprocess.run(args, check=True, capture_output=True, text=True, timeout=60).stdout


def submit(url: str, name: str, runs_dir: Path, outputs: Path) -> str:
    """The shipped script as an array of TASKS one-CPU tasks; its job id."""
    env = {
        **os.environ,
        "CARTPOLE_STORAGE": url,
        "CARTPOLE_RUNS_DIR": str(runs_dir),
        "CARTPOLE_VENV": sys.prefix,
    }
    out = subprocess.run(
        ["sbatch", "--parsable", f"--array=0-{TASKS - 1}", "--cpus-per-task=1",
         f"--output={outputs}/task-%a.out", f"--chdir={runs_dir}", str(SCRIPT),
         *COMPARE_ARGS, "--name", name, *SHARED_ARGS],
        env=env, check=True, capture_output=True, text=True, timeout=60,
    ).stdout  # fmt: skip
    return out.strip().split(";")[0]


def compare_pids(runs_dir: Path) -> dict[int, int]:
    """{array task: pid} of the live `cartpole compare` processes of each task (found by their
    --runs-dir, RUNS_DIR/task-N: the cluster's node is this machine)."""
    found = {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            args = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
        except OSError:
            continue
        if "compare" in args and "--runs-dir" in args:
            folder = Path(args[args.index("--runs-dir") + 1])
            if folder.parent == runs_dir and folder.name.startswith("task-"):
                found[int(folder.name.removeprefix("task-"))] = int(pid)
    return found


def claims_of(shared: SharedComparison, pid: int) -> list[Any]:
    return [r for r in shared.rows() if r.state == RowState.CLAIMED and f":{pid}:" in (r.owner or "")]


def training_task(shared: SharedComparison, runs_dir: Path) -> tuple[int, list[Any]] | None:
    """(array task, its claimed rows) of a task whose worker trains a claimed run now (its run folder is
    there), if any."""
    for task, pid in compare_pids(runs_dir).items():
        held = claims_of(shared, pid)
        runs = runs_dir / f"task-{task}" / "experiments" / shared.name / "runs"
        if any(any(runs.glob(f"*__{row.agent}__s{row.seed}__*")) for row in held):
            return task, held
    return None


def job_states(job: str) -> dict[int, str]:
    """{array task: JobState} of the job's tasks (slurmctld keeps ended ones for MinJobAge, 300 s)."""
    states = {}
    for line in slurm("scontrol", "show", "job", "--oneliner", job).splitlines():
        fields = dict(f.split("=", 1) for f in line.split() if "=" in f)
        if "ArrayTaskId" in fields:
            states[int(fields["ArrayTaskId"])] = fields["JobState"]
    return states


def open_shared(url: str, name: str) -> SharedComparison | None:
    try:
        shared = SharedComparison.open(url, name)
    except Exception:
        return None
    return shared if shared.rows() else None


def finished_records(runs_dir: Path) -> list[dict[str, Any]]:
    """Every finished record under ``runs_dir``, all tasks' folders together."""
    records = (json.loads(p.read_text()) for p in sorted(runs_dir.glob("**/records/*.json")))
    return [r for r in records if r.get("state") == "finished"]


@proc
@pytest.mark.slow
def test_a_job_array_shares_one_comparison_and_survives_a_scancel(tmp_path):
    url = cluster()
    name = f"slurm-{uuid.uuid4().hex[:8]}"
    runs_dir, outputs = tmp_path / "cluster", tmp_path / "outputs"
    runs_dir.mkdir()
    outputs.mkdir()
    job = submit(url, name, runs_dir, outputs)
    alone: subprocess.Popen[str] | None = None
    try:
        shared = wait_for(lambda: open_shared(url, name), 300, "the comparison to be created")
        cancelled, held = wait_for(
            lambda: training_task(shared, runs_dir), 300, "a task to train a claimed run"
        )
        slurm("scancel", f"{job}_{cancelled}")
        # The same comparison on one machine, meanwhile (the cluster's tasks often wait).
        alone = subprocess.Popen(
            [sys.executable, "-m", "cartpole", "compare", *COMPARE_ARGS, "--name", name,
             "--runs-dir", str(tmp_path / "one-machine")],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        wait_for(lambda: not slurm("squeue", "--noheader", "--array", "--jobs", job).strip(), 540,
                 "the job array to end")  # fmt: skip
        _, alone_errors = alone.communicate(timeout=300)
    finally:
        subprocess.run(["scancel", job], capture_output=True, timeout=60)
        if alone is not None and alone.poll() is None:
            alone.kill()
    logs = "\n".join(f"--- task {p.name}\n{p.read_text()}" for p in sorted(outputs.iterdir()))
    states = job_states(job)
    assert states == {t: "CANCELLED" if t == cancelled else "COMPLETED" for t in range(TASKS)}, logs
    # scancel's SIGTERM: the task gave its claims back at once (no task waited out the claim timeout).
    assert "stopping: gave back the claims of" in (outputs / f"task-{cancelled}.out").read_text(), logs

    # Every (entry, seed) finished exactly once; what the cancelled task held, another task claimed again.
    rows = shared.rows()
    assert sorted((r.entry, r.seed) for r in rows) == sorted((e, s) for e in ENTRIES for s in range(SEEDS))
    assert all(r.state == RowState.FINISHED for r in rows), logs
    taken_over = {(r.entry, r.seed) for r in held}
    for row in rows:
        if (row.entry, row.seed) in taken_over:
            assert row.claims >= 2 and f"task-{cancelled}" not in row.record["run"], row
    records = finished_records(runs_dir)
    assert sorted((r["agent"], r["seed"]) for r in records) == sorted((r.entry, r.seed) for r in rows)

    # The same results as one machine's run of the same comparison, run by run.
    assert alone.returncode == 0, alone_errors
    expected = {
        (r["agent"], r["seed"]): {k: r[k] for k in SAME} for r in finished_records(tmp_path / "one-machine")
    }
    assert len(expected) == len(ENTRIES) * SEEDS
    assert {(r.entry, r.seed): {k: r.record[k] for k in SAME} for r in rows} == expected


def test_the_docs_show_the_shipped_compare_script():
    """docs/EXPERIMENTS.md shows the script this test submits, less its comment header."""
    lines = SCRIPT.read_text().splitlines()
    header = next(
        i for i, line in enumerate(lines[1:], 1) if not line.startswith("#") or line.startswith("#SBATCH")
    )
    shipped = lines[:1] + lines[header:]
    docs = (DOCS / "EXPERIMENTS.md").read_text()
    block = docs[docs.index("```bash\n#!/bin/bash\n") :].split("\n", 1)[1]
    assert block[: block.index("```")].splitlines() == shipped
