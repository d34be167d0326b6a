"""Two `cartpole compare` processes (two "machines") share one comparison in a real PostgreSQL server;
one is killed with SIGKILL part way, and the other takes its claims over.

Needs CARTPOLE_TEST_POSTGRES_URL, which `.ci/postgres.sh` exports after starting a throwaway cluster:
    source .ci/postgres.sh && python -m pytest tests/test_compare_postgres.py
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import uuid

import pytest
from platforms import kill_9, proc
from polling import wait_for

from cartpole.experiments.shared import RowState, SharedComparison

URL = os.environ.get("CARTPOLE_TEST_POSTGRES_URL")
pytestmark = pytest.mark.skipif(
    not URL,
    reason="no PostgreSQL server: run `source .ci/postgres.sh` (starts a throwaway cluster and exports "
    "CARTPOLE_TEST_POSTGRES_URL), then pytest tests/test_compare_postgres.py",
)
ENTRIES = ["cem", "random-search"]
SEEDS = 4


def compare_command(name: str, runs_dir: object) -> list[str]:
    assert URL is not None
    return [sys.executable, "-m", "cartpole", "compare", *ENTRIES, "--seeds", str(SEEDS), "--budget", "3gen",
            "--storage", URL, "--name", name, "--chunk", "2", "--claim-timeout", "3",
            "--runs-dir", str(runs_dir)]  # fmt: skip


def claims_of(shared: SharedComparison, pid: int) -> list[object]:
    return [r for r in shared.rows() if r.state == RowState.CLAIMED and f":{pid}:" in (r.owner or "")]


def worker_processes(marker: str) -> list[str]:
    """Command lines of live processes that mention ``marker`` (a machine's runs folder)."""
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                line = f.read().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if marker in line:
            found.append(line)
    return found


@kill_9
@proc
def test_two_compare_processes_share_one_comparison_and_survive_a_sigkill(tmp_path):
    assert URL is not None
    name = f"shared-{uuid.uuid4().hex[:8]}"
    machines = [tmp_path / "machine0", tmp_path / "machine1"]
    doomed = subprocess.Popen(
        compare_command(name, machines[0]), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    survivor = subprocess.Popen(
        compare_command(name, machines[1]), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        shared = wait_for(lambda: _open(name), 120, "the comparison to be created")
        held = wait_for(lambda: claims_of(shared, doomed.pid), 120, "the first process to claim runs")
        doomed.send_signal(signal.SIGKILL)  # a lost machine: no clean-up, no release of its claims
        doomed.wait(timeout=30)
        _, stderr = survivor.communicate(timeout=600)
    finally:
        for process in (doomed, survivor):
            if process.poll() is None:
                process.kill()
    assert survivor.returncode == 0, stderr

    rows = shared.rows()
    assert len(rows) == len(ENTRIES) * SEEDS
    assert {(r.entry, r.seed) for r in rows} == {(e, s) for e in ENTRIES for s in range(SEEDS)}
    assert all(r.state == RowState.FINISHED for r in rows)
    # What the killed process held was claimed again and finished by the survivor.
    taken_over = {(r.entry, r.seed) for r in held}
    assert all(
        r.claims >= 2 and "machine1" in r.record["run"] for r in rows if (r.entry, r.seed) in taken_over
    )
    # The killed process's workers did not train on as orphans.
    wait_for(lambda: not worker_processes(str(machines[0])), 30, "the killed process's workers to stop")

    # Any machine builds the whole report from the database: every (entry, seed) exactly once.
    reporter = subprocess.run(
        [sys.executable, "-m", "cartpole", "compare", "--report", "--storage", URL, "--name", name,
         "--runs-dir", str(tmp_path / "laptop")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert reporter.returncode == 0, reporter.stderr
    report = json.loads((tmp_path / "laptop" / "experiments" / name / "report.json").read_text())
    assert [e["entry"] for e in report["entries"]] == ENTRIES
    for entry in report["entries"]:
        assert entry["runs"] == SEEDS and sorted(entry["seeds"]) == list(range(SEEDS))
        assert entry["solved"] == sum(
            bool(r.record["solved_in_training"]) for r in rows if r.entry == entry["entry"]
        )
    assert (tmp_path / "laptop" / "experiments" / name / "curves.png").is_file()

    # Re-running the command adds nothing twice: no new rows, no new claims, no new runs.
    claims = {(r.entry, r.seed): r.claims for r in rows}
    again = subprocess.run(compare_command(name, machines[1]), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert {(r.entry, r.seed): r.claims for r in shared.rows()} == claims


def _open(name: str) -> SharedComparison | None:
    assert URL is not None
    try:
        shared = SharedComparison.open(URL, name)
    except Exception:
        return None
    return shared if shared.rows() else None


def test_workers_claiming_at_the_same_moment_each_get_other_runs_at_once():
    """A claim locks only the rows it takes: 16 workers (threads, a connection each) released together
    each get a run on their first try, and no run is claimed twice (a claim that locked every claimable
    row left the others with nothing until it ended)."""
    import threading

    from cartpole.experiments.entries import Entry
    from cartpole.experiments.shared import new_owner

    assert URL is not None
    name = f"together-{uuid.uuid4().hex[:8]}"
    entries = [Entry("cem"), Entry("random-search")]
    labels, seeds = [e.label for e in entries], list(range(32))
    SharedComparison.join(URL, name, {"env_id": "CartPole-v1", "budget": "3gen"}, entries, seeds)
    workers = [SharedComparison.open(URL, name) for _ in range(16)]
    for shared in workers:
        shared.rows()  # connected before the start
    start = threading.Barrier(len(workers))
    found: list[object] = [None] * len(workers)

    def claim_once(index: int) -> None:
        start.wait()
        found[index] = workers[index].claim(new_owner(), 1, dict.fromkeys(labels, True), set(), labels, seeds)

    threads = [threading.Thread(target=claim_once, args=(i,)) for i in range(len(workers))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=120)
    assert all(claim is not None for claim in found), found
    taken = [(claim.entry.label, seed) for claim in found for seed in claim.seeds]  # type: ignore[attr-defined]
    assert len(taken) == len(set(taken)) == len(workers)
    rows = workers[0].rows()
    assert sum(r.state == RowState.CLAIMED for r in rows) == len(workers)
    assert all(r.claims <= 1 for r in rows)


def test_workers_joining_at_the_same_moment_add_every_row_once():
    """A join holds no lock across round trips: 32 workers (threads, a connection each) join one new
    comparison at the same moment, half asking for one entry and fewer seeds, half for two entries;
    every row is there once and both entries are listed once."""
    import threading

    from cartpole.experiments.entries import Entry

    assert URL is not None
    name = f"joins-{uuid.uuid4().hex[:8]}"
    cem, random_search = Entry("cem"), Entry("random-search")
    start = threading.Barrier(32)
    errors: list[BaseException] = []

    def join_once(index: int) -> None:
        entries, seeds = ([cem], range(50)) if index % 2 else ([random_search, cem], range(100))
        start.wait()
        try:
            shared = SharedComparison.join(URL, name, {"env_id": "CartPole-v1", "budget": "3gen"}, entries,
                                           list(seeds))  # fmt: skip
            shared.engine.dispose()
        except BaseException as err:  # reported below, not lost in a thread
            errors.append(err)

    threads = [threading.Thread(target=join_once, args=(i,)) for i in range(32)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=120)
    assert not errors, errors
    shared = SharedComparison.open(URL, name)
    rows = shared.rows()
    assert sorted((r.entry, r.seed) for r in rows) == sorted(
        (e, s) for e in ("cem", "random-search") for s in range(100)
    )
    assert all(r.state == RowState.PENDING and r.claims == 0 for r in rows)
    assert sorted(e.label for e in shared.entries()) == ["cem", "random-search"]
